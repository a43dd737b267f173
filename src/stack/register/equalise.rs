//! Local defocus equalisation of a frame against the reference.
//!
//! Where one image is sharper than the other, an intensity fit is biased: defocus pulls the
//! silhouette of a curved object inwards by about σ²/2R, so a frame with its near objects more
//! blurred than in the reference looks slightly shrunk there (measured: 0.3–0.7 px at the corners
//! of 640×480 frames; 0.01 px with defocus switched off). Gaussian blurs compose, so blurring the
//! sharper image by √(σ_a² − σ_b²) makes both equally blurred and the bias goes. The amount is
//! chosen per pixel from a small stack of blurs, as whichever pairing matches best locally.

use crate::stack::blur::gaussian_blur_into;
use crate::stack::image::Plane;
use rayon::prelude::*;

/// Blur candidates in pixels of the level: 0, then √2 steps (relative defocus up to ~6 px at
/// the level, ~12–24 px in a phone frame).
pub const SIGMAS: [f32; 8] = [0.0, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.7];
/// Half-width of the window the match is judged over, level pixels. The pairing is judged a
/// level above the one it serves (see [`finer`]), where 3 spans 14 pixels of that one: more
/// accurate, and far cheaper, than judging it on the level itself over a wider window.
const WINDOW: usize = 3;
/// Relative cost added per blur step: with nothing to tell them apart, prefer less blur.
const STEP_PENALTY: f32 = 0.01;

/// A plane blurred by every sigma in [`SIGMAS`].
#[derive(Default)]
pub struct Stack {
    pub layers: Vec<Plane>,
}

impl Stack {
    pub fn new(p: &Plane) -> Stack {
        let mut stack = Stack::default();
        stack.fill(p);
        stack
    }

    /// The stack of `p` in `self`'s planes: a refinement makes one for every frame, each the
    /// same size, and fresh planes for each were a fifth of the page faults of fusing a 10 ×
    /// 1.2 MP stack.
    pub fn fill(&mut self, p: &Plane) {
        let layers = &mut self.layers;
        layers.resize_with(SIGMAS.len(), || Plane::from_vec(0, 0, 1, Vec::new()));
        layers[0].clone_from(p);
        for k in 1..SIGMAS.len() {
            let (a, b) = (SIGMAS[k - 1], SIGMAS[k]);
            let (done, rest) = layers.split_at_mut(k);
            gaussian_blur_into(&done[k - 1], (b * b - a * a).sqrt(), &mut rest[0]);
        }
    }
}

/// Per template pixel, which layer of the template's stack and which of the frame's to compare:
/// at most one of the two is blurred. `frame` holds the frame's stack warped onto the template,
/// already corrected for gain and offset; NaN marks pixels outside the frame.
pub fn choose(template: &Stack, frame: &[Plane]) -> Vec<(u8, u8)> {
    let (w, h) = (template.layers[0].width(), template.layers[0].height());
    let n = SIGMAS.len();
    let pairs: Vec<(u8, u8)> = (0..n)
        .map(|k| (k as u8, 0))
        .chain((1..n).map(|k| (0, k as u8)))
        .collect();
    // Each pair's windowed cost folded into the best so far (the lowest cost, the first pair on
    // a tie) as it comes: holding all fifteen cost planes took 60 bytes a pixel of the level.
    type Best = (Vec<f32>, Vec<u8>);
    let merge = |mut a: Best, b: Best| {
        a.0.par_iter_mut()
            .zip(a.1.par_iter_mut())
            .zip(b.0.par_iter().zip(b.1.par_iter()))
            .for_each(|((ca, ka), (cb, kb))| {
                if cb.total_cmp(ca).then(kb.cmp(ka)).is_lt() {
                    (*ca, *ka) = (*cb, *kb);
                }
            });
        a
    };
    let best = pairs
        .par_iter()
        .enumerate()
        .map(|(k, &(kt, kf))| {
            let (t, f) = (&template.layers[kt as usize], &frame[kf as usize]);
            let d = t
                .data()
                .iter()
                .zip(f.data())
                .map(|(a, b)| if b.is_nan() { 0.0 } else { (a - b) * (a - b) })
                .collect();
            let penalty = 1.0 + STEP_PENALTY * (kt + kf) as f32;
            let mut c = box_sum(&Plane::from_vec(w, h, 1, d), WINDOW);
            c.data_mut().iter_mut().for_each(|v| *v *= penalty);
            (c.into_data(), vec![k as u8; w * h])
        })
        .reduce_with(merge)
        .expect("fifteen pairs");
    best.1.iter().map(|&k| pairs[k as usize]).collect()
}

