//! Burt–Adelson Gaussian and Laplacian pyramids: seam blending and the max-contrast baseline.

use super::blur::par_strips;
use super::image::Plane;

/// Levels so that the coarsest level is still at least ~8 pixels on its short side.
pub fn levels_for(width: usize, height: usize) -> usize {
    let mut n = 1;
    let (mut w, mut h) = (width, height);
    while w.min(h) >= 16 && n < 9 {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        n += 1;
    }
    n
}

/// What [`reduce`] reads a row at a time: a plane's own rows, or rows a source makes on
/// demand (a frame's luma, see `register`), so the source need not be a plane at all. Unlike
/// `blur`'s row streams, a plane's rows are lent, not copied: compose reduces planes a lot.
pub trait RowSource: Sync {
    /// Width and height.
    fn size(&self) -> (usize, usize);
    /// Row `y`: borrowed, or made in `buf` (as wide as the rows) and returned.
    fn row<'a>(&'a self, y: usize, buf: &'a mut [f32]) -> &'a [f32];
}

impl RowSource for Plane {
    fn size(&self) -> (usize, usize) {
        (self.width(), self.height())
    }

    fn row<'a>(&'a self, y: usize, _: &'a mut [f32]) -> &'a [f32] {
        &self.data()[y * self.width()..][..self.width()]
    }
}

/// Blurs and halves a plane (or any [`RowSource`]).
///
/// Streams like the blur: each strip keeps the five horizontally reduced rows its output rows
/// need in a ring, so there is no half-width intermediate plane.
pub fn reduce(p: &impl RowSource) -> Plane {
    let (w, h) = p.size();
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0f32; nw * nh];
    reduce_into(p, &mut out);
    Plane::from_vec(nw, nh, 1, out)
}

/// `reduce` into an existing buffer of the halved size.
fn reduce_into(p: &impl RowSource, out: &mut [f32]) {
    let (w, h) = p.size();
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    assert_eq!(out.len(), nw * nh, "reduced buffer size");
    par_strips(out, nw, nh, |i0, strip| {
        // Source row s, reduced along x, lives in slot s % 5.
        let mut ring = vec![0.0f32; 5 * nw];
        let (mut even, mut odd, mut buf) = (Vec::new(), Vec::new(), vec![0.0f32; w]);
        let mut next = (2 * i0).saturating_sub(2);
        for (i, out) in (i0..).zip(strip.chunks_exact_mut(nw)) {
            while next <= (2 * i + 2).min(h - 1) {
                let dst = &mut ring[next % 5 * nw..][..nw];
                reduce_row(p.row(next, &mut buf), dst, &mut even, &mut odd);
                next += 1;
            }
            let row = |s: usize| &ring[s.min(h - 1) % 5 * nw..][..nw];
            let (a, b, m) = (
                row((2 * i).saturating_sub(2)),
                row((2 * i).saturating_sub(1)),
                row(2 * i),
            );
            let (d, e) = (row(2 * i + 1), row(2 * i + 2));
            let taps = a.iter().zip(b).zip(m).zip(d).zip(e);
            for (o, ((((a, b), m), d), e)) in out.iter_mut().zip(taps) {
                *o = (a + e + 4.0 * (b + d) + 6.0 * m) / 16.0;
            }
        }
    });
}

/// Binomial [1 4 6 4 1]/16 blur and 2× subsampling of one row with replicated edges.
///
/// The edge-padded row is split into its even and odd samples (`even`, `odd`: scratch) so the
/// taps are unit-stride slices and the loop vectorises with no clamping inside.
fn reduce_row(row: &[f32], out: &mut [f32], even: &mut Vec<f32>, odd: &mut Vec<f32>) {
    let (w, nw) = (row.len(), out.len());
    // padded[j + 2] = row[clamp(j)]; even[m] = padded[2m], odd[m] = padded[2m + 1].
    for v in [&mut *even, &mut *odd] {
        v.clear();
        v.resize(nw + 2, row[w - 1]);
        v[0] = row[0];
    }
    for ((e, o), pair) in even[1..]
        .iter_mut()
        .zip(&mut odd[1..])
        .zip(row.chunks_exact(2))
    {
        *e = pair[0];
        *o = pair[1];
    }
    let taps = even
        .iter()
        .zip(&even[1..])
        .zip(&even[2..])
        .zip(odd.iter().zip(&odd[1..]));
    for (o, (((a, m), e), (b, d))) in out.iter_mut().zip(taps) {
        *o = (a + e + 4.0 * (b + d) + 6.0 * m) / 16.0;
    }
}

/// Upsamples to `w`×`h` with the interpolating kernel matching `reduce`.
pub fn expand(p: &Plane, w: usize, h: usize) -> Plane {
    let mut out = vec![0.0f32; w * h];
    expand_with(p, w, h, &mut out, |o, u| *o = u);
    Plane::from_vec(w, h, 1, out)
}

