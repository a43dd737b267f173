//! The spill removal's tests: a disc in front of a textured background, blurred as a lens would.

use super::blur_fit::{monotone, with_predicted, Pair};
use super::light::{fit, luma, Fitted, PROBES};
use super::synthesis::{Blurred, Blurs, Group, Spill};
use super::*;
use crate::stack::blur::gaussian_blur;
use crate::stack::NoProgress;
use std::rc::Rc;
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
use std::sync::Mutex;

const SIZE: usize = 160;
const CENTRE: f32 = 80.0;
const RADIUS: f32 = 40.0;

/// A pair as the fit gives it.
fn fitted(near: u8, far: u8, sigma: f32) -> Pair {
    Pair {
        near,
        far,
        sigma,
        predicted: false,
    }
}

/// A textured disc (the near object) over a textured background, seen by three frames:
/// focused on the disc (the background blurred by 3 px), between (disc 2, background
/// 1.5), and on the background (the disc blurred by 4 px over it), mixed in `light` and
/// stored in sRGB-encoded 8 bits. Returns the frames and the sharp background.
fn scene(light: Light) -> (Vec<Image<u8>>, Vec<Plane>) {
    scene_of(light, RADIUS, 4.0)
}

/// [`scene`] with a disc of `radius`, blurred by `blur` in the frame focused behind it.
fn scene_of(light: Light, radius: f32, blur: f32) -> (Vec<Image<u8>>, Vec<Plane>) {
    let plane = |f: &dyn Fn(f32, f32) -> f32| {
        Plane::from_fn(SIZE, SIZE, 1, |x, y, _| f(x as f32, y as f32))
    };
    let alpha = plane(&|x, y| {
        let r = ((x - CENTRE).powi(2) + (y - CENTRE).powi(2)).sqrt();
        (radius + 0.5 - r).clamp(0.0, 1.0)
    });
    let stripes = |x: f32, y: f32, p: f32| 0.5 + 0.35 * ((x + 0.5 * y) * p).sin();
    let near: Vec<Plane> = [0.9, 0.3, 0.2]
        .iter()
        .map(|&c| plane(&|x, y| light.mixing()(c * stripes(x, y, 0.7))))
        .collect();
    let far: Vec<Plane> = [0.3, 0.5, 0.8]
        .iter()
        .map(|&c| plane(&|x, y| light.mixing()(c * stripes(y, -x, 0.45))))
        .collect();
    let frame = |near_sigma: f32, far_sigma: f32| {
        let a = gaussian_blur(&alpha, near_sigma);
        let planes: Vec<Plane> = near
            .iter()
            .zip(&far)
            .map(|(c, b)| {
                let ac = Plane::from_vec(
                    c.width(),
                    c.height(),
                    1,
                    c.data()
                        .iter()
                        .zip(alpha.data())
                        .map(|(v, m)| v * m)
                        .collect(),
                );
                let (ac, b) = (gaussian_blur(&ac, near_sigma), gaussian_blur(b, far_sigma));
                let data = (0..SIZE * SIZE)
                    .map(|i| light.storing()(ac.data()[i] + (1.0 - a.data()[i]) * b.data()[i]))
                    .collect();
                Plane::from_vec(SIZE, SIZE, 1, data)
            })
            .collect();
        Image::<u8>::from_planes(&planes)
    };
    let frames = vec![frame(0.0, 3.0), frame(blur / 2.0, 1.5), frame(blur, 0.0)];
    let background = far
        .iter()
        .map(|b| {
            let data = b.data().iter().map(|&v| light.storing()(v)).collect();
            Plane::from_vec(b.width(), b.height(), 1, data)
        })
        .collect();
    (frames, background)
}

fn full(frames: usize) -> Vec<Coverage> {
    vec![Coverage::full(SIZE, SIZE); frames]
}

