//! The labelling offers each pixel only a few candidate frames. On content where many frames tie
//! (smooth regions, noise, many frames) its labels must still be as good as exhaustive
//! expansion's, which offers every frame everywhere: energy within 1 %.

use focusd::sim::flats::{flats, FlatsParams};
use focusd::stack::internal::{label_stack, labelling_energy};
use focusd::stack::{Coverage, GraphCutParams, NoProgress};

#[test]
fn candidate_labelling_is_within_one_percent_of_exhaustive_on_flats() {
    let p = FlatsParams {
        width: 480,
        height: 360,
        frames: 16,
        ..FlatsParams::default()
    };
    let frames = flats(&p);
    let coverage = vec![Coverage::full(p.width, p.height); p.frames];
    let label = |params: GraphCutParams| {
        let labels = label_stack(&frames, &coverage, 7, &params, usize::MAX, &NoProgress).labels;
        (
            labelling_energy(&frames, &coverage, &labels, 7, &params),
            labels,
        )
    };
    let (default, labels) = label(GraphCutParams::default());
    let (exhaustive, _) = label(GraphCutParams::exhaustive());
    let ratio = default as f64 / exhaustive as f64;
    eprintln!("energy {default} against exhaustive {exhaustive}: {ratio:.4}");
    assert!(ratio <= 1.01, "energy ratio {ratio:.4}");
    // The stack is hard for the reason it is meant to be: the labels use most frames.
    let mut used = [false; 256];
    labels.iter().for_each(|&l| used[l as usize] = true);
    let used = used.iter().filter(|&&u| u).count();
    assert!(used >= p.frames * 3 / 4, "only {used} frames used");
    // And 1 % is a narrow margin: one label (the best single frame) costs far more.
    let single = (0..p.frames as u8)
        .map(|l| {
            let params = GraphCutParams::default();
            labelling_energy(&frames, &coverage, &vec![l; p.width * p.height], 7, &params)
        })
        .min()
        .unwrap();
    assert!(
        single as f64 > 1.1 * exhaustive as f64,
        "single frame {single}"
    );
}
