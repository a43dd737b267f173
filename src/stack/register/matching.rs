//! Descriptor matching: nearest neighbour within a search radius, Lowe's ratio test, and a
//! cross-check (each side's best match must be the other).
//!
//! The radius is the hand-held prior: frames of a sweep move by a few percent of the frame, so
//! only keypoints that close can correspond. It cuts the work ~15× against all pairs and leaves
//! fewer look-alikes for the ratio test to trip on.

use super::descriptor::LEN;
use rayon::prelude::*;

/// Keypoint positions (full-resolution pixels) and their descriptors.
pub struct Features {
    pub pos: Vec<(f32, f32)>,
    pub desc: Vec<[f32; LEN]>,
}

/// Buckets of keypoint indices on a square grid of `cell`-sized cells.
struct Grid {
    cell: f32,
    cols: usize,
    rows: usize,
    buckets: Vec<Vec<usize>>,
}

impl Grid {
    fn new(pos: &[(f32, f32)], cell: f32) -> Grid {
        let max = pos
            .iter()
            .fold((0.0f32, 0.0f32), |m, p| (m.0.max(p.0), m.1.max(p.1)));
        let cols = (max.0 / cell) as usize + 1;
        let rows = (max.1 / cell) as usize + 1;
        let mut buckets = vec![Vec::new(); cols * rows];
        for (i, p) in pos.iter().enumerate() {
            let (c, r) = Self::cell_of(p, cell);
            buckets[r.min(rows - 1) * cols + c.min(cols - 1)].push(i);
        }
        Grid {
            cell,
            cols,
            rows,
            buckets,
        }
    }

    fn cell_of(p: &(f32, f32), cell: f32) -> (usize, usize) {
        (
            (p.0.max(0.0) / cell) as usize,
            (p.1.max(0.0) / cell) as usize,
        )
    }

    /// Indices in the 3×3 cells around `p`: a superset of those within one cell of it.
    fn near(&self, p: &(f32, f32)) -> impl Iterator<Item = usize> + '_ {
        let (c, r) = Self::cell_of(p, self.cell);
        let (c, r) = (c.min(self.cols - 1), r.min(self.rows - 1));
        let rs = r.saturating_sub(1)..=(r + 1).min(self.rows - 1);
        rs.flat_map(move |rr| {
            let cs = c.saturating_sub(1)..=(c + 1).min(self.cols - 1);
            cs.flat_map(move |cc| self.buckets[rr * self.cols + cc].iter().copied())
        })
    }
}

/// Lanes of [`dist2`]'s partial sums.
const LANES: usize = 8;

/// Squared distance of two descriptors, summed in [`LANES`] independent partial sums: one
/// running sum of 128 terms waits on each add in turn (a float sum is not reassociated for
/// us), and matching was a third of the global registration's time.
fn dist2(a: &[f32; LEN], b: &[f32; LEN]) -> f32 {
    let mut acc = [0.0f32; LANES];
    for (ca, cb) in a.chunks_exact(LANES).zip(b.chunks_exact(LANES)) {
        for ((s, x), y) in acc.iter_mut().zip(ca).zip(cb) {
            *s += (x - y) * (x - y);
        }
    }
    acc.iter().sum()
}

/// Best and second-best candidate of `q` among `cand` within `radius`: (index, d², second d²).
fn best_two(
    q: &[f32; LEN],
    qp: (f32, f32),
    other: &Features,
    grid: &Grid,
    radius: f32,
) -> Option<(usize, f32, f32)> {
    let r2 = radius * radius;
    let mut best: Option<(usize, f32)> = None;
    let mut second = f32::INFINITY;
    for j in grid.near(&qp) {
        let p = other.pos[j];
        if (p.0 - qp.0).powi(2) + (p.1 - qp.1).powi(2) > r2 {
            continue;
        }
        let d = dist2(q, &other.desc[j]);
        match best {
            Some((_, b)) if d >= b => second = second.min(d),
            _ => {
                if let Some((_, b)) = best {
                    second = b;
                }
                best = Some((j, d));
            }
        }
    }
    best.map(|(j, d)| (j, d, second))
}

/// Pairs (index in `a`, index in `b`) that pass the ratio test (on distances, not squares) and
/// the cross-check.
pub fn match_features(a: &Features, b: &Features, radius: f32, ratio: f32) -> Vec<(usize, usize)> {
    if a.pos.is_empty() || b.pos.is_empty() {
        return Vec::new();
    }
    let (ga, gb) = (Grid::new(&a.pos, radius), Grid::new(&b.pos, radius));
    let r2 = ratio * ratio;
    (0..a.pos.len())
        .into_par_iter()
        .filter_map(|i| {
            let (j, d, second) = best_two(&a.desc[i], a.pos[i], b, &gb, radius)?;
            if d >= r2 * second {
                return None;
            }
            let (back, _, _) = best_two(&b.desc[j], b.pos[j], a, &ga, radius)?;
            (back == i).then_some((i, j))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(k: usize) -> [f32; LEN] {
        let mut d = [0.0; LEN];
        d[k] = 1.0;
        d
    }

    #[test]
    fn the_distance_in_lanes_is_the_squared_distance() {
        let a: [f32; LEN] = std::array::from_fn(|i| (i as f32 * 0.37).sin());
        let b: [f32; LEN] = std::array::from_fn(|i| (i as f32 * 0.11).cos() * 0.5);
        let plain: f64 = a
            .iter()
            .zip(&b)
            .map(|(x, y)| f64::from(x - y).powi(2))
            .sum();
        assert!(
            (f64::from(dist2(&a, &b)) - plain).abs() < 1e-5 * plain,
            "{plain}"
        );
        assert_eq!(dist2(&a, &a), 0.0);
    }

    #[test]
    fn matches_within_radius_only_and_mutually() {
        let a = Features {
            pos: vec![(10.0, 10.0), (50.0, 50.0), (90.0, 10.0)],
            desc: vec![unit(0), unit(1), unit(2)],
        };
        let b = Features {
            // unit(0) moved 5 px: found; unit(1) moved 40 px: beyond the radius; unit(2) twice.
            pos: vec![(15.0, 10.0), (90.0, 50.0), (91.0, 10.0), (89.0, 11.0)],
            desc: vec![unit(0), unit(1), unit(2), unit(2)],
        };
        assert_eq!(match_features(&a, &b, 20.0, 0.8), vec![(0, 0)]);
    }
}