/// [`unmix`] on the whole of every frame, everything textured, without progress.
fn unmix_in(frames: &mut [Image<u8>], labels: &mut [u8], order: Order) -> Unmixed {
    let n = frames.len();
    unmix_covered(frames, labels, &full(n), order)
}

/// [`unmix_in`] with each frame covering what `coverage` says.
fn unmix_covered(
    frames: &mut [Image<u8>],
    labels: &mut [u8],
    coverage: &[Coverage],
    order: Order,
) -> Unmixed {
    unmix(
        frames,
        labels,
        &[true; SIZE * SIZE],
        1,
        coverage,
        order,
        true,
        &NoProgress,
    )
}

/// Pixel `i`'s three samples in `f`.
fn pixel(f: &Image<u8>, i: usize) -> &[u8] {
    &f.data()[i * 3..][..3]
}

fn distance(i: usize) -> f32 {
    let (x, y) = ((i % SIZE) as f32, (i / SIZE) as f32);
    ((x - CENTRE).powi(2) + (y - CENTRE).powi(2)).sqrt() - RADIUS
}

/// The disc labelled 0 exactly, to its edge pixel, and the rest 2.
fn exact_labels() -> Vec<u8> {
    (0..SIZE * SIZE)
        .map(|i| if distance(i) < 0.5 { 0 } else { 2 })
        .collect()
}

/// The disc labelled 0 and the rest 2, as a label map that follows contrast gets them
/// roughly: 3 px too wide on the left, 3 px too narrow on the right.
fn labels() -> Vec<u8> {
    (0..SIZE * SIZE)
        .map(|i| {
            let shift = if i % SIZE < SIZE / 2 { 3.0 } else { -3.0 };
            if distance(i) < shift {
                0
            } else {
                2
            }
        })
        .collect()
}

/// RMS error of `frame` against `truth` over pixels 2–12 px outside the disc: the halo.
fn halo(frame: &Image<u8>, truth: &[Plane]) -> f32 {
    halo_within(frame, truth, 2.0..12.0)
}

/// [`halo`] over the pixels whose distance outside the disc is in `ring`.
fn halo_within(frame: &Image<u8>, truth: &[Plane], ring: std::ops::Range<f32>) -> f32 {
    let ring: Vec<usize> = (0..SIZE * SIZE)
        .filter(|&i| ring.contains(&distance(i)))
        .collect();
    let sum: f32 = ring
        .iter()
        .flat_map(|&i| (0..3).map(move |c| (i, c)))
        .map(|(i, c)| (frame.data()[i * 3 + c] as f32 / 255.0 - truth[c].data()[i]).powi(2))
        .sum();
    (sum / (ring.len() * 3) as f32).sqrt()
}

#[test]
fn the_halo_is_taken_out_in_the_light_the_defocus_mixed_in() {
    for light in [Light::Linear, Light::Display] {
        let (mut frames, background) = scene(light);
        let before = frames.clone();
        let mut l = labels();
        let out = unmix_in(&mut frames, &mut l, Order::NearestFirst);
        assert_eq!(out.light, Some(light));
        let pair = out.pairs.iter().find(|p| (p.near, p.far) == (0, 2));
        let sigma = pair.expect("the disc's blur in frame 2 is fitted").sigma;
        assert!((sigma - 4.0).abs() <= 0.5, "{light:?}: σ {sigma}");
        let (was, now) = (halo(&before[2], &background), halo(&frames[2], &background));
        assert!(now < 0.6 * was, "{light:?}: halo RMS {was} -> {now}");
        // Far from the disc, and in the frames nothing spills into, nothing changes.
        let far_away = (0..SIZE * SIZE).filter(|&i| distance(i) > 30.0);
        assert!(far_away
            .into_iter()
            .all(|i| frames[2].data()[i * 3] == before[2].data()[i * 3]));
        assert_eq!((&frames[0], &frames[1]), (&before[0], &before[1]));
        // Of the right side's 3 px the labels missed, the pixels clearly the disc's colour go
        // back to its frame (the stripes make the rest too close to call); outside the disc
        // no label moves.
        let right = |i: usize| i % SIZE > SIZE / 2 + 8;
        let missed = (0..SIZE * SIZE).filter(|&i| right(i) && (-2.5..-0.5).contains(&distance(i)));
        let (moved, all) = missed.fold((0, 0), |(m, a), i| (m + usize::from(l[i] == 0), a + 1));
        assert!(moved * 3 >= all, "{light:?}: {moved} of {all} moved");
        let outside = (0..SIZE * SIZE).filter(|&i| right(i) && distance(i) > 1.0);
        assert!(
            outside.into_iter().all(|i| l[i] == 2),
            "{light:?}: a label moved outside"
        );
    }
}

