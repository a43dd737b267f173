//! Stacks that are hard for the labelling rather than for the eye: large smooth regions that look
//! the same in every frame but for their noise, with a few textured patches in focus in one frame
//! each. On the smooth regions many frames tie and the sharpest frame changes from pixel to
//! pixel, which is what made exhaustive expansion's cost grow with frames × pixels; the scenes of
//! [`super::scene`] are textured almost everywhere and hide it.
//!
//! The patches' texture is a sum of plane waves, so its defocus is exact and cheap: a Gaussian
//! blur of σ scales a wave of frequency f by exp(−2π²σ²f²).

use super::rng::Rng;
use crate::stack::image::Image;
use rayon::prelude::*;
use std::f32::consts::TAU;
use std::ops::Range;

/// What a flats stack looks like; `flats` is a pure function of it.
#[derive(Clone, Debug)]
pub struct FlatsParams {
    pub width: usize,
    pub height: usize,
    pub frames: usize,
    pub seed: u64,
    /// Gaussian noise sigma in 8-bit units, independent per frame, pixel and channel.
    pub noise_sigma: f32,
    /// Defocus sigma (px) of a patch one frame away from its focus.
    pub blur_per_frame: f32,
    /// Textured patches, the k-th in focus in frame k mod `frames`; `None`: two per frame. The
    /// patches are drawn in the same order whatever the frame count, so a stack of 25 frames
    /// with the 16 patches of an 8-frame stack shows the same scene: what the labelling's
    /// growth with the frame count is measured on (`benches/bench-report`), apart from the
    /// growth with the depth steps that more patches bring.
    pub patches: Option<usize>,
}

impl Default for FlatsParams {
    fn default() -> Self {
        Self {
            width: 480,
            height: 360,
            frames: 16,
            seed: 1,
            noise_sigma: 2.0,
            blur_per_frame: 1.5,
            patches: None,
        }
    }
}

/// A plane wave: x and y frequency in cycles per pixel, and phase.
type Wave = (f32, f32, f32);

/// A textured disc in focus in one frame.
struct Patch {
    cx: f32,
    cy: f32,
    r: f32,
    focus: usize,
    /// (fx, fy, phase, amplitude) of each plane wave, frequencies in cycles per pixel.
    waves: Vec<(f32, f32, f32, f32)>,
}

impl Patch {
    /// The patch's texture at (x, y) seen with defocus sigma `s`.
    fn texture(&self, x: f32, y: f32, s: f32) -> f32 {
        self.waves
            .iter()
            .map(|&(fx, fy, ph, a)| {
                let damp = (-0.5 * (TAU * s).powi(2) * (fx * fx + fy * fy)).exp();
                a * damp * (TAU * (fx * x + fy * y) + ph).cos()
            })
            .sum()
    }

    /// The pixel columns and rows the patch may cover in a `width`×`height` image.
    fn bounds(&self, width: usize, height: usize) -> (Range<usize>, Range<usize>) {
        let span = |c: f32, n: usize| {
            ((c - self.r).floor().max(0.0) as usize).min(n)
                ..((c + self.r).ceil().max(0.0) as usize + 1).min(n)
        };
        (span(self.cx, width), span(self.cy, height))
    }
}

/// Renders an aligned RGB stack: frame i focuses the patches of focus i; everything else is a
/// smooth colour field (wavelengths of a third of the image and more) plus noise.
pub fn flats(p: &FlatsParams) -> Vec<Image<u8>> {
    let (field, patches) = scene(p);
    (0..p.frames)
        .into_par_iter()
        .map(|i| {
            let mut v = field.clone();
            for t in &patches {
                let s = p.blur_per_frame * t.focus.abs_diff(i) as f32;
                let (xs, ys) = t.bounds(p.width, p.height);
                for y in ys {
                    for x in xs.clone() {
                        let (fx, fy) = (x as f32, y as f32);
                        if (fx - t.cx).powi(2) + (fy - t.cy).powi(2) < t.r * t.r {
                            let d = t.texture(fx, fy, s);
                            for c in &mut v[(y * p.width + x) * 3..][..3] {
                                *c += d;
                            }
                        }
                    }
                }
            }
            let mut noise = Rng::stream(p.seed, 1 + i as u64);
            let data = v
                .iter()
                .map(|&v| {
                    (v + noise.normal() as f32 * p.noise_sigma)
                        .round()
                        .clamp(0.0, 255.0) as u8
                })
                .collect();
            Image::from_vec(p.width, p.height, 3, data)
        })
        .collect()
}