/// Expands `p` to `w`×`h` and combines each expanded value `u` into `out` with `f(out, u)`, so
/// Laplacian bands and collapses are formed in place without a full-size expanded plane.
/// Streams like `reduce`, with a ring of the three x-expanded source rows an output row needs.
fn expand_with(p: &Plane, w: usize, h: usize, out: &mut [f32], f: impl Fn(&mut f32, f32) + Sync) {
    let (sw, sh) = (p.width(), p.height());
    let clamp = |s: usize| s.min(sh - 1);
    par_strips(out, w, h, |y0, strip| {
        // Source row s, expanded along x, lives in slot s % 3.
        let mut ring = vec![0.0f32; 3 * w];
        let mut padded = Vec::new();
        let mut next = clamp((y0 / 2).saturating_sub(1));
        for (y, out) in (y0..).zip(strip.chunks_exact_mut(w)) {
            let i = y / 2;
            while next <= clamp(i + 1) {
                expand_row(
                    &p.data()[next * sw..][..sw],
                    &mut ring[next % 3 * w..][..w],
                    &mut padded,
                );
                next += 1;
            }
            let row = |s: usize| &ring[clamp(s) % 3 * w..][..w];
            if y % 2 == 0 {
                let (a, b, c) = (row(i.saturating_sub(1)), row(i), row(i + 1));
                for (((o, a), b), c) in out.iter_mut().zip(a).zip(b).zip(c) {
                    f(o, (a + 6.0 * b + c) / 8.0);
                }
            } else {
                for ((o, a), b) in out.iter_mut().zip(row(i)).zip(row(i + 1)) {
                    f(o, (a + b) / 2.0);
                }
            }
        }
    });
}

/// Expands one row to `out.len()` samples (replicated edges), two outputs per source sample so
/// the loop has no parity test or clamping; `padded` is scratch.
fn expand_row(row: &[f32], out: &mut [f32], padded: &mut Vec<f32>) {
    let (sw, w) = (row.len(), out.len());
    // padded[j + 1] = row[clamp(j)], long enough for every output's right tap.
    padded.clear();
    padded.push(row[0]);
    padded.extend_from_slice(row);
    padded.resize((w / 2 + 3).max(sw + 2), row[sw - 1]);
    let taps = padded.iter().zip(&padded[1..]).zip(&padded[2..]);
    let mut pairs = out.chunks_exact_mut(2);
    for (o, ((a, b), c)) in pairs.by_ref().zip(taps) {
        o[0] = (a + 6.0 * b + c) / 8.0;
        o[1] = (b + c) / 2.0;
    }
    if let [o] = pairs.into_remainder() {
        let i = w / 2;
        *o = (padded[i] + 6.0 * padded[i + 1] + padded[i + 2]) / 8.0;
    }
}

/// `p` followed by zero planes of the successively halved sizes: a pyramid's buffers, to be
/// filled (and refilled for the next frame) in place.
pub(crate) fn with_levels(p: Plane, levels: usize) -> Vec<Plane> {
    let mut pyr = Vec::with_capacity(levels);
    pyr.push(p);
    for _ in 1..levels {
        let last = pyr.last().unwrap();
        let next = Plane::new(last.width().div_ceil(2), last.height().div_ceil(2), 1);
        pyr.push(next);
    }
    pyr
}

/// Recomputes the Gaussian levels 1.. of `pyr` from level 0.
pub(crate) fn fill_gaussian(pyr: &mut [Plane]) {
    for l in 1..pyr.len() {
        let (fine, coarse) = pyr.split_at_mut(l);
        reduce_into(&fine[l - 1], coarse[0].data_mut());
    }
}

/// Band-pass levels, finest first; the last level is the low-pass residual.
pub fn laplacian_pyramid(p: &Plane, levels: usize) -> Vec<Plane> {
    let mut pyr = with_levels(p.clone(), levels);
    fill_laplacian(&mut pyr);
    pyr
}

/// Turns level 0 of `pyr` into the Laplacian pyramid of that plane, in place.
pub(crate) fn fill_laplacian(pyr: &mut [Plane]) {
    fill_gaussian(pyr);
    for l in 0..pyr.len() - 1 {
        // Level l + 1 is still Gaussian here: bands are formed finest first.
        let (fine, coarse) = pyr.split_at_mut(l + 1);
        let band = &mut fine[l];
        let (w, h) = (band.width(), band.height());
        expand_with(&coarse[0], w, h, band.data_mut(), |b, u| *b -= u);
    }
}

pub fn collapse(pyr: &[Plane]) -> Plane {
    collapse_of(pyr.to_vec())
}