/// With the disc labelled exactly: the pixel at its edge keeps its frame's colour (the
/// guard), the one beyond is un-mixed already, where a 2 px guard left a rim of the disc's
/// colour.
#[test]
fn only_the_pixel_at_the_edge_is_guarded() {
    let (mut frames, background) = scene_of(Light::Linear, RADIUS, 4.0);
    let before = frames.clone();
    let mut labels = exact_labels();
    unmix_in(&mut frames, &mut labels, Order::NearestFirst);
    let (was, now) = (
        halo_within(&before[2], &background, 2.0..3.0),
        halo_within(&frames[2], &background, 2.0..3.0),
    );
    assert!(now < 0.6 * was, "second pixel out: RMS {was} -> {now}");
    let edge = (0..SIZE * SIZE).filter(|&i| (0.5..0.9).contains(&distance(i)));
    assert!(edge
        .into_iter()
        .all(|i| pixel(&frames[2], i) == pixel(&before[2], i)));
}

/// Inside the disc's edge the frame focused behind it shows the disc's own pixels once
/// un-mixed, not the disc defocused with the background through it; deeper in, and in the
/// frame one plane behind, nothing is filled.
#[test]
fn the_near_object_s_edge_is_filled_into_the_frame_behind_it() {
    let (mut frames, _) = scene(Light::Linear);
    let before = frames.clone();
    let mut labels = exact_labels();
    let out = unmix_in(&mut frames, &mut labels, Order::NearestFirst);
    let edge: Vec<usize> = (0..SIZE * SIZE)
        .filter(|&i| (-5.0..-1.0).contains(&distance(i)))
        .collect();
    let own = edge
        .iter()
        .filter(|&&i| pixel(&frames[2], i) == pixel(&frames[0], i))
        .count();
    let was = edge
        .iter()
        .filter(|&&i| pixel(&before[2], i) == pixel(&frames[0], i))
        .count();
    assert!(
        own * 10 >= edge.len() * 9,
        "{own} of {} (was {was})",
        edge.len()
    );
    assert!(out.filled >= own, "{} filled", out.filled);
    let deep = (0..SIZE * SIZE).filter(|&i| distance(i) < -8.0);
    assert!(deep
        .into_iter()
        .all(|i| pixel(&frames[2], i) == pixel(&before[2], i)));
    assert_eq!(frames[1], before[1]);
}

/// Where a frame does not reach, a label may be the reference's for want of the frame the
/// labelling chose, not for depth: nothing is filled there.
#[test]
fn nothing_is_filled_where_a_frame_does_not_reach() {
    let (mut frames, _) = scene(Light::Linear);
    let before = frames.clone();
    let mut labels = exact_labels();
    // Frame 1 misses the columns left of the disc's centre.
    let mut coverage = full(3);
    coverage[1].spans.fill((CENTRE as u32, SIZE as u32));
    let out = unmix_covered(&mut frames, &mut labels, &coverage, Order::NearestFirst);
    assert!(out.filled > 0);
    let left_edge = (0..SIZE * SIZE)
        .filter(|&i| (i % SIZE) < CENTRE as usize && (-5.0..-1.0).contains(&distance(i)));
    assert!(left_edge
        .into_iter()
        .all(|i| pixel(&frames[2], i) == pixel(&before[2], i)));
}

