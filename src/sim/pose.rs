//! Hand-held camera poses: per-frame translation, roll and focus breathing.

use super::rng::Rng;
use super::SimParams;
use crate::stack::transform::Affine;

/// A frame's pose relative to the reference frame, as seen in the image of the far background.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Image translation in pixels (x right, y down).
    pub translation: (f64, f64),
    /// Roll about the image centre, radians (positive turns +x towards +y).
    pub rotation: f64,
    /// Magnification relative to the reference frame (focus breathing).
    pub scale: f64,
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        translation: (0.0, 0.0),
        rotation: 0.0,
        scale: 1.0,
    };

    /// The affine taking reference pixel coordinates to this frame's pixel coordinates.
    pub fn ref_to_frame(&self, width: usize, height: usize) -> Affine {
        let centre = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
        Affine::similarity(self.scale, self.rotation, centre, self.translation)
    }
}

/// Absolute breathing magnification of frame `i` of `n`: `1 + breathing·(i/(n−1) − 0.5)`, with
/// the hand-held `breathing` or, on a stack that is not hand-held, `tripod_breathing`.
pub fn breathing_scale(p: &SimParams, i: usize) -> f64 {
    let b = if p.handheld {
        p.breathing
    } else {
        p.tripod_breathing
    };
    1.0 + b * (i as f64 / (p.planes - 1) as f64 - 0.5)
}

/// Draws every frame's pose. Without `handheld` all are the identity but for the lens's
/// `tripod_breathing` (a scale about the centre, relative to the reference's). Otherwise a slow drift
/// across the sweep (up to 60 % of the limits, growing with distance from the reference) plus
/// per-frame tremor (up to 40 %) keep |translation| ≤ max_shift·width and |roll| ≤ max_rotation;
/// the breathing scale is taken relative to the reference frame's, so the reference is exactly
/// the identity even when its absolute breathing scale is not 1 (even plane counts).
pub fn draw_poses(p: &SimParams, seed_stream: u64) -> Vec<Pose> {
    let n = p.planes;
    let reference = (n - 1) / 2;
    if !p.handheld {
        let s_ref = breathing_scale(p, reference);
        return (0..n)
            .map(|i| Pose {
                scale: if i == reference {
                    1.0
                } else {
                    breathing_scale(p, i) / s_ref
                },
                ..Pose::IDENTITY
            })
            .collect();
    }
    let mut rng = Rng::stream(p.seed, seed_stream);
    let tmax = p.max_shift * p.width as f64;
    let rmax = p.max_rotation_deg.to_radians();
    let drift = rng.in_disc(0.6 * tmax);
    let drift_rot = rng.range(-0.6, 0.6) * rmax;
    let span = reference.max(n - 1 - reference).max(1) as f64;
    let s_ref = breathing_scale(p, reference);
    (0..n)
        .map(|i| {
            let jitter = rng.in_disc(0.4 * tmax);
            let jitter_rot = rng.range(-0.4, 0.4) * rmax;
            if i == reference {
                return Pose::IDENTITY;
            }
            let k = (i as f64 - reference as f64) / span;
            Pose {
                translation: (drift.0 * k + jitter.0, drift.1 * k + jitter.1),
                rotation: drift_rot * k + jitter_rot,
                scale: breathing_scale(p, i) / s_ref,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_respect_limits_and_reference_is_identity() {
        for seed in 0..20 {
            let p = SimParams {
                handheld: true,
                planes: 8,
                seed,
                ..SimParams::default()
            };
            let poses = draw_poses(&p, 1);
            assert_eq!(poses[3], Pose::IDENTITY);
            let tmax = p.max_shift * p.width as f64;
            for q in &poses {
                assert!(q.translation.0.hypot(q.translation.1) <= tmax + 1e-9);
                assert!(q.rotation.abs() <= p.max_rotation_deg.to_radians() + 1e-12);
                assert!((q.scale - 1.0).abs() <= p.breathing * 1.01);
            }
            // Breathing is monotonic across the sweep.
            assert!(poses.windows(2).all(|w| w[1].scale > w[0].scale));
        }
        let aligned = draw_poses(&SimParams::default(), 1);
        assert!(aligned.iter().all(|q| *q == Pose::IDENTITY));
    }
}
