//! Burt–Adelson Gaussian and Laplacian pyramids: seam blending and the max-contrast baseline.

use super::image::Plane;
use rayon::prelude::*;

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

/// Binomial [1 4 6 4 1]/16 blur and 2× subsampling along one axis of a row-major buffer.
fn reduce_rows(src: &[f32], w: usize, h: usize) -> (Vec<f32>, usize) {
    let nw = w.div_ceil(2);
    let mut dst = vec![0.0f32; nw * h];
    dst.par_chunks_mut(nw)
        .zip(src.par_chunks(w))
        .for_each(|(out, row)| {
            let at = |i: isize| row[i.clamp(0, w as isize - 1) as usize];
            for (i, o) in out.iter_mut().enumerate() {
                let c = 2 * i as isize;
                *o = (at(c - 2) + at(c + 2) + 4.0 * (at(c - 1) + at(c + 1)) + 6.0 * at(c)) / 16.0;
            }
        });
    (dst, nw)
}

fn reduce_cols(src: &[f32], w: usize, h: usize) -> (Vec<f32>, usize) {
    let nh = h.div_ceil(2);
    let mut dst = vec![0.0f32; w * nh];
    dst.par_chunks_mut(w).enumerate().for_each(|(i, out)| {
        let row = |r: isize| {
            let r = r.clamp(0, h as isize - 1) as usize;
            &src[r * w..r * w + w]
        };
        let c = 2 * i as isize;
        let (a, b, m, d, e) = (row(c - 2), row(c - 1), row(c), row(c + 1), row(c + 2));
        for x in 0..w {
            out[x] = (a[x] + e[x] + 4.0 * (b[x] + d[x]) + 6.0 * m[x]) / 16.0;
        }
    });
    (dst, nh)
}

/// Blurs and halves a plane.
pub fn reduce(p: &Plane) -> Plane {
    let (tmp, nw) = reduce_rows(&p.data, p.width, p.height);
    let (out, nh) = reduce_cols(&tmp, nw, p.height);
    Plane::from_vec(nw, nh, 1, out)
}

/// Upsamples to `w`×`h` with the interpolating kernel matching `reduce`.
pub fn expand(p: &Plane, w: usize, h: usize) -> Plane {
    let (sw, sh) = (p.width, p.height);
    // Along x.
    let mut tmp = vec![0.0f32; w * sh];
    tmp.par_chunks_mut(w)
        .zip(p.data.par_chunks(sw))
        .for_each(|(out, row)| {
            let at = |i: isize| row[i.clamp(0, sw as isize - 1) as usize];
            for (x, o) in out.iter_mut().enumerate() {
                let i = (x / 2) as isize;
                *o = if x % 2 == 0 {
                    (at(i - 1) + 6.0 * at(i) + at(i + 1)) / 8.0
                } else {
                    (at(i) + at(i + 1)) / 2.0
                };
            }
        });
    // Along y.
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        let row = |r: isize| {
            let r = r.clamp(0, sh as isize - 1) as usize;
            &tmp[r * w..r * w + w]
        };
        let i = (y / 2) as isize;
        if y % 2 == 0 {
            let (a, b, c) = (row(i - 1), row(i), row(i + 1));
            for x in 0..w {
                o[x] = (a[x] + 6.0 * b[x] + c[x]) / 8.0;
            }
        } else {
            let (a, b) = (row(i), row(i + 1));
            for x in 0..w {
                o[x] = (a[x] + b[x]) / 2.0;
            }
        }
    });
    Plane::from_vec(w, h, 1, out)
}

pub fn gaussian_pyramid(p: &Plane, levels: usize) -> Vec<Plane> {
    let mut pyr = vec![p.clone()];
    for _ in 1..levels {
        let next = reduce(pyr.last().unwrap());
        pyr.push(next);
    }
    pyr
}

/// Band-pass levels, finest first; the last level is the low-pass residual.
pub fn laplacian_pyramid(p: &Plane, levels: usize) -> Vec<Plane> {
    let g = gaussian_pyramid(p, levels);
    let mut lap = Vec::with_capacity(levels);
    for l in 0..levels - 1 {
        let up = expand(&g[l + 1], g[l].width, g[l].height);
        let mut band = g[l].clone();
        band.data
            .iter_mut()
            .zip(&up.data)
            .for_each(|(b, u)| *b -= u);
        lap.push(band);
    }
    lap.push(g[levels - 1].clone());
    lap
}

pub fn collapse(pyr: &[Plane]) -> Plane {
    let mut acc = pyr.last().unwrap().clone();
    for band in pyr[..pyr.len() - 1].iter().rev() {
        let mut up = expand(&acc, band.width, band.height);
        up.data
            .iter_mut()
            .zip(&band.data)
            .for_each(|(u, b)| *u += b);
        acc = up;
    }
    acc
}

/// A pyramid of zeros with the geometry of `like`.
pub fn zeros_like(like: &[Plane]) -> Vec<Plane> {
    like.iter()
        .map(|p| Plane::new(p.width, p.height, 1))
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
            .data
            .iter()
            .zip(&back.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err < 1e-5, "max error {err}");
    }

    #[test]
    fn reduce_keeps_constants_and_halves() {
        let p = Plane::from_fn(9, 4, 1, |_, _, _| 0.25);
        let r = reduce(&p);
        assert_eq!((r.width, r.height), (5, 2));
        assert!(r.data.iter().all(|v| (v - 0.25).abs() < 1e-6));
        let e = expand(&r, 9, 4);
        assert!(e.data.iter().all(|v| (v - 0.25).abs() < 1e-6));
    }
}