/// Where not every frame reaches, the labelling chose among the frames that do: a strip of the
/// nearest frame's label along the border is no near object, and no spill is taken out around it.
#[test]
fn a_label_where_a_frame_does_not_reach_is_no_near_object() {
    let (mut frames, _) = scene(Light::Linear);
    let before = frames.clone();
    let mut labels = exact_labels();
    const STRIP: usize = 2;
    for row in labels.chunks_mut(SIZE) {
        row[..STRIP].fill(0);
    }
    let mut coverage = full(3);
    for c in &mut coverage[1..] {
        c.spans.fill((STRIP as u32, SIZE as u32));
    }
    let out = unmix_covered(&mut frames, &mut labels, &coverage, Order::NearestFirst);
    assert!(out.changed[2] > 0, "the disc's halo is still taken out");
    // Beyond the disc's spill (2.5 of its 4 px blur), the background beside the strip.
    let beside = (0..SIZE * SIZE).filter(|&i| (STRIP..30).contains(&(i % SIZE)));
    let moved = beside
        .filter(|&i| pixel(&frames[2], i) != pixel(&before[2], i))
        .count();
    assert_eq!(moved, 0);
}

/// The same haloed scene with an order its edges did not tell: left exactly as it is, labels
/// too, and the log says why.
#[test]
fn an_untold_order_leaves_the_frames_as_they_are() {
    let (mut frames, _) = scene(Light::Linear);
    let (before, mut l) = (frames.clone(), labels());
    let out = unmix_in(&mut frames, &mut l, Order::Unknown);
    assert_eq!(frames, before);
    assert_eq!(l, labels());
    assert!(out.untold && out.pairs.is_empty(), "{out:?}");
    assert!(out.to_string().contains("do not tell"), "{out}");
}

/// Records the stages announced and the steps advanced.
#[derive(Default)]
struct Steps {
    stages: Mutex<Vec<(Stage, usize)>>,
    done: AtomicUsize,
}

impl Progress for Steps {
    fn stage(&self, stage: Stage, total: usize) {
        self.stages.lock().unwrap().push((stage, total));
    }
    fn advance(&self, steps: usize) {
        self.done.fetch_add(steps, Relaxed);
    }
}

/// The daemon's watchdog fails a job whose progress stands still: the spill removal
/// announces its own stage and advances through every step it announced.
#[test]
fn the_spill_removal_reports_its_progress_to_the_end() {
    let (mut frames, _) = scene(Light::Linear);
    let steps = Steps::default();
    let out = unmix(
        &mut frames,
        &mut labels(),
        &[true; SIZE * SIZE],
        1,
        &full(3),
        Order::NearestFirst,
        true,
        &steps,
    );
    assert!(!out.pairs.is_empty());
    let stages = steps.stages.into_inner().unwrap();
    assert_eq!(stages, [(Stage::Spill, 14)]);
    assert_eq!(steps.done.into_inner(), 14);
}

/// A small near object is fitted into the frames two and three planes behind it
/// but is too small for the two farthest: those pairs are added with the σ the other
/// pairs' focal axis gives (2 px a plane here); a near depth with nothing fitted gets none.
#[test]
fn the_pairs_too_small_to_fit_are_predicted_from_the_others() {
    let fitted = |near: u8, far: u8| fitted(near, far, 2.0 * f32::from(far - near));
    let pairs = vec![
        fitted(0, 2),
        fitted(0, 3),
        fitted(1, 3),
        fitted(1, 4),
        fitted(1, 5),
        fitted(2, 4),
        fitted(2, 5),
    ];
    let all = with_predicted(pairs.clone(), 6);
    assert_eq!(
        all[..pairs.len()],
        pairs[..],
        "the fitted pairs are kept as they are"
    );
    let added: Vec<(u8, u8, f32)> = all[pairs.len()..]
        .iter()
        .map(|p| {
            assert!(p.predicted);
            (p.near, p.far, p.sigma)
        })
        .collect();
    // Depth 3 has no fitted pair, so (3, 5) is not added.
    assert_eq!(added, [(0, 4, 8.0), (0, 5, 10.0)]);
}