/// `collapse` taking the pyramid: each band's buffer accumulates the expanded coarser sum.
pub(crate) fn collapse_of(mut pyr: Vec<Plane>) -> Plane {
    let mut acc = pyr.pop().expect("at least one level");
    while let Some(mut band) = pyr.pop() {
        let (w, h) = (band.width(), band.height());
        expand_with(&acc, w, h, band.data_mut(), |b, u| *b += u);
        acc = band;
    }
    acc
}

/// A pyramid of zeros with the geometry of `like`.
pub fn zeros_like(like: &[Plane]) -> Vec<Plane> {
    like.iter()
        .map(|p| Plane::new(p.width(), p.height(), 1))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laplacian_round_trip_is_exact() {
        let p = Plane::from_fn(37, 29, 1, |x, y, _| ((x * 31 + y * 17) % 13) as f32 / 13.0);
        let n = levels_for(37, 29);
        assert_eq!(n, 2);
        let pyr = laplacian_pyramid(&p, 4);
        assert_eq!(pyr.len(), 4);
        let back = collapse(&pyr);
        let err = p
            .data()
            .iter()
            .zip(back.data())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err < 1e-5, "max error {err}");
    }

    #[test]
    fn reduce_keeps_constants_and_halves() {
        let p = Plane::from_fn(9, 4, 1, |_, _, _| 0.25);
        let r = reduce(&p);
        assert_eq!((r.width(), r.height()), (5, 2));
        assert!(r.data().iter().all(|v| (v - 0.25).abs() < 1e-6));
        let e = expand(&r, 9, 4);
        assert!(e.data().iter().all(|v| (v - 0.25).abs() < 1e-6));
    }

    /// Direct clamped-index forms of `reduce` and `expand`, in the same float operation order.
    fn reference_reduce(p: &Plane) -> Plane {
        let h = p.height() as isize;
        let at = |q: &Plane, x: isize, y: isize| {
            q.at(
                x.clamp(0, q.width() as isize - 1) as usize,
                y.clamp(0, h - 1) as usize,
                0,
            )
        };
        let five =
            |a: f32, b: f32, m: f32, d: f32, e: f32| (a + e + 4.0 * (b + d) + 6.0 * m) / 16.0;
        let tmp = Plane::from_fn(p.width().div_ceil(2), p.height(), 1, |x, y, _| {
            let (c, y) = (2 * x as isize, y as isize);
            five(
                at(p, c - 2, y),
                at(p, c - 1, y),
                at(p, c, y),
                at(p, c + 1, y),
                at(p, c + 2, y),
            )
        });
        Plane::from_fn(tmp.width(), p.height().div_ceil(2), 1, |x, y, _| {
            let (x, c) = (x as isize, 2 * y as isize);
            five(
                at(&tmp, x, c - 2),
                at(&tmp, x, c - 1),
                at(&tmp, x, c),
                at(&tmp, x, c + 1),
                at(&tmp, x, c + 2),
            )
        })
    }

    fn reference_expand(p: &Plane, w: usize, h: usize) -> Plane {
        let at =
            |q: &Plane, x: usize, y: usize| q.at(x.min(q.width() - 1), y.min(q.height() - 1), 0);
        let tmp = Plane::from_fn(w, p.height(), 1, |x, y, _| {
            let i = x / 2;
            match x % 2 {
                0 => (at(p, i.saturating_sub(1), y) + 6.0 * at(p, i, y) + at(p, i + 1, y)) / 8.0,
                _ => (at(p, i, y) + at(p, i + 1, y)) / 2.0,
            }
        });
        Plane::from_fn(w, h, 1, |x, y, _| {
            let i = y / 2;
            match y % 2 {
                0 => {
                    (at(&tmp, x, i.saturating_sub(1)) + 6.0 * at(&tmp, x, i) + at(&tmp, x, i + 1))
                        / 8.0
                }
                _ => (at(&tmp, x, i) + at(&tmp, x, i + 1)) / 2.0,
            }
        })
    }

    #[test]
    fn streaming_kernels_match_direct_forms_exactly() {
        for (w, h) in [(1, 1), (2, 3), (5, 4), (37, 29), (64, 70), (131, 150)] {
            let p = Plane::from_fn(w, h, 1, |x, y, _| ((x * 31 + y * 17) % 13) as f32 / 13.0);
            let r = reduce(&p);
            assert_eq!(r, reference_reduce(&p), "reduce {w}x{h}");
            for (ew, eh) in [(2 * w, 2 * h), (2 * w - 1, 2 * h - 1), (2 * w + 3, h)] {
                assert_eq!(
                    expand(&p, ew, eh),
                    reference_expand(&p, ew, eh),
                    "expand {w}x{h} to {ew}x{eh}"
                );
            }
        }
    }
}
