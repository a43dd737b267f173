//! Focus distances and thin-lens defocus.
//!
//! Depth inside the simulator is a *plane coordinate* q: 0 at the nearest focus plane, `planes − 1`
//! at the farthest, uniformly spaced in diopters (1/m) between `near_diopters` and `far_diopters`,
//! as a focus sweep that steps the lens evenly would be. For a thin lens focused at distance d the
//! blur-circle diameter of a point at distance z is proportional to |1/z − 1/d|, so the Gaussian
//! PSF sigma is linear in the diopter difference — and therefore in the plane difference:
//! `sigma = min(blur_per_plane · |q − i|, max_blur)` for frame i.

use super::SimParams;

#[derive(Clone, Copy, Debug)]
pub struct Optics {
    pub near_diopters: f64,
    pub far_diopters: f64,
    pub planes: usize,
    pub blur_per_plane: f64,
    pub max_blur: f64,
}

impl Optics {
    pub fn new(p: &SimParams) -> Self {
        Self {
            near_diopters: p.near_diopters,
            far_diopters: p.far_diopters,
            planes: p.planes,
            blur_per_plane: p.blur_per_plane,
            max_blur: p.max_blur,
        }
    }

    /// Diopters between adjacent focus planes.
    pub fn plane_step(&self) -> f64 {
        (self.near_diopters - self.far_diopters) / (self.planes.max(2) - 1) as f64
    }

    /// Object distance (diopters) at plane coordinate `q`.
    pub fn diopters_at(&self, q: f64) -> f64 {
        self.near_diopters - q * self.plane_step()
    }

    /// Where frame `i` is focused (diopters).
    pub fn focus_diopters(&self, i: usize) -> f64 {
        self.diopters_at(i as f64)
    }

    /// Gaussian sigma (px) of a point at `z` diopters in a frame focused at `d` diopters: blur circle
    /// ∝ |z − d| (both already 1/distance), calibrated so one plane step gives `blur_per_plane`.
    pub fn sigma(&self, z: f64, d: f64) -> f64 {
        let kappa = self.blur_per_plane / self.plane_step();
        (kappa * (z - d).abs()).min(self.max_blur)
    }

    /// Sigma of plane coordinate `q` in frame `i`.
    pub fn sigma_q(&self, q: f64, i: usize) -> f64 {
        self.sigma(self.diopters_at(q), self.focus_diopters(i))
    }

    /// The largest sigma any layer at depth in `0..=planes−1` gets in any frame.
    pub fn worst_sigma(&self) -> f64 {
        (self.blur_per_plane * (self.planes - 1) as f64).min(self.max_blur)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_is_linear_in_planes_and_capped() {
        let o = Optics::new(&SimParams::default());
        assert_eq!(o.sigma_q(2.0, 2), 0.0);
        assert!((o.sigma_q(3.0, 2) - o.blur_per_plane).abs() < 1e-9);
        assert!((o.sigma_q(0.0, 2) - 2.0 * o.blur_per_plane).abs() < 1e-9);
        assert!((o.sigma_q(5.0, 0) - o.max_blur).abs() < 1e-9);
        assert!((o.focus_diopters(0) - o.near_diopters).abs() < 1e-12);
        assert!((o.focus_diopters(o.planes - 1) - o.far_diopters).abs() < 1e-9);
    }
}
