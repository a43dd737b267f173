//! Tie maps: where a pixel's frames focus alike within noise, so the focus cost cannot tell
//! them apart and the label goes to the fallback frame.

use super::GraphCutParams;
use crate::stack::focus::AMP_SCALE;
use rayon::prelude::*;

/// What each pixel's frames tie within: the noise floor ([`GraphCutParams::tie`]), or a share
/// of the median frame's amplitude where that is more ([`GraphCutParams::tie_noise`]); and the
/// frame ties go to ([`GraphCutParams::tie_bias`]). The map is held at the coarse level,
/// `factor` times smaller than the level read, `width` pixels wide.
pub(super) struct Ties<'m> {
    pub(super) map: &'m [u16],
    pub(super) coarse_width: usize,
    pub(super) factor: usize,
    pub(super) width: usize,
    pub(super) fallback: u8,
}

impl<'m> Ties<'m> {
    /// Ties read from `map`, `factor` times smaller than a level `width` pixels wide.
    pub(super) fn scaled(map: &'m [u16], factor: usize, width: usize, fallback: u8) -> Self {
        Self {
            map,
            coarse_width: width.div_ceil(factor),
            factor,
            width,
            fallback,
        }
    }

    /// Ties read from `map` at the level's own size.
    pub(super) fn whole(map: &'m [u16], width: usize, fallback: u8) -> Self {
        Self::scaled(map, 1, width, fallback)
    }

    #[inline]
    pub(super) fn at(&self, p: usize) -> u16 {
        let (x, y) = (p % self.width, p / self.width);
        self.map[y / self.factor * self.coarse_width + x / self.factor]
    }
}

/// The map [`Ties`] reads, from every frame's amplitudes at the coarse level. The lower median:
/// of a few frames the upper one is the second-sharpest, which would tie away real focus (the
/// 4-frame stack of `tests/fuse_quality.rs` fell below the pyramid baseline).
pub(super) fn tie_map(amps: &[Vec<u16>], p: &GraphCutParams) -> Vec<u16> {
    let floor = p.tie * p.noise_floor * AMP_SCALE;
    let n = amps.len();
    let mut map = vec![0u16; amps[0].len()];
    map.par_chunks_mut(4096).enumerate().for_each(|(k, out)| {
        let mut v = [0u16; 256];
        for (j, o) in out.iter_mut().enumerate() {
            let i = k * 4096 + j;
            for (x, a) in v.iter_mut().zip(amps) {
                *x = a[i];
            }
            let (_, median, _) = v[..n].select_nth_unstable((n - 1) / 2);
            *o = (p.tie_noise * *median as f32).max(floor) as u16;
        }
    });
    map
}
