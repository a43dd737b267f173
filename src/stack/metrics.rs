//! Image quality measures for reports and tests.

use super::align::keys;
use super::image::{Image, Plane, Sample};
use rayon::prelude::*;

/// Tenengrad sharpness (the paper's metric): mean Sobel gradient magnitude of luma, in 8-bit units.
///
/// Luma is made a band of rows at a time (with a row above and below), not for the whole image:
/// the CLI reports every input frame's sharpness, and a whole float plane a frame would be a
/// large share of a fuse's freshly faulted (zeroed) pages.
pub fn tenengrad<T: Sample>(img: &Image<T>) -> f64 {
    const BAND: usize = 64;
    let (w, h) = (img.width(), img.height());
    if w < 3 || h < 3 {
        return 0.0;
    }
    let sum: f64 = (1..h - 1)
        .into_par_iter()
        .step_by(BAND)
        .map(|y0| {
            let y1 = (y0 + BAND).min(h - 1);
            gradient_sum(&img.luma_rows(y0 - 1..y1 + 1))
        })
        .sum();
    sum / ((w - 2) * (h - 2)) as f64 * 255.0
}

/// Σ Sobel gradient magnitude over the pixels of `l` that have all eight neighbours. Each row
/// sums in [`LANES`] single-precision lanes, which the compiler vectorises, and rows add up in
/// double precision: a pixel at a time in double precision costs a visible share of a fuse's CPU
/// time, for a figure only the log shows.
fn gradient_sum(l: &Plane) -> f64 {
    const LANES: usize = 8;
    let w = l.width();
    let mut s = 0.0f64;
    let mut mag = vec![0.0f32; w - 2];
    for y in 1..l.height() - 1 {
        let row = |dy: usize| &l.data()[(y + dy - 1) * w..][..w];
        let (a, b, c) = (row(0), row(1), row(2));
        for (x, m) in mag.iter_mut().enumerate() {
            // Pixel x + 1 from its neighbours at x, x + 1 and x + 2.
            let gx = a[x + 2] + 2.0 * b[x + 2] + c[x + 2] - a[x] - 2.0 * b[x] - c[x];
            let gy = c[x] + 2.0 * c[x + 1] + c[x + 2] - a[x] - 2.0 * a[x + 1] - a[x + 2];
            *m = (gx * gx + gy * gy).sqrt();
        }
        let mut lanes = [0.0f32; LANES];
        let mut chunks = mag.chunks_exact(LANES);
        for chunk in &mut chunks {
            lanes.iter_mut().zip(chunk).for_each(|(a, &v)| *a += v);
        }
        let rest: f32 = chunks.remainder().iter().sum();
        s += lanes.iter().map(|&v| f64::from(v)).sum::<f64>() + f64::from(rest);
    }
    s
}

/// PSNR in dB of `a` against `b` (same geometry), over the interior `margin` pixels in from each
/// edge, on each type's full scale.
pub fn psnr<T: Sample, U: Sample>(a: &Image<T>, b: &Image<U>, margin: usize) -> f64 {
    let (w, h) = (a.width(), a.height());
    psnr_where(a, b, |x, y| {
        (margin..w.saturating_sub(margin)).contains(&x)
            && (margin..h.saturating_sub(margin)).contains(&y)
    })
}