/// A pairing judged on the level above (`cw`×`ch`) for the level below (`w`×`h`): each pixel
/// takes its parent's, every sigma doubled (two √2 steps), the largest kept where it would
/// run off the candidates. Judging costs fifteen windowed differences a pixel: a quarter of
/// the pixels there.
pub fn finer(pick: &[(u8, u8)], cw: usize, ch: usize, w: usize, h: usize) -> Vec<(u8, u8)> {
    let last = (SIGMAS.len() - 1) as u8;
    let up = |k: u8| if k == 0 { 0 } else { (k + 2).min(last) };
    (0..w * h)
        .map(|i| {
            // Pixel x of the level above sits at 2x here: the nearest parent of x is ⌈x/2⌉.
            let (x, y) = ((i % w).div_ceil(2), (i / w).div_ceil(2));
            let (t, f) = pick[y.min(ch - 1) * cw + x.min(cw - 1)];
            (up(t), up(f))
        })
        .collect()
}

/// Sum over the (2r+1)² window around each pixel, truncated at the borders.
pub(super) fn box_sum(p: &Plane, r: usize) -> Plane {
    let (w, h) = (p.width(), p.height());
    Plane::from_vec(w, h, 1, box_sums(p.data(), w, h, r))
}

/// [`box_sum`] of `w`×`h` samples held in a slice, not a plane.
pub(super) fn box_sums(data: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    assert_eq!(data.len(), w * h, "not {w}x{h} samples");
    // Along rows with a running sum, a group of rows at a time, then down the columns a row at
    // a time (contiguous). Every buffer is written as it is made, none zeroed first: zeroing a
    // plane cost as much as summing it.
    let groups: Vec<Vec<f32>> = data
        .par_chunks(w * ROW_GROUP)
        .map(|src| running_sums(src, w, r))
        .collect();
    let row = |y: usize| &groups[y / ROW_GROUP][y % ROW_GROUP * w..][..w];
    let mut out = Vec::with_capacity(w * h);
    let mut acc = vec![0.0f32; w];
    for y in 0..=r.min(h - 1) {
        acc.iter_mut().zip(row(y)).for_each(|(a, v)| *a += v);
    }
    for y in 0..h {
        out.extend_from_slice(&acc);
        if y + r + 1 < h {
            acc.iter_mut()
                .zip(row(y + r + 1))
                .for_each(|(a, v)| *a += v);
        }
        if y >= r {
            acc.iter_mut().zip(row(y - r)).for_each(|(a, v)| *a -= v);
        }
    }
    out
}

/// Rows whose running sums [`box_sum`] advances together, one vector lane each.
const ROW_GROUP: usize = 8;