/// The noise-free smooth field (RGB, f32) and the patches ([`FlatsParams::patches`]).
fn scene(p: &FlatsParams) -> (Vec<f32>, Vec<Patch>) {
    let mut rng = Rng::stream(p.seed, 0);
    let (w, h) = (p.width as f64, p.height as f64);
    let wave = |rng: &mut Rng| {
        let f = rng.range(0.3, 3.0) / w.max(h);
        let a = rng.range(0.0, TAU as f64);
        (
            (f * a.cos()) as f32,
            (f * a.sin()) as f32,
            rng.range(0.0, TAU as f64) as f32,
        )
    };
    // Per channel: a base level and two slow waves.
    let channels: Vec<(f32, [Wave; 2])> = (0..3)
        .map(|_| {
            (
                rng.range(60.0, 190.0) as f32,
                [wave(&mut rng), wave(&mut rng)],
            )
        })
        .collect();
    let mut field = Vec::with_capacity(p.width * p.height * 3);
    for y in 0..p.height {
        for x in 0..p.width {
            let (x, y) = (x as f32, y as f32);
            for (base, waves) in &channels {
                let slow: f32 = waves
                    .iter()
                    .zip([25.0, 20.0])
                    .map(|(&(fx, fy, ph), a)| a * (TAU * (fx * x + fy * y) + ph).sin())
                    .sum();
                field.push(base + slow);
            }
        }
    }
    let frames = p.frames.max(1);
    let patches = (0..p.patches.unwrap_or(2 * frames))
        .map(|k| Patch {
            cx: rng.range(0.0, w) as f32,
            cy: rng.range(0.0, h) as f32,
            r: (rng.range(0.03, 0.08) * w.min(h)) as f32,
            focus: k % frames,
            waves: (0..4)
                .map(|_| {
                    let (f, a) = (rng.range(0.08, 0.3), rng.range(0.0, TAU as f64));
                    (
                        (f * a.cos()) as f32,
                        (f * a.sin()) as f32,
                        rng.range(0.0, TAU as f64) as f32,
                        rng.range(8.0, 20.0) as f32,
                    )
                })
                .collect(),
        })
        .collect();
    (field, patches)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each patch is sharpest in its own frame, and away from patches the frames differ only by
    /// noise: what makes them tie.
    #[test]
    fn patches_are_sharpest_in_their_frame_and_flats_differ_only_by_noise() {
        let p = FlatsParams {
            width: 200,
            height: 150,
            frames: 5,
            ..FlatsParams::default()
        };
        let frames = flats(&p);
        assert_eq!(frames.len(), 5);
        assert_eq!(frames, flats(&p), "not deterministic");
        let (_, patches) = scene(&p);
        let inside = |x: usize, y: usize| {
            patches.iter().any(|t| {
                (x as f32 - t.cx).powi(2) + (y as f32 - t.cy).powi(2) < (t.r + 2.0).powi(2)
            })
        };
        // Horizontal gradient energy of a frame's green over the pixels `keep` chooses.
        let grad = |f: &Image<u8>, keep: &dyn Fn(usize, usize) -> bool| -> f64 {
            (0..f.height())
                .flat_map(|y| (1..f.width()).map(move |x| (x, y)))
                .filter(|&(x, y)| keep(x, y))
                .map(|(x, y)| (f.at(x, y, 1) as f64 - f.at(x - 1, y, 1) as f64).powi(2))
                .sum()
        };
        let mut checked = 0;
        for (k, t) in patches.iter().enumerate() {
            // Only patches no other patch overlaps.
            let alone = patches.iter().enumerate().all(|(j, o)| {
                j == k || (o.cx - t.cx).powi(2) + (o.cy - t.cy).powi(2) > (o.r + t.r).powi(2)
            });
            if !alone {
                continue;
            }
            let own = |x: usize, y: usize| {
                (x as f32 - t.cx).powi(2) + (y as f32 - t.cy).powi(2) < (t.r - 2.0).powi(2)
            };
            let energy: Vec<f64> = frames.iter().map(|f| grad(f, &own)).collect();
            let best = (0..energy.len()).max_by(|&a, &b| energy[a].total_cmp(&energy[b]));
            assert_eq!(best, Some(t.focus), "patch {k}: {energy:?}");
            checked += 1;
        }
        assert!(checked >= 3, "only {checked} patches stand alone");
        // Away from patches, frame differences are noise of σ√2.
        let (a, b) = (&frames[1], &frames[3]);
        let (mut sum, mut n) = (0.0, 0);
        for y in 0..p.height {
            for x in 0..p.width {
                if !inside(x, y) {
                    let d = a.at(x, y, 0) as f64 - b.at(x, y, 0) as f64;
                    sum += d * d;
                    n += 1;
                }
            }
        }
        let rms = (sum / n as f64).sqrt();
        let expected = p.noise_sigma as f64 * 2f64.sqrt();
        assert!(
            (rms - expected).abs() < 0.2 * expected,
            "rms {rms}, expected {expected}"
        );
    }

    /// Given as many patches as a stack of fewer frames has, a longer stack shows that stack's
    /// scene: the same patches in the same places, each in focus in the frame of its index.
    #[test]
    fn the_same_patches_are_the_same_scene_whatever_the_frame_count() {
        let short = FlatsParams {
            frames: 8,
            ..FlatsParams::default()
        };
        let long = FlatsParams {
            frames: 25,
            patches: Some(16),
            ..FlatsParams::default()
        };
        let ((field_s, s), (field_l, l)) = (scene(&short), scene(&long));
        assert_eq!(field_s, field_l);
        assert_eq!((s.len(), l.len()), (16, 16));
        for (k, (a, b)) in s.iter().zip(&l).enumerate() {
            assert_eq!((a.cx, a.cy, a.r, &a.waves), (b.cx, b.cy, b.r, &b.waves));
            assert_eq!((a.focus, b.focus), (k % 8, k));
        }
        assert_eq!(scene(&FlatsParams::default()).1.len(), 32, "two a frame");
    }
}
