//! Object outlines as signed distance functions, giving anti-aliased coverage at any position.

/// A 2-D point in reference-frame pixel coordinates.
pub type Pt = (f64, f64);

#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Covers the whole plane (the background).
    Everywhere,
    Disc {
        c: Pt,
        r: f64,
    },
    Ellipse {
        c: Pt,
        rx: f64,
        ry: f64,
        angle: f64,
    },
    /// A rectangle of half-size `hw`×`hh` with corners rounded by `radius`, rotated by `angle`.
    RoundRect {
        c: Pt,
        hw: f64,
        hh: f64,
        radius: f64,
        angle: f64,
    },
    /// A simple (non-self-intersecting) polygon, convex or not.
    Polygon {
        pts: Vec<Pt>,
    },
}

/// Rotates `p - c` by `-angle` into the shape's local frame.
#[inline]
fn local(p: Pt, c: Pt, angle: f64) -> Pt {
    let (s, co) = angle.sin_cos();
    let (dx, dy) = (p.0 - c.0, p.1 - c.1);
    (co * dx + s * dy, -s * dx + co * dy)
}

impl Shape {
    /// Signed distance in pixels: negative inside. Exact for discs, rectangles and polygons, a close
    /// approximation near the outline for ellipses.
    pub fn sdf(&self, x: f64, y: f64) -> f64 {
        match self {
            Shape::Everywhere => f64::NEG_INFINITY,
            Shape::Disc { c, r } => (x - c.0).hypot(y - c.1) - r,
            Shape::Ellipse { c, rx, ry, angle } => {
                let (u, v) = local((x, y), *c, *angle);
                let k0 = (u / rx).hypot(v / ry);
                let k1 = (u / (rx * rx)).hypot(v / (ry * ry));
                if k1 < 1e-12 {
                    -rx.min(*ry)
                } else {
                    k0 * (k0 - 1.0) / k1
                }
            }
            Shape::RoundRect {
                c,
                hw,
                hh,
                radius,
                angle,
            } => {
                let (u, v) = local((x, y), *c, *angle);
                let qx = u.abs() - (hw - radius);
                let qy = v.abs() - (hh - radius);
                qx.max(0.0).hypot(qy.max(0.0)) + qx.max(qy).min(0.0) - radius
            }
            Shape::Polygon { pts } => polygon_sdf(pts, (x, y)),
        }
    }

    /// Fraction of the pixel at (x, y) covered: a one-pixel linear ramp across the outline.
    #[inline]
    pub fn coverage(&self, x: f64, y: f64) -> f32 {
        (0.5 - self.sdf(x, y)).clamp(0.0, 1.0) as f32
    }

    /// `[x0, y0, x1, y1]` enclosing the shape (None when unbounded).
    pub fn bbox(&self) -> Option<[f64; 4]> {
        match self {
            Shape::Everywhere => None,
            Shape::Disc { c, r } => Some([c.0 - r, c.1 - r, c.0 + r, c.1 + r]),
            Shape::Ellipse { c, rx, ry, angle } => {
                let (s, co) = angle.sin_cos();
                let ex = (rx * co).hypot(ry * s);
                let ey = (rx * s).hypot(ry * co);
                Some([c.0 - ex, c.1 - ey, c.0 + ex, c.1 + ey])
            }
            Shape::RoundRect {
                c, hw, hh, angle, ..
            } => {
                let (s, co) = angle.sin_cos();
                let ex = hw * co.abs() + hh * s.abs();
                let ey = hw * s.abs() + hh * co.abs();
                Some([c.0 - ex, c.1 - ey, c.0 + ex, c.1 + ey])
            }
            Shape::Polygon { pts } => {
                let mut b = [
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ];
                for &(x, y) in pts {
                    b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
                }
                Some(b)
            }
        }
    }

    /// True when (x, y) may have non-zero coverage (cheap box test with the anti-aliasing ramp).
    #[inline]
    pub fn near(&self, x: f64, y: f64) -> bool {
        match self.bbox() {
            None => true,
            Some(b) => x >= b[0] - 1.0 && x <= b[2] + 1.0 && y >= b[1] - 1.0 && y <= b[3] + 1.0,
        }
    }