/// The (2r+1)-wide running sums along up to [`ROW_GROUP`] rows of width `w` (`src` holds them
/// one after another, and so does the result). A running sum is a chain of dependent adds,
/// bound by their latency rather than by the arithmetic; transposed into lanes, the rows'
/// chains advance together, one vector add a step, each row still summed in its own order: the
/// same sums to the bit, and `box_sum` about twice as fast.
fn running_sums(src: &[f32], w: usize, r: usize) -> Vec<f32> {
    type Lanes = [f32; ROW_GROUP];
    let mut s: Lanes = [0.0; ROW_GROUP];
    let mut rows = src.chunks_exact(w);
    let first = rows.next().expect("a row");
    s[0] = first[..=r.min(w - 1)].iter().sum();
    let mut lanes: Vec<Lanes> = first
        .iter()
        .map(|&v| {
            let mut lane = [0.0; ROW_GROUP];
            lane[0] = v;
            lane
        })
        .collect();
    for (j, row) in (1..).zip(rows) {
        for (lane, v) in lanes.iter_mut().zip(row) {
            lane[j] = *v;
        }
        s[j] = row[..=r.min(w - 1)].iter().sum();
    }
    let add = |s: &mut Lanes, v: &Lanes| s.iter_mut().zip(v).for_each(|(s, v)| *s += v);
    let sub = |s: &mut Lanes, v: &Lanes| s.iter_mut().zip(v).for_each(|(s, v)| *s -= v);
    let sums: Vec<Lanes> = (0..w)
        .map(|x| {
            let sum = s;
            if x + r + 1 < w {
                add(&mut s, &lanes[x + r + 1]);
            }
            if x >= r {
                sub(&mut s, &lanes[x - r]);
            }
            sum
        })
        .collect();
    let mut out = Vec::with_capacity(src.len());
    for j in 0..src.len() / w {
        out.extend(sums.iter().map(|sum| sum[j]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::blur::gaussian_blur;

    #[test]
    fn box_sum_counts_window() {
        let p = Plane::from_fn(7, 5, 1, |_, _, _| 1.0);
        let s = box_sum(&p, 1);
        assert_eq!(s.at(3, 2, 0), 9.0);
        assert_eq!(s.at(0, 0, 0), 4.0);
    }

    #[test]
    fn box_sum_is_the_window_sum_in_groups_of_rows_and_part_groups() {
        // 13 rows: one group of eight and a part group; windows narrower and wider than it.
        let (w, h) = (11, 13);
        let p = Plane::from_fn(w, h, 1, |x, y, _| {
            ((x * 7 + y * 13) % 10) as f32 * 0.1 - 0.3
        });
        for r in [0, 2, 20] {
            let s = box_sum(&p, r);
            for y in 0..h {
                for x in 0..w {
                    let (ys, xs) = (
                        y.saturating_sub(r)..=(y + r).min(h - 1),
                        x.saturating_sub(r)..=(x + r).min(w - 1),
                    );
                    let p = &p;
                    let naive: f32 = ys
                        .flat_map(|yy| xs.clone().map(move |xx| p.at(xx, yy, 0)))
                        .sum();
                    assert!((s.at(x, y, 0) - naive).abs() < 1e-4, "r {r} at {x},{y}");
                }
            }
        }
    }

    /// The lanes and row groups reorder no sum: every output is, to the bit, the plain running
    /// sums along each row and then down each column.
    #[test]
    fn box_sums_are_the_plain_running_sums_to_the_bit() {
        let (w, h) = (37, 29);
        let data: Vec<f32> = (0..w * h)
            .map(|i| ((i * 7919 % 1013) as f32 * 0.37).sin())
            .collect();
        for r in [0, 3, 12, 40] {
            let mut rows = vec![0.0f32; w * h];
            for (row, out) in data.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
                let mut s: f32 = row[..=r.min(w - 1)].iter().sum();
                for (x, o) in out.iter_mut().enumerate() {
                    *o = s;
                    if x + r + 1 < w {
                        s += row[x + r + 1];
                    }
                    if x >= r {
                        s -= row[x - r];
                    }
                }
            }
            let mut want = vec![0.0f32; w * h];
            for x in 0..w {
                let mut s = 0.0f32;
                for y in 0..=r.min(h - 1) {
                    s += rows[y * w + x];
                }
                for y in 0..h {
                    want[y * w + x] = s;
                    if y + r + 1 < h {
                        s += rows[(y + r + 1) * w + x];
                    }
                    if y >= r {
                        s -= rows[(y - r) * w + x];
                    }
                }
            }
            assert_eq!(box_sums(&data, w, h, r), want, "r {r}");
        }
    }

    #[test]
    fn a_pairing_judged_above_serves_below_with_its_sigmas_doubled() {
        // 2×2 above, 4×3 below: column 0 takes parent column 0, columns 1-3 column 1 (the
        // last clamped); rows likewise.
        let above = [(0, 0), (1, 0), (0, 4), (6, 0)];
        let below = finer(&above, 2, 2, 4, 3);
        assert_eq!(below[0], (0, 0));
        assert_eq!(below[1], (3, 0)); // σ 0.7 above is 1.4 here
        assert_eq!(below[3], (3, 0));
        assert_eq!(below[4], (0, 6)); // σ 2 above is 4 here
        assert_eq!(below[2 * 4], (0, 6));
        assert_eq!(below[2 * 4 + 3], (7, 0)); // 8 px is off the candidates: the largest
        for (k, &(t, f)) in below.iter().enumerate() {
            assert!(t == 0 || f == 0, "{k}: both blurred");
        }
        assert_eq!(SIGMAS[3], 2.0 * SIGMAS[1]);
        assert_eq!(SIGMAS[6], 2.0 * SIGMAS[4]);
    }

    #[test]
    fn a_stack_filled_again_is_the_new_planes_stack() {
        let a = Plane::from_fn(40, 30, 1, |x, y, _| ((x * y) % 7) as f32);
        let b = Plane::from_fn(25, 19, 1, |x, y, _| ((x + 3 * y) % 5) as f32);
        let mut s = Stack::new(&a);
        s.fill(&b);
        assert_eq!(s.layers, Stack::new(&b).layers);
        assert_eq!(s.layers.len(), SIGMAS.len());
    }

    #[test]
    fn picks_the_blur_that_makes_them_alike() {
        let sharp = Plane::from_fn(64, 48, 1, |x, y, _| {
            (((x / 3) + (y / 3)) % 2) as f32 * 0.5 + 0.25
        });
        let blurred = gaussian_blur(&sharp, 2.0);
        let t = Stack::new(&sharp);
        let f = Stack::new(&blurred);
        let sel = choose(&t, &f.layers);
        // The template is the sharper one: it gets blurred by ~2, the frame not at all.
        let (kt, kf) = sel[24 * 64 + 32];
        assert_eq!((SIGMAS[kt as usize], kf), (2.0, 0));
        let sel = choose(&f, &t.layers);
        assert_eq!(sel[24 * 64 + 32], (0, 4));
    }
}