/// PSNR in dB of `a` against `b` (same geometry) over the pixels (x, y) where `keep` holds, on
/// each type's full scale; infinite-free (a perfect match gives 120 dB).
pub fn psnr_where<T: Sample, U: Sample>(
    a: &Image<T>,
    b: &Image<U>,
    keep: impl Fn(usize, usize) -> bool,
) -> f64 {
    assert!(a.same_geometry(b), "psnr of images of different geometry");
    let (w, h, ch) = (a.width(), a.height(), a.channels());
    let mut se = 0.0f64;
    let mut n = 0usize;
    for y in 0..h {
        for x in (0..w).filter(|&x| keep(x, y)) {
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

/// The band around depth steps: every pixel within `radius` px (Euclidean) of a nonzero pixel of
/// `steps` (one channel), row-major. With `radius` = 3σ of the largest defocus blur, the band
/// holds every pixel a defocused near object can spill onto (halos).
pub fn step_band(steps: &Image<u8>, radius: f64) -> Vec<bool> {
    let (w, h) = (steps.width(), steps.height());
    let r = radius.max(0.0).floor() as isize;
    let r2 = radius * radius;
    let mut band = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if steps.at(x, y, 0) == 0 {
                continue;
            }
            for dy in -r..=r {
                let v = y as isize + dy;
                if v < 0 || v >= h as isize {
                    continue;
                }
                for dx in -r..=r {
                    let u = x as isize + dx;
                    if u >= 0 && u < w as isize && ((dx * dx + dy * dy) as f64) <= r2 {
                        band[v as usize * w + u as usize] = true;
                    }
                }
            }
        }
    }
    band
}

/// The aligned depth oracle: each pixel copied from the frame `labels` names (the frame focused
/// at its true depth), sampled where `at(frame, x, y)` says that frame shows it (its true motion,
/// parallax included), with `undo(frame, channel, value)` taking a sample (0..=255) back to the
/// exposure of the truth (the frame's gain undone). The best any labelling of perfectly
/// registered frames can do, and so a ceiling only if it loses nothing itself: the frames are
/// sampled bicubically (Keys, as the engine warps them; bilinear sampling softens them once more,
/// which would put the oracle below the fused images it should bound).
pub fn depth_oracle(
    frames: &[Image<u8>],
    labels: &[u8],
    at: impl Fn(usize, usize, usize) -> (f32, f32) + Sync,
    undo: impl Fn(usize, usize, f32) -> f32 + Sync,
) -> Image<u8> {
    let w = frames[0].width();
    let one = |x: usize, y: usize| {
        let k = labels[y * w + x] as usize;
        k..k + 1
    };
    oracle(frames, at, undo, one, |_, _, _| 0)
}

/// The per-pixel best frame: each pixel copied from whichever frame, sampled and undone as in
/// [`depth_oracle`], is nearest to `truth` there (squared error over the channels). A bound on
/// every output that chooses among the frames pixel by pixel, however it chooses: it also picks
/// the frame whose noise happens to lie nearest, which no real choice can, so only un-mixing,
/// denoising or deblurring (pixels no frame holds) can score above it.
pub fn best_frame_oracle(
    frames: &[Image<u8>],
    truth: &Image<u8>,
    at: impl Fn(usize, usize, usize) -> (f32, f32) + Sync,
    undo: impl Fn(usize, usize, f32) -> f32 + Sync,
) -> Image<u8> {
    let error = |x: usize, y: usize, px: &[u8]| -> u32 {
        px.iter()
            .enumerate()
            .map(|(c, &v)| (v as i32 - truth.at(x, y, c) as i32).pow(2) as u32)
            .sum()
    };
    oracle(frames, at, undo, |_, _| 0..frames.len(), error)
}

/// Each pixel from whichever of the frames `candidates(x, y)` gives the least
/// `error(x, y, sample)` (the first on a tie), each frame sampled bicubically where `at` says it
/// shows the pixel, its gain undone by `undo`. Only the candidates are sampled.
fn oracle(
    frames: &[Image<u8>],
    at: impl Fn(usize, usize, usize) -> (f32, f32) + Sync,
    undo: impl Fn(usize, usize, f32) -> f32 + Sync,
    candidates: impl Fn(usize, usize) -> std::ops::Range<usize> + Sync,
    error: impl Fn(usize, usize, &[u8]) -> u32 + Sync,
) -> Image<u8> {
    let f0 = &frames[0];
    let (w, h, ch) = (f0.width(), f0.height(), f0.channels());
    let mut data = vec![0u8; w * h * ch];
    data.par_chunks_mut(w * ch)
        .enumerate()
        .for_each(|(y, row)| {
            let mut sample = vec![0u8; ch];
            for x in 0..w {
                let mut best = u32::MAX;
                for k in candidates(x, y) {
                    let f = &frames[k];
                    let (u, v) = at(k, x, y);
                    let (u, v) = (u.clamp(0.0, (w - 1) as f32), v.clamp(0.0, (h - 1) as f32));
                    let (x0, y0) = (u.floor() as usize, v.floor() as usize);
                    let (kx, ky) = (keys(u - x0 as f32), keys(v - y0 as f32));
                    let tap = |o: usize, i: usize, n: usize| (o + i).saturating_sub(1).min(n - 1);
                    for (c, s) in sample.iter_mut().enumerate() {
                        let mut acc = 0.0f32;
                        for (j, wy) in ky.iter().enumerate() {
                            for (i, wx) in kx.iter().enumerate() {
                                acc += wx * wy * f.at(tap(x0, i, w), tap(y0, j, h), c) as f32;
                            }
                        }
                        *s = undo(k, c, acc).round().clamp(0.0, 255.0) as u8;
                    }
                    let e = error(x, y, &sample);
                    if e < best {
                        best = e;
                        row[x * ch..(x + 1) * ch].copy_from_slice(&sample);
                    }
                }
            }
        });
    Image::from_vec(w, h, ch, data)
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
        // A vertical step 0 → 255 down 150 rows (several bands): the two columns beside it
        // have |gx| = 4 · 255 on every interior row, every other pixel 0.
        let step = Image::<u8>::from_fn(30, 150, 3, |x, _, _| if x < 15 { 0 } else { 255 });
        let expected = 2.0 * 4.0 * 255.0 / 28.0;
        let got = tenengrad(&step);
        assert!((got - expected).abs() < 1e-3, "{got} against {expected}");
        // Only the right half differs: the left half alone is perfect.
        let c = Image::<u8>::from_fn(20, 20, 1, |x, _, _| if x < 10 { 0 } else { 245 });
        let left = psnr_where(&a, &c, |x, _| x < 10);
        let right = psnr_where(&a, &c, |x, _| x >= 10);
        assert!(left >= 120.0 && (right - 20.0 * (255.0f64 / 10.0).log10()).abs() < 1e-6);
    }

    #[test]
    fn band_reaches_radius_around_steps() {
        let mut steps = Image::<u8>::new(30, 20, 1);
        steps.data_mut()[10 * 30 + 15] = 255;
        let band = step_band(&steps, 3.0);
        assert_eq!(band.iter().filter(|&&b| b).count(), 29); // lattice points in a radius-3 disc
        assert!(band[10 * 30 + 18] && band[13 * 30 + 15] && !band[12 * 30 + 18]);
        assert!(step_band(&Image::new(5, 5, 1), 3.0).iter().all(|&b| !b));
    }

    #[test]
    fn oracle_samples_the_labelled_frame_where_it_moved() {
        let a = Image::<u8>::from_fn(8, 4, 1, |x, _, _| 10 * x as u8);
        let b = Image::<u8>::from_fn(8, 4, 1, |_, y, _| 100 + y as u8);
        let labels: Vec<u8> = (0..32).map(|k| (k % 8 >= 4) as u8).collect();
        // Frame 0 shows everything half a pixel to the right.
        let at =
            |f: usize, x: usize, y: usize| (x as f32 + if f == 0 { 0.5 } else { 0.0 }, y as f32);
        let o = depth_oracle(&[a.clone(), b.clone()], &labels, at, |_, _, v| v);
        assert_eq!(o.at(1, 0, 0), 15);
        assert_eq!(o.at(5, 2, 0), 102);
        // Frame 1 was exposed at gain 2: undone, its samples are halved.
        let o = depth_oracle(
            &[a, b],
            &labels,
            at,
            |f, _, v| if f == 1 { v / 2.0 } else { v },
        );
        assert_eq!(o.at(1, 0, 0), 15);
        assert_eq!(o.at(5, 2, 0), 51);
    }

    #[test]
    fn best_frame_oracle_takes_each_pixel_from_the_frame_nearest_the_truth() {
        // Frame 0 is right on the left half, frame 1 on the right half, each 40 off elsewhere.
        let truth = Image::<u8>::from_fn(8, 4, 1, |x, y, _| (20 * x + y) as u8);
        let off = |right: bool| {
            Image::<u8>::from_fn(8, 4, 1, |x, y, _| {
                (20 * x + y) as u8 + if (x >= 4) == right { 0 } else { 40 }
            })
        };
        let at = |_: usize, x: usize, y: usize| (x as f32, y as f32);
        let o = best_frame_oracle(&[off(false), off(true)], &truth, at, |_, _, v| v);
        assert_eq!(o.data(), truth.data());
        // One frame alone is what it is, wherever it is off.
        let o = best_frame_oracle(&[off(true)], &truth, at, |_, _, v| v);
        assert_eq!(o.data(), off(true).data());
    }
}