/// A thin near object: fitted at 4 px in every frame behind it, while the object behind
/// it (depth 1) is blurred more in the same frames. Each σ is raised to its bound; pairs
/// already in order are kept.
#[test]
fn a_fit_short_of_its_neighbours_is_raised_to_them() {
    let pairs = vec![
        fitted(0, 2, 4.0),
        fitted(0, 3, 4.0),
        fitted(0, 4, 4.0),
        fitted(1, 3, 4.5),
        fitted(1, 4, 6.5),
        fitted(2, 4, 3.0),
    ];
    let raised: Vec<(u8, u8, f32)> = monotone(pairs, 5)
        .iter()
        .map(|p| (p.near, p.far, p.sigma))
        .collect();
    assert_eq!(
        raised,
        [
            (0, 2, 4.0),
            (0, 3, 4.5),
            (0, 4, 6.5),
            (1, 3, 4.5),
            (1, 4, 6.5),
            (2, 4, 3.0)
        ]
    );
}

/// A disc 24 px in radius blurred by 7 px behind: deeper than 3σ it has no interior to fit
/// on, deeper than 1.5σ enough. Its spill is still fitted and un-mixed.
#[test]
fn a_small_object_s_deep_blur_is_still_fitted() {
    let (radius, blur) = (24.0, 7.0);
    let (mut frames, _) = scene_of(Light::Linear, radius, blur);
    let mut labels: Vec<u8> = (0..SIZE * SIZE)
        .map(|i| u8::from(distance(i) + RADIUS > radius) * 2)
        .collect();
    let out = unmix_in(&mut frames, &mut labels, Order::NearestFirst);
    let fitted: Vec<(u8, u8, f32)> = out.pairs.iter().map(|p| (p.near, p.far, p.sigma)).collect();
    assert!(
        matches!(fitted[..], [(0, 2, s)] if (s - blur).abs() <= 1.0),
        "{fitted:?}"
    );
    assert!(out.changed[2] > 0, "{out:?}");
}

/// Five textured discs side by side, one per depth 0–4, over a background (depth 5), seen
/// by six frames each focused on one depth (disc k blurred by 1.5·|l − k| px in frame l),
/// mixed in `light`: each frame's luma in both lights, and the depths' masks.
fn discs(light: Light) -> ([(Light, Vec<Plane>); 2], Vec<Plane>) {
    let (w, h) = (400, 80);
    let mix = light.mixing();
    let plane =
        |f: &dyn Fn(f32, f32) -> f32| Plane::from_fn(w, h, 1, |x, y, _| f(x as f32, y as f32));
    let alpha: Vec<Plane> = (0..5)
        .map(|k| {
            plane(&|x, y| (30.5 - (x - 40.0 - 80.0 * k as f32).hypot(y - 40.0)).clamp(0.0, 1.0))
        })
        .collect();
    let texture = |x: f32, y: f32, k: f32| mix(0.5 + 0.35 * ((x + 0.5 * y) * 0.7 + k).sin());
    let frames: Vec<Plane> = (0..6)
        .map(|l| {
            let mut acc = gaussian_blur(&plane(&|x, y| texture(y, -x, 9.0)), 1.5 * (5 - l) as f32);
            for (k, a) in alpha.iter().enumerate() {
                let s = 1.5 * (l as f32 - k as f32).abs();
                let ac =
                    plane(&|x, y| a.data()[y as usize * w + x as usize] * texture(x, y, k as f32));
                let (a, ac) = (gaussian_blur(a, s), gaussian_blur(&ac, s));
                for ((v, a), c) in acc.data_mut().iter_mut().zip(a.data()).zip(ac.data()) {
                    *v = c + (1.0 - a) * *v;
                }
            }
            acc.data_mut()
                .iter_mut()
                .for_each(|v| *v = light.storing()(*v));
            acc
        })
        .collect();
    let lumas = |light: Light| {
        frames
            .iter()
            .map(|f| luma(std::slice::from_ref(f), light))
            .collect()
    };
    let behind = plane(&|x, y| {
        1.0 - alpha
            .iter()
            .map(|a| a.data()[y as usize * w + x as usize])
            .sum::<f32>()
    });
    let masks = alpha.into_iter().chain([behind]).collect();
    (
        [
            (Light::Linear, lumas(Light::Linear)),
            (Light::Display, lumas(Light::Display)),
        ],
        masks,
    )
}

