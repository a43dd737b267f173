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

/// A smooth displacement added after a global affine, sampled on a regular grid over the
/// reference frame and interpolated bilinearly: what the affine cannot model (parallax of near
/// objects, lens distortion that changes with focus) varies slowly across the frame.
#[derive(Clone, Debug, PartialEq)]
pub struct OffsetField {
    /// Reference pixels between grid nodes; node (i, j) sits at (i·step, j·step).
    pub step: f64,
    pub cols: usize,
    pub rows: usize,
    /// Row-major `(dx, dy)` per node, in frame pixels.
    pub offsets: Vec<(f32, f32)>,
}

impl OffsetField {
    /// The offset at reference point (x, y), clamped to the grid's edge beyond it.
    #[inline]
    pub fn at(&self, x: f64, y: f64) -> (f64, f64) {
        self.between(self.cell(x, self.cols), self.cell(y, self.rows))
    }

    /// The grid cell along an axis of `nodes` nodes that reference coordinate `x` falls in, and
    /// how far across it: apart so that a raster scan finds each column's once per frame and
    /// each row's once per row, not two divisions and four clamps per pixel.
    #[inline]
    pub fn cell(&self, x: f64, nodes: usize) -> (usize, f64) {
        let g = (x / self.step).clamp(0.0, (nodes - 1) as f64);
        let i = (g as usize).min(nodes.saturating_sub(2));
        (i, g - i as f64)
    }

    /// The offset between the nodes of `cell`s along x (`cols`) and along y (`rows`).
    #[inline]
    pub fn between(&self, (i, fx): (usize, f64), (j, fy): (usize, f64)) -> (f64, f64) {
        let node = |i: usize, j: usize| {
            let (dx, dy) = self.offsets[j.min(self.rows - 1) * self.cols + i.min(self.cols - 1)];
            (dx as f64, dy as f64)
        };
        let lerp =
            |a: (f64, f64), b: (f64, f64), t: f64| (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        let top = lerp(node(i, j), node(i + 1, j), fx);
        let bottom = lerp(node(i, j + 1), node(i + 1, j + 1), fx);
        lerp(top, bottom, fy)
    }

    /// The length of the offset that a share `q` (0..=1) of the nodes stay within, frame pixels:
    /// how much local motion the field holds.
    pub fn reach(&self, q: f64) -> f64 {
        let mut m: Vec<f32> = self.offsets.iter().map(|o| o.0.hypot(o.1)).collect();
        if m.is_empty() {
            return 0.0;
        }
        let k = rank(m.len(), q);
        *m.select_nth_unstable_by(k, f32::total_cmp).1 as f64
    }
}

/// Which of `n` (at least 1) values, sorted ascending, is their share-`q` (0..=1) quantile, as
/// [`OffsetField::reach`] takes it.
pub fn rank(n: usize, q: f64) -> usize {
    ((n - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize
}

/// Where each reference pixel lies in a frame: the global affine plus, optionally, a smooth
/// offset field.
#[derive(Clone, Debug, PartialEq)]
pub struct Warp {
    pub affine: Affine,
    pub field: Option<OffsetField>,
}

impl Warp {
    pub fn affine(affine: Affine) -> Warp {
        Warp {
            affine,
            field: None,
        }
    }

    #[inline(always)]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let (u, v) = self.affine.apply(x, y);
        match &self.field {
            Some(f) => {
                let (dx, dy) = f.at(x, y);
                (u + dx, v + dy)
            }
            None => (u, v),
        }
    }

    /// The frame rows (as a range of y coordinates, not rounded) that reference rows `rows`,
    /// `width` pixels wide, map into: the affine's extremes lie on the corners of the
    /// rectangle, and the field adds at most its largest offset (`reach` the field's
    /// [`OffsetField::reach`] at 1, passed in as it is made once per frame).
    pub fn frame_rows(&self, rows: std::ops::Range<usize>, width: usize, reach: f64) -> (f64, f64) {
        let (x1, y0, y1) = (
            width.saturating_sub(1) as f64,
            rows.start as f64,
            rows.end as f64 - 1.0,
        );
        let v = [(0.0, y0), (x1, y0), (0.0, y1), (x1, y1)].map(|(x, y)| self.affine.apply(x, y).1);
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        (lo - reach, hi + reach)
    }

    /// [`Warp::apply`] for a raster scan of a `width`-pixel-wide reference: the field's cells
    /// along x are found once for every row.
    pub fn raster(&self, width: usize) -> Raster<'_> {
        let cols = match &self.field {
            Some(f) => (0..width).map(|x| f.cell(x as f64, f.cols)).collect(),
            None => Vec::new(),
        };
        Raster { warp: self, cols }
    }
}

/// A [`Warp`] with its field's cells along x found ([`Warp::raster`]).
pub struct Raster<'a> {
    warp: &'a Warp,
    cols: Vec<(usize, f64)>,
}

