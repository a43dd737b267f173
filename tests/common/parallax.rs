//! Local registration under parallax, measured on the simulator's layered stacks: what the
//! register tests assert on and `benches/tools/local_fields.rs` prints.

use focusd::sim::render::{render_scene, true_positions};
use focusd::sim::scene::Scene;
use focusd::sim::{render, SimParams};
use focusd::stack::internal::{register, Plane, Warp};
use focusd::stack::{RegisterParams, Registration};

/// Per frame but the reference: the RMS distance (px) between where the registration and the
/// truth send the reference pixels on which that frame is sharp (its plane is the true depth
/// there, the layer is textured and fills the 5×5 window), with the local fields and with the
/// affines alone.
pub fn sharp_displacement_rms(p: &SimParams, reg: &Registration) -> Vec<(usize, f64, f64)> {
    let scene = Scene::generate(p);
    let r = render_scene(p, &scene);
    let (w, h) = (p.width, p.height);
    let own = &r.owner;
    let depth = r.stack.depth.data();
    (0..p.planes)
        .filter(|&i| i != r.stack.reference)
        .map(|i| {
            let truth = true_positions(p, &scene, &r, i);
            let warp = Warp {
                affine: reg.ref_to_frame[i],
                field: reg.field[i].clone(),
            };
            let (mut with, mut without, mut n) = (0.0, 0.0, 0usize);
            for y in 2..h - 2 {
                for x in 2..w - 2 {
                    let k = y * w + x;
                    let li = own[k];
                    if depth[k] as usize != i
                        || !scene.layers[li].textured
                        || !(y - 2..=y + 2)
                            .all(|yy| (x - 2..=x + 2).all(|xx| own[yy * w + xx] == li))
                    {
                        continue;
                    }
                    let (tx, ty) = truth[k];
                    let (ax, ay) = warp.affine.apply(x as f64, y as f64);
                    let (fx, fy) = warp.apply(x as f64, y as f64);
                    with += (fx - tx).powi(2) + (fy - ty).powi(2);
                    without += (ax - tx).powi(2) + (ay - ty).powi(2);
                    n += 1;
                }
            }
            let n = n.max(1) as f64;
            (i, (with / n).sqrt(), (without / n).sqrt())
        })
        .collect()
}

/// A hand-held 640×480 linear-light stack of 6 planes with `parallax` px of near-layer parallax.
pub fn layered(seed: u64, parallax: f64) -> SimParams {
    SimParams {
        seed,
        handheld: true,
        parallax_px: parallax,
        linear_light: true,
        ..SimParams::default()
    }
}

/// Registers `p`'s stack: per frame the displacement errors where it is sharp (with and without
/// the local fields) and whether it got a field.
pub fn local_effect(p: &SimParams) -> Vec<(usize, f64, f64, bool)> {
    let s = render(p);
    let lumas: Vec<Plane> = s.frames.iter().map(|f| f.luma()).collect();
    let reg = register(&lumas, s.reference, &RegisterParams::default()).unwrap();
    assert!(reg.field[s.reference].is_none());
    sharp_displacement_rms(p, &reg)
        .into_iter()
        .map(|(i, with, without)| (i, with, without, reg.field[i].is_some()))
        .collect()
}