#[test]
fn the_light_told_by_the_probes_gives_what_every_depth_fitted_in_both_gives() {
    for light in [Light::Linear, Light::Display] {
        let (lights, masks) = discs(light);
        let probed = fit(lights.clone(), &masks, 1, PROBES, &NoProgress);
        let every = fit(lights, &masks, 1, usize::MAX, &NoProgress);
        let Fitted::Told(told, pairs) = &probed else {
            panic!("{light:?}: {probed:?}");
        };
        assert_eq!(*told, light);
        assert!(
            pairs.iter().filter(|p| !p.predicted).count() >= 4,
            "{probed:?}"
        );
        assert_eq!(probed, every);
    }
}

#[test]
fn fits_that_explain_the_stack_alike_in_both_lights_tell_no_light() {
    // The same luma given as both lights: every fit is the same in both, so neither light is
    // told, and nothing is un-mixed (the first light is no longer taken on a tie).
    let (lights, masks) = discs(Light::Linear);
    let [(_, linear), _] = lights;
    let alike = [(Light::Linear, linear.clone()), (Light::Display, linear)];
    assert_eq!(
        fit(alike, &masks, 1, PROBES, &NoProgress),
        Fitted::Untold(0.0)
    );
}

#[test]
fn a_stack_given_farthest_first_is_un_mixed_the_same() {
    let (frames, _) = scene(Light::Linear);
    let (mut forward, mut fl) = (frames.clone(), labels());
    unmix_in(&mut forward, &mut fl, Order::NearestFirst);
    let mut reversed: Vec<Image<u8>> = frames.into_iter().rev().collect();
    let mut rl: Vec<u8> = labels().iter().map(|&l| 2 - l).collect();
    let out = unmix_in(&mut reversed, &mut rl, Order::FarthestFirst);
    assert_eq!(reversed[0], forward[2]);
    assert!(rl.iter().zip(&fl).all(|(&r, &f)| r == 2 - f));
    assert!(out.pairs.iter().all(|p| (p.near, p.far) == (2, 0)));
}

