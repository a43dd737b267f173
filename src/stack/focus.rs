//! Per-pixel focus measure: local energy of a difference of Gaussians (the paper's unary term).

use super::blur::{downsample_area, gaussian_blur};
use super::image::Plane;
use rayon::prelude::*;

/// Focus measure settings, in pixels of the frame.
#[derive(Clone, Debug)]
pub struct FocusParams {
    /// The DoG band: blur at `sigma_fine` minus blur at `sigma_coarse`.
    pub sigma_fine: f32,
    pub sigma_coarse: f32,
    /// Gaussian window over which the squared DoG response is aggregated.
    pub window: f32,
}

impl Default for FocusParams {
    fn default() -> Self {
        Self {
            sigma_fine: 0.7,
            sigma_coarse: 2.0,
            window: 2.0,
        }
    }
}

/// Amplitudes are stored as u16 with this full scale (luma is 0..=1, a DoG amplitude ≲ 0.5),
/// which halves memory against f32 and keeps 1.5e-5 resolution, far below sensor noise.
pub const AMP_SCALE: f32 = 65535.0;

/// RMS DoG response around each pixel, quantised to u16 (see `AMP_SCALE`).
pub fn focus_amplitude(luma: &Plane, p: &FocusParams) -> Vec<u16> {
    let fine = gaussian_blur(luma, p.sigma_fine);
    let coarse = gaussian_blur(luma, p.sigma_coarse);
    let mut dog = fine;
    dog.data
        .par_iter_mut()
        .zip(&coarse.data)
        .for_each(|(f, c)| *f = (*f - c) * (*f - c));
    drop(coarse);
    let energy = gaussian_blur(&dog, p.window);
    energy
        .data
        .par_iter()
        .map(|e| (e.max(0.0).sqrt() * AMP_SCALE).round().min(65535.0) as u16)
        .collect()
}

/// Area-downsamples a u16 amplitude map by `factor`.
pub fn downsample_amplitude(amp: &[u16], width: usize, height: usize, factor: usize) -> Vec<u16> {
    let p = Plane::from_vec(width, height, 1, amp.iter().map(|&a| a as f32).collect());
    downsample_area(&p, factor)
        .data
        .iter()
        .map(|&v| v.round() as u16)
        .collect()
}

/// Per-pixel maximum over the stack.
pub fn max_amplitude(amps: &[Vec<u16>]) -> Vec<u16> {
    let mut m = amps[0].clone();
    for a in &amps[1..] {
        m.par_iter_mut().zip(a).for_each(|(m, &v)| *m = (*m).max(v));
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sharper_texture_has_higher_amplitude() {
        let sharp = Plane::from_fn(64, 64, 1, |x, y, _| ((x / 2 + y / 2) % 2) as f32);
        let soft = gaussian_blur(&sharp, 2.0);
        let flat = Plane::from_fn(64, 64, 1, |_, _, _| 0.5);
        let p = FocusParams::default();
        let mean = |v: Vec<u16>| v.iter().map(|&a| a as f64).sum::<f64>() / v.len() as f64;
        let (a, b, c) = (
            mean(focus_amplitude(&sharp, &p)),
            mean(focus_amplitude(&soft, &p)),
            mean(focus_amplitude(&flat, &p)),
        );
        assert!(a > 3.0 * b, "sharp {a} vs soft {b}");
        assert!(b > c && c == 0.0);
    }
}
