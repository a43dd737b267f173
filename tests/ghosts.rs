//! The ghost check (`stack::ghosts`) on simulated stacks: it passes an image made of the frames'
//! own content, flags a doubled one, and finds each frame's global pose by itself.

use focusd::sim::{render, SimParams, SimStack};
use focusd::stack::internal::ghosts::{check, SEARCH, WIDTH};
use focusd::stack::{Affine, Image};

fn parallax_stack() -> SimStack {
    render(&SimParams {
        width: 480,
        height: 360,
        planes: 6,
        seed: 5,
        handheld: true,
        parallax_px: 6.0,
        gain_jitter: 0.05,
        linear_light: true,
        ..SimParams::default()
    })
}

#[test]
fn truth_passes_a_doubled_image_fails_and_poses_are_found() {
    let s = parallax_stack();
    let clean = check(&s.truth, &s.frames);
    eprintln!(
        "truth: {} of {} textured tiles below threshold ({:.1} %)",
        clean.ghosts(),
        clean.textured(),
        100.0 * clean.share()
    );
    assert!(
        clean.textured() > 200,
        "{} textured tiles",
        clean.textured()
    );
    // Even the truth is not every frame's pixels at occlusion edges: no frame holds a sharp
    // near edge over a sharp background there (the halo), and at 480 px a tile is 15 px.
    assert!(clean.share() <= 0.05, "truth flagged: {:.3}", clean.share());

    // Each alignment is the true reference→frame affine of the background, in working-width
    // pixels (the corners are the worst place), to within the search window, except that a
    // frame whose near layers move against the background pulls its fit towards them: the check
    // aligns to whatever the frame holds sharp. Measured: 0.3–0.9 px for the frames focused
    // behind the near layers, 3.8 and 3.3 px for frames 0 and 1, focused on them, whose near
    // layers move 4.4 and 4.7 px (working width). A fit off by more than that would be neither.
    let k = WIDTH as f64 / 480.0;
    let to_work = Affine([[k, 0.0, 0.5 * k - 0.5], [0.0, k, 0.5 * k - 0.5]]);
    let from_work = to_work.inverse().unwrap();
    let errors: Vec<(f64, f64)> = clean
        .alignments
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let want = to_work.compose(&s.ref_to_frame[i]).compose(&from_work);
            let got = a.expect("every frame aligns");
            let err = got.corner_error(&want, WIDTH, 750);
            let [px, py] = s.info[i].parallax;
            let parallax = k * px.hypot(py);
            eprintln!(
                "frame {i}: corner error {err:.2} px, near layers' parallax {parallax:.2} px"
            );
            (err, parallax)
        })
        .collect();
    for (i, &(err, parallax)) in errors.iter().enumerate() {
        assert!(
            err < 0.8 * SEARCH as f64 + parallax,
            "frame {i}: corner error {err:.2} px"
        );
    }

    // Content moved by more than the search window is a ghost: the truth with every other band
    // of 40 rows shifted, as a misregistered part would be; 8 px (17 at the working width), and
    // 2 px (4.2 px: parallax a window of ±5 px let pass).
    let t = &s.truth;
    for (shift, least) in [(8, 0.15), (2, 0.1)] {
        let moved = Image::<u8>::from_fn(t.width(), t.height(), 3, |x, y, c| {
            let dx = if (y / 40) % 2 == 1 { shift } else { 0 };
            t.at((x + dx).min(t.width() - 1), y, c)
        });
        ghosts_above(&moved, &s, least, &format!("bands shifted {shift} px"));
    }
    // Two copies 12 px apart, half and half: doubled text.
    let doubled = Image::<u8>::from_fn(t.width(), t.height(), 3, |x, y, c| {
        let other = t.at((x + 12).min(t.width() - 1), y, c);
        ((t.at(x, y, c) as u16 + other as u16) / 2) as u8
    });
    ghosts_above(&doubled, &s, 0.15, "doubled");
}

/// Asserts that more than `least` of `img`'s textured tiles are ghosts (measured: bands shifted
/// 8 px 31.7 %, 2 px 15.4 %, doubled 47.3 %; the truth itself 1.7 %).
fn ghosts_above(img: &Image<u8>, s: &SimStack, least: f64, what: &str) {
    let share = check(img, &s.frames).share();
    eprintln!("{what}: {:.1} % ghosts", 100.0 * share);
    assert!(share > least, "{what}: {share:.3}");
}