/// The spill of near objects sharing a σ, summed before one blur, is the sum of each
/// one's own blurred spill (to float rounding).
#[test]
fn pairs_sharing_a_blur_are_blurred_once_to_the_same_spill() {
    let (w, h) = (48, 40);
    let plane = |seed: usize| {
        Plane::from_fn(w, h, 1, |x, y, _| {
            ((x * 7 + y * 13 + seed * 31) % 17) as f32 / 16.0
        })
    };
    let masks: Vec<Plane> = (0..5).map(|k| plane(k + 10)).collect();
    let mixed: Vec<Vec<Plane>> = (0..5)
        .map(|k| (0..3).map(|c| plane(3 * k + c)).collect())
        .collect();
    // Near depths 0 and 2 share σ 6 px in far frame 3 and again in far frame 4.
    let pairs = [
        fitted(0, 3, 6.0),
        fitted(1, 3, 4.0),
        fitted(2, 3, 6.0),
        fitted(0, 4, 6.0),
        fitted(1, 4, 5.0),
        fitted(2, 4, 6.0),
    ];
    let factor = 2;
    let mut blurs = Blurs::new(&pairs, 5, 3);
    let mut spills = Vec::new();
    for l in 0..5 {
        let groups = blurs.of(l, &mixed, &masks, factor);
        assert_eq!(groups.len(), [0, 0, 0, 2, 2][l]);
        if l == 3 {
            // Blurred once, kept for far frame 4, and the same blur given there.
            assert_eq!(blurs.kept.len(), 1);
            assert!(Rc::ptr_eq(&blurs.kept[0].1, &groups[1]));
        }
        if !groups.is_empty() {
            spills.push((l, Spill::sum(&groups, factor)));
        }
    }
    assert!(blurs.kept.is_empty());
    // Each far frame's spill is the sum of its pairs' spills, each pair blurred alone.
    let alone = |p: &Pair| {
        let g = Group {
            sigma: p.sigma,
            near: vec![p.near],
        };
        Spill::sum(&[Rc::new(Blurred::of(&mixed, &masks, &g, factor))], factor)
    };
    let close = |got: &Plane, want: Vec<f32>| {
        got.data()
            .iter()
            .zip(want)
            .all(|(g, w)| (g - w).abs() <= 1e-5 * w.abs().max(1.0))
    };
    for (l, spill) in &spills {
        let parts: Vec<Spill> = pairs
            .iter()
            .filter(|p| p.far as usize == *l)
            .map(alone)
            .collect();
        let sum = |f: &dyn Fn(&Spill) -> &Plane| -> Vec<f32> {
            (0..w * h)
                .map(|i| parts.iter().map(|s| f(s).data()[i]).sum())
                .collect()
        };
        assert!(close(&spill.cover, sum(&|s| &s.cover)), "far frame {l}");
        for c in 0..3 {
            assert!(
                close(&spill.colour[c], sum(&|s| &s.colour[c])),
                "far frame {l}, channel {c}"
            );
        }
        assert!(spill.cover.data().iter().any(|&a| a > 0.1));
    }
    // With room for none, nothing is kept: the shared group is blurred again.
    let mut tight = Blurs::new(&pairs, 5, 3);
    tight.limit = 0;
    for l in 0..5 {
        tight.of(l, &mixed, &masks, factor);
        assert!(tight.kept.is_empty());
    }
}

#[test]
fn without_a_step_two_planes_deep_nothing_changes() {
    let (frames, _) = scene(Light::Linear);
    // Two frames, and three whose labels are all one plane.
    for (mut f, mut l) in [
        (
            frames[1..].to_vec(),
            labels().iter().map(|&l| l / 2).collect::<Vec<u8>>(),
        ),
        (frames.clone(), vec![1; SIZE * SIZE]),
    ] {
        let (before, labels_before) = (f.clone(), l.clone());
        let cover = full(f.len());
        let out = unmix(
            &mut f,
            &mut l,
            &[true; SIZE * SIZE],
            1,
            &cover,
            Order::NearestFirst,
            true,
            &NoProgress,
        );
        assert_eq!((out.light, out.changed.iter().sum::<usize>()), (None, 0));
        assert_eq!((f, l), (before, labels_before));
    }
}

#[test]
fn without_the_repairs_the_labels_are_left_as_they_are() {
    let (frames, _) = scene(Light::Linear);
    let run = |repair| {
        let (mut f, mut l) = (frames.clone(), labels());
        let textured = [true; SIZE * SIZE];
        let out = unmix(
            &mut f,
            &mut l,
            &textured,
            1,
            &full(3),
            Order::NearestFirst,
            repair,
            &NoProgress,
        );
        (out, l)
    };
    let (kept, kept_labels) = run(false);
    assert_eq!(kept.repaired, None);
    assert_eq!(kept_labels, labels());
    let (repaired, repaired_labels) = run(true);
    let moved = repaired
        .repaired
        .expect("the repairs were asked for")
        .relabelled;
    let changed = repaired_labels
        .iter()
        .zip(&labels())
        .filter(|(a, b)| a != b)
        .count();
    assert!(moved > 0);
    assert_eq!(moved, changed);
}
