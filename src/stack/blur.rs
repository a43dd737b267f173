//! Separable Gaussian blur and area downsampling on f32 planes, parallel over rows.

use super::image::Plane;
use rayon::prelude::*;

/// Normalised Gaussian taps, radius ⌈3σ⌉.
pub fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k
}

/// Gaussian blur with replicated edges; σ ≤ 0 returns a copy.
pub fn gaussian_blur(src: &Plane, sigma: f32) -> Plane {
    if sigma <= 0.0 {
        return src.clone();
    }
    convolve_separable(src, &gaussian_kernel(sigma))
}

/// Convolves a single-channel plane with a symmetric odd-length kernel along x then y.
pub fn convolve_separable(src: &Plane, k: &[f32]) -> Plane {
    debug_assert_eq!(src.channels, 1);
    let (w, h) = (src.width, src.height);
    let r = k.len() / 2;
    let mut tmp = vec![0.0f32; w * h];
    tmp.par_chunks_mut(w)
        .zip(src.data.par_chunks(w))
        .for_each(|(out, row)| {
            // Pad once so the inner loop needs no bounds clamping.
            let mut padded = Vec::with_capacity(w + 2 * r);
            padded.extend(std::iter::repeat_n(row[0], r));
            padded.extend_from_slice(row);
            padded.extend(std::iter::repeat_n(row[w - 1], r));
            for (x, o) in out.iter_mut().enumerate() {
                let win = &padded[x..x + k.len()];
                *o = win.iter().zip(k).map(|(a, b)| a * b).sum();
            }
        });
    let mut dst = vec![0.0f32; w * h];
    dst.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        out.fill(0.0);
        for (i, &kv) in k.iter().enumerate() {
            let sy = (y as isize + i as isize - r as isize).clamp(0, h as isize - 1) as usize;
            let row = &tmp[sy * w..sy * w + w];
            for (o, &v) in out.iter_mut().zip(row) {
                *o += kv * v;
            }
        }
    });
    Plane::from_vec(w, h, 1, dst)
}

/// Averages `factor`×`factor` blocks (partial blocks at the right and bottom edges included).
pub fn downsample_area(src: &Plane, factor: usize) -> Plane {
    if factor <= 1 {
        return src.clone();
    }
    let (w, h) = (src.width, src.height);
    let (cw, ch) = (w.div_ceil(factor), h.div_ceil(factor));
    let mut dst = vec![0.0f32; cw * ch];
    dst.par_chunks_mut(cw).enumerate().for_each(|(cy, out)| {
        let y0 = cy * factor;
        let y1 = (y0 + factor).min(h);
        for (cx, o) in out.iter_mut().enumerate() {
            let x0 = cx * factor;
            let x1 = (x0 + factor).min(w);
            let mut s = 0.0;
            for y in y0..y1 {
                s += src.data[y * w + x0..y * w + x1].iter().sum::<f32>();
            }
            *o = s / ((y1 - y0) * (x1 - x0)) as f32;
        }
    });
    Plane::from_vec(cw, ch, 1, dst)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_constant_and_mean() {
        let p = Plane::from_fn(37, 23, 1, |x, y, _| ((x * 7 + y * 13) % 11) as f32);
        let b = gaussian_blur(&p, 2.0);
        let mean = |q: &Plane| q.data.iter().sum::<f32>() / q.data.len() as f32;
        assert!((mean(&p) - mean(&b)).abs() < 0.2);
        let c = gaussian_blur(&Plane::from_fn(9, 9, 1, |_, _, _| 3.0), 1.5);
        assert!(c.data.iter().all(|v| (v - 3.0).abs() < 1e-5));
        // Blurring must reduce variance of a high-frequency pattern.
        let var = |q: &Plane| {
            let m = mean(q);
            q.data.iter().map(|v| (v - m) * (v - m)).sum::<f32>()
        };
        assert!(var(&b) < 0.5 * var(&p));
    }

    #[test]
    fn downsample_averages_blocks() {
        let p = Plane::from_fn(5, 3, 1, |x, _, _| x as f32);
        let d = downsample_area(&p, 2);
        assert_eq!((d.width, d.height), (3, 2));
        assert_eq!(d.data, vec![0.5, 2.5, 4.0, 0.5, 2.5, 4.0]);
    }
}
