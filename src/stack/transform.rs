//! 2-D affine transforms and the transforms JSON shared by the simulator and registration.

use serde::{Deserialize, Serialize};

/// `[[a, b, c], [d, e, f]]`: x' = a·x + b·y + c, y' = d·x + e·y + f, in pixel-centre coordinates
/// (x right, y down, origin at the centre of the top-left pixel).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Affine(pub [[f64; 3]; 2]);

impl Affine {
    pub const IDENTITY: Affine = Affine([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);

    /// Scale `s` and rotation `theta` (radians) about `centre`, then translation `t`.
    pub fn similarity(s: f64, theta: f64, centre: (f64, f64), t: (f64, f64)) -> Affine {
        let (c, sn) = (s * theta.cos(), s * theta.sin());
        let (cx, cy) = centre;
        Affine([
            [c, -sn, cx - c * cx + sn * cy + t.0],
            [sn, c, cy - sn * cx - c * cy + t.1],
        ])
    }

    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let m = &self.0;
        (
            m[0][0] * x + m[0][1] * y + m[0][2],
            m[1][0] * x + m[1][1] * y + m[1][2],
        )
    }

    /// `None` for a singular matrix.
    pub fn inverse(&self) -> Option<Affine> {
        let [[a, b, c], [d, e, f]] = self.0;
        let det = a * e - b * d;
        if det.abs() < 1e-12 || !det.is_finite() {
            return None;
        }
        let (ia, ib, id, ie) = (e / det, -b / det, -d / det, a / det);
        Some(Affine([
            [ia, ib, -(ia * c + ib * f)],
            [id, ie, -(id * c + ie * f)],
        ]))
    }

    /// `self ∘ other`: applies `other` first.
    pub fn compose(&self, other: &Affine) -> Affine {
        let [[a, b, c], [d, e, f]] = self.0;
        let [[p, q, r], [s, t, u]] = other.0;
        Affine([
            [a * p + b * s, a * q + b * t, a * r + b * u + c],
            [d * p + e * s, d * q + e * t, d * r + e * u + f],
        ])
    }

    /// Mean distance between where the two transforms send the corners of a `w`×`h` frame.
    pub fn corner_error(&self, other: &Affine, w: usize, h: usize) -> f64 {
        let (x1, y1) = (w as f64 - 1.0, h as f64 - 1.0);
        let corners = [(0.0, 0.0), (x1, 0.0), (0.0, y1), (x1, y1)];
        corners
            .iter()
            .map(|&(x, y)| {
                let (ax, ay) = self.apply(x, y);
                let (bx, by) = other.apply(x, y);
                ((ax - bx).powi(2) + (ay - by).powi(2)).sqrt()
            })
            .sum::<f64>()
            / 4.0
    }
}

/// One frame's entry in the transforms JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameTransform {
    pub file: String,
    /// Takes reference-frame pixel coordinates to this frame's pixel coordinates.
    pub ref_to_frame: Affine,
}

/// `{"reference": r, "size": [w, h], "frames": [...]}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transforms {
    pub reference: usize,
    pub size: [usize; 2],
    pub frames: Vec<FrameTransform>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_and_compose_round_trip() {
        let a = Affine::similarity(1.03, 0.02, (320.0, 240.0), (5.5, -3.0));
        let id = a.compose(&a.inverse().unwrap());
        assert!(id.corner_error(&Affine::IDENTITY, 640, 480) < 1e-9);
        let (x, y) = a.apply(320.0, 240.0);
        assert!((x - 325.5).abs() < 1e-9 && (y - 237.0).abs() < 1e-9);
        assert!(Affine([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0]])
            .inverse()
            .is_none());
    }

    #[test]
    fn json_format_matches_spec() {
        let t = Transforms {
            reference: 1,
            size: [4, 3],
            frames: vec![FrameTransform {
                file: "a.jpg".into(),
                ref_to_frame: Affine::IDENTITY,
            }],
        };
        let s = serde_json::to_string(&t).unwrap();
        assert_eq!(
            s,
            r#"{"reference":1,"size":[4,3],"frames":[{"file":"a.jpg","ref_to_frame":[[1.0,0.0,0.0],[0.0,1.0,0.0]]}]}"#
        );
        assert_eq!(serde_json::from_str::<Transforms>(&s).unwrap(), t);
    }
}