impl Raster<'_> {
    /// [`Warp::apply`] at pixel x of row `y`, as a function of x. The field is interpolated
    /// down to the row once, at every node column, and then only along x per pixel: the same
    /// bilinear interpolation in the other order (equal but for rounding), in half the work of
    /// [`OffsetField::between`] a pixel, which with this closure was 2–3 % of a parallax
    /// stack's CPU time.
    #[inline]
    pub fn row(&self, y: usize) -> impl Fn(usize) -> (f64, f64) + '_ {
        let yf = y as f64;
        let along: Vec<(f64, f64)> = match &self.warp.field {
            Some(f) => {
                let row = f.cell(yf, f.rows);
                (0..f.cols).map(|i| f.between((i, 0.0), row)).collect()
            }
            None => Vec::new(),
        };
        move |x| {
            let (u, v) = self.warp.affine.apply(x as f64, yf);
            if along.is_empty() {
                return (u, v);
            }
            let (i, fx) = self.cols[x];
            let (a, b) = (along[i], along[(i + 1).min(along.len() - 1)]);
            (u + a.0 + (b.0 - a.0) * fx, v + a.1 + (b.1 - a.1) * fx)
        }
    }
}

/// One frame's entry in the transforms JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameTransform {
    pub file: String,
    /// Takes reference-frame pixel coordinates to this frame's pixel coordinates.
    pub ref_to_frame: Affine,
    /// How far the local field the fuse added to the affine reaches; absent where the frame kept
    /// none (the affine stands alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local_field: Option<FieldExtent>,
}

/// The size of a local offset field, in frame pixels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldExtent {
    /// 99th percentile of the displacement over the field's nodes.
    pub p99_px: f64,
    /// The largest displacement.
    pub max_px: f64,
    /// Share of the nodes displaced by more than half a pixel.
    pub moved_share: f64,
}

impl FieldExtent {
    pub fn of(f: &OffsetField) -> FieldExtent {
        let moved = f.offsets.iter().filter(|o| o.0.hypot(o.1) > 0.5).count();
        FieldExtent {
            p99_px: f.reach(0.99),
            max_px: f.reach(1.0),
            moved_share: moved as f64 / f.offsets.len().max(1) as f64,
        }
    }
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
                local_field: None,
            }],
        };
        let s = serde_json::to_string(&t).unwrap();
        assert_eq!(
            s,
            r#"{"reference":1,"size":[4,3],"frames":[{"file":"a.jpg","ref_to_frame":[[1.0,0.0,0.0],[0.0,1.0,0.0]]}]}"#
        );
        assert_eq!(serde_json::from_str::<Transforms>(&s).unwrap(), t);
    }

    #[test]
    fn field_interpolates_between_nodes_and_clamps_outside() {
        let f = OffsetField {
            step: 10.0,
            cols: 2,
            rows: 2,
            offsets: vec![(0.0, 0.0), (1.0, 0.0), (0.0, 2.0), (1.0, 2.0)],
        };
        assert_eq!(f.at(5.0, 5.0), (0.5, 1.0));
        assert_eq!(f.at(-3.0, 40.0), (0.0, 2.0));
        assert_eq!(f.reach(0.0), 0.0);
        assert!((f.reach(1.0) - 5f64.sqrt()).abs() < 1e-6);
        let w = Warp {
            affine: Affine([[1.0, 0.0, 3.0], [0.0, 1.0, 0.0]]),
            field: Some(f),
        };
        assert_eq!(w.apply(10.0, 0.0), (14.0, 0.0));
        let raster = w.raster(30);
        for y in [0, 7, 25] {
            let at = raster.row(y);
            for x in [0, 3, 12, 29] {
                assert_eq!(at(x), w.apply(x as f64, y as f64), "({x}, {y})");
            }
        }
        assert_eq!(Warp::affine(Affine::IDENTITY).apply(2.0, 3.0), (2.0, 3.0));
        // A raster scan interpolates in the other order: the same offsets but for rounding.
        let w = Warp {
            affine: Affine([[1.01, 0.02, 3.0], [-0.01, 0.99, 1.5]]),
            field: Some(OffsetField {
                step: 7.0,
                cols: 4,
                rows: 3,
                offsets: (0..12)
                    .map(|i| (i as f32 * 0.37 - 2.0, (i * i) as f32 * 0.05))
                    .collect(),
            }),
        };
        let raster = w.raster(25);
        for y in [0, 4, 9, 13, 20] {
            let at = raster.row(y);
            for x in 0..25 {
                let ((u, v), (eu, ev)) = (at(x), w.apply(x as f64, y as f64));
                assert!((u - eu).abs() < 1e-9 && (v - ev).abs() < 1e-9, "({x}, {y})");
            }
        }
    }
}
