//! Image quality measures for reports and tests.

use super::image::{Image, Plane, Sample};
use rayon::prelude::*;

/// Tenengrad sharpness (the paper's metric): mean Sobel gradient magnitude of luma, in 8-bit units.
pub fn tenengrad<T: Sample>(img: &Image<T>) -> f64 {
    let l = img.luma();
    tenengrad_plane(&l) * 255.0
}

fn tenengrad_plane(l: &Plane) -> f64 {
    let (w, h) = (l.width, l.height);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let sum: f64 = (1..h - 1)
        .into_par_iter()
        .map(|y| {
            let px = |x: usize, y: usize| l.data[y * w + x];
            let mut s = 0.0f64;
            for x in 1..w - 1 {
                let gx = px(x + 1, y - 1) + 2.0 * px(x + 1, y) + px(x + 1, y + 1)
                    - px(x - 1, y - 1)
                    - 2.0 * px(x - 1, y)
                    - px(x - 1, y + 1);
                let gy = px(x - 1, y + 1) + 2.0 * px(x, y + 1) + px(x + 1, y + 1)
                    - px(x - 1, y - 1)
                    - 2.0 * px(x, y - 1)
                    - px(x + 1, y - 1);
                s += ((gx * gx + gy * gy) as f64).sqrt();
            }
            s
        })
        .sum();
    sum / ((w - 2) * (h - 2)) as f64
}

/// PSNR in dB of `a` against `b` (same geometry), over the interior `margin` pixels in from each
/// edge, on each type's full scale.
pub fn psnr<T: Sample, U: Sample>(a: &Image<T>, b: &Image<U>, margin: usize) -> f64 {
    assert!(a.same_geometry(b), "psnr of images of different geometry");
    let (w, h, ch) = (a.width, a.height, a.channels);
    let mut se = 0.0f64;
    let mut n = 0usize;
    for y in margin..h.saturating_sub(margin) {
        for x in margin..w.saturating_sub(margin) {
            for c in 0..ch {
                let d = (a.at(x, y, c).to_f32() / T::MAX - b.at(x, y, c).to_f32() / U::MAX) as f64;
                se += d * d;
                n += 1;
            }
        }
    }
    let mse = se / n.max(1) as f64;
    10.0 * (1.0 / mse.max(1e-12)).log10()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_and_tenengrad_respond_to_content() {
        let a = Image::<u8>::from_fn(20, 20, 1, |x, _, _| if x < 10 { 0 } else { 255 });
        let b = Image::<u8>::from_fn(20, 20, 1, |x, _, _| if x < 10 { 10 } else { 245 });
        let p = psnr(&a, &b, 0);
        assert!((p - 20.0 * (255.0f64 / 10.0).log10()).abs() < 1e-6);
        assert!(tenengrad(&a) > tenengrad(&b));
        assert_eq!(tenengrad(&Image::<u8>::new(20, 20, 1)), 0.0);
    }
}