    /// Area in pixels (for visibility bookkeeping).
    pub fn area(&self) -> f64 {
        match self {
            Shape::Everywhere => f64::INFINITY,
            Shape::Disc { r, .. } => std::f64::consts::PI * r * r,
            Shape::Ellipse { rx, ry, .. } => std::f64::consts::PI * rx * ry,
            Shape::RoundRect { hw, hh, radius, .. } => {
                4.0 * hw * hh - (4.0 - std::f64::consts::PI) * radius * radius
            }
            Shape::Polygon { pts } => {
                let n = pts.len();
                (0..n)
                    .map(|i| {
                        let (a, b) = (pts[i], pts[(i + 1) % n]);
                        a.0 * b.1 - b.0 * a.1
                    })
                    .sum::<f64>()
                    .abs()
                    / 2.0
            }
        }
    }
}

/// Exact signed distance to a simple polygon (after Inigo Quilez): the nearest edge distance, with
/// the sign from a crossing-number inside test.
fn polygon_sdf(v: &[Pt], p: Pt) -> f64 {
    let n = v.len();
    let dot = |a: Pt, b: Pt| a.0 * b.0 + a.1 * b.1;
    let sub = |a: Pt, b: Pt| (a.0 - b.0, a.1 - b.1);
    let mut d = dot(sub(p, v[0]), sub(p, v[0]));
    let mut s = 1.0;
    let mut j = n - 1;
    for i in 0..n {
        let e = sub(v[j], v[i]);
        let w = sub(p, v[i]);
        let t = (dot(w, e) / dot(e, e)).clamp(0.0, 1.0);
        let b = (w.0 - e.0 * t, w.1 - e.1 * t);
        d = d.min(dot(b, b));
        let c1 = p.1 >= v[i].1;
        let c2 = p.1 < v[j].1;
        let c3 = e.0 * w.1 > e.1 * w.0;
        if (c1 && c2 && c3) || (!c1 && !c2 && !c3) {
            s = -s;
        }
        j = i;
    }
    s * d.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances_and_boxes() {
        let d = Shape::Disc {
            c: (10.0, 10.0),
            r: 5.0,
        };
        assert!((d.sdf(10.0, 10.0) + 5.0).abs() < 1e-12);
        assert!((d.sdf(18.0, 10.0) - 3.0).abs() < 1e-12);
        assert_eq!(d.coverage(15.0, 10.0), 0.5);
        let sq = Shape::Polygon {
            pts: vec![(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)],
        };
        assert!((sq.sdf(5.0, 5.0) + 5.0).abs() < 1e-12);
        assert!((sq.sdf(13.0, 5.0) - 3.0).abs() < 1e-12);
        assert!((sq.area() - 100.0).abs() < 1e-9);
        let rr = Shape::RoundRect {
            c: (0.0, 0.0),
            hw: 10.0,
            hh: 4.0,
            radius: 2.0,
            angle: std::f64::consts::FRAC_PI_2,
        };
        // Rotated by 90°: long axis vertical.
        assert!((rr.sdf(0.0, 12.0) - 2.0).abs() < 1e-9);
        assert!((rr.sdf(6.0, 0.0) - 2.0).abs() < 1e-9);
        let b = rr.bbox().unwrap();
        assert!((b[3] - 10.0).abs() < 1e-9 && (b[2] - 4.0).abs() < 1e-9);
        let e = Shape::Ellipse {
            c: (0.0, 0.0),
            rx: 8.0,
            ry: 4.0,
            angle: 0.0,
        };
        assert!(e.sdf(8.0, 0.0).abs() < 1e-9 && e.sdf(0.0, 4.0).abs() < 1e-9);
        assert!(e.sdf(0.0, 0.0) < 0.0 && e.sdf(9.0, 0.0) > 0.0);
    }
}
