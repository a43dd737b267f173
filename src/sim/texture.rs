//! Procedural, band-limited surface textures evaluated at any point (reference pixel units).
//!
//! Every pattern is anti-aliased analytically (one-pixel ramps at edges, noise octaves no finer
//! than ~2.5 px), so an unblurred rendering looks like a sharp photograph rather than a jagged
//! raster, and the defocus the renderer adds is the only blur in the stack.

use super::rng::{hash3, unit, Rng};
use super::shape::{Pt, Shape};
use std::sync::OnceLock;

/// Linear RGB-ish colour with channels in 0..=1 (the simulator does not model a tone curve).
pub type Rgb = [f32; 3];

#[inline]
pub fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

#[inline]
pub fn scale(c: Rgb, k: f32) -> Rgb {
    [c[0] * k, c[1] * k, c[2] * k]
}

/// HSV (all in 0..=1) to RGB.
pub fn hsv(h: f32, s: f32, v: f32) -> Rgb {
    let h6 = (h - h.floor()) * 6.0;
    let f = h6 - h6.floor();
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    match h6 as u32 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Value noise in [0, 1] on a unit lattice with quintic interpolation.
pub fn value_noise(x: f64, y: f64, seed: u64) -> f32 {
    let (xf, yf) = (x.floor(), y.floor());
    let (ix, iy) = (xf as i64, yf as i64);
    let (ux, uy) = (fade((x - xf) as f32), fade((y - yf) as f32));
    let v = |dx: i64, dy: i64| unit(hash3(ix + dx, iy + dy, seed));
    let top = v(0, 0) + (v(1, 0) - v(0, 0)) * ux;
    let bot = v(0, 1) + (v(1, 1) - v(0, 1)) * ux;
    top + (bot - top) * uy
}

/// Finest lattice spacing any noise octave may have, px: keeps every texture band-limited (no
/// aliasing, and the only blur in a frame is the simulated defocus and resampling).
pub const MIN_FEATURE_PX: f64 = 2.5;

/// Fractal (multi-octave) value noise in [0, 1]: up to `octaves` octaves, the coarsest with
/// feature size `scale` px, each next one half the size and half the amplitude, rotated to hide
/// the grid; octaves finer than [`MIN_FEATURE_PX`] are dropped.
pub fn fbm(x: f64, y: f64, scale: f64, octaves: u32, seed: u64) -> f32 {
    let (mut u, mut v) = (x / scale, y / scale);
    let (mut sum, mut amp, mut norm) = (0.0f32, 1.0f32, 0.0f32);
    let (s, c) = 0.6f64.sin_cos();
    let fits = (scale / MIN_FEATURE_PX).log2().floor().max(0.0) as u32 + 1;
    for o in 0..octaves.min(fits) {
        sum += amp * value_noise(u, v, seed.wrapping_add(o as u64 * 7919));
        norm += amp;
        amp *= 0.5;
        (u, v) = (2.0 * (c * u - s * v) + 17.3, 2.0 * (s * u + c * v) - 9.1);
    }
    sum / norm
}

/// Stretches a value centred on 0.5 by `k` and clamps to [0, 1].
#[inline]
fn stretch(t: f32, k: f32) -> f32 {
    (0.5 + (t - 0.5) * k).clamp(0.0, 1.0)
}

/// Anti-aliased pulse train: 1 for the first `duty` of every period of phase `s` (in periods),
/// 0 elsewhere, with one-pixel ramps (`period` in px).
#[inline]
fn pulse(s: f64, period: f64, duty: f64) -> f32 {
    let f = s - s.floor();
    let d = if f < duty {
        f.min(duty - f)
    } else {
        -(f - duty).min(1.0 - f)
    };
    (0.5 + d * period).clamp(0.0, 1.0) as f32
}

/// Anti-aliased line of width `w` px at distance `d` px from its centre line.
#[inline]
fn line(d: f64, w: f64) -> f32 {
    (0.5 + w / 2.0 - d.abs()).clamp(0.0, 1.0) as f32
}

#[inline]
fn rot(p: Pt, angle: f64) -> Pt {
    let (s, c) = angle.sin_cos();
    (c * p.0 + s * p.1, -s * p.0 + c * p.1)
}

/// A glyph: strokes between points of its unit box.
type Glyph = Vec<[(f32, f32); 2]>;

/// Text-like glyphs: each is 2–4 strokes between nodes of a 3×4 grid in a unit box.
fn glyph_table() -> &'static [Glyph] {
    static TABLE: OnceLock<Vec<Glyph>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rng = Rng::new(0x6c79_7068_7321);
        let node = |k: usize| ((k % 3) as f32 * 0.5, (k / 3) as f32 / 3.0);
        (0..48)
            .map(|_| {
                let strokes = 2 + rng.below(3);
                let mut g = Vec::new();
                let mut a = rng.below(12);
                while g.len() < strokes {
                    let b = rng.below(12);
                    if b == a {
                        continue;
                    }
                    g.push([node(a), node(b)]);
                    // Half the time continue from the end point (pen strokes), else jump.
                    a = if rng.chance(0.5) { b } else { rng.below(12) };
                }
                g
            })
            .collect()
    })
}

/// Ink coverage of glyph `id` drawn in a `w`×`h` box at local position (x, y) (box at origin).
fn glyph_ink(id: usize, x: f64, y: f64, w: f64, h: f64, stroke: f64) -> f32 {
    if x < -stroke || y < -stroke || x > w + stroke || y > h + stroke {
        return 0.0;
    }
    let table = glyph_table();
    let mut d = f64::INFINITY;
    for seg in &table[id % table.len()] {
        let (ax, ay) = (seg[0].0 as f64 * w, seg[0].1 as f64 * h);
        let (bx, by) = (seg[1].0 as f64 * w, seg[1].1 as f64 * h);
        let (ex, ey) = (bx - ax, by - ay);
        let (px, py) = (x - ax, y - ay);
        let t = ((px * ex + py * ey) / (ex * ex + ey * ey)).clamp(0.0, 1.0);
        d = d.min((px - ex * t).hypot(py - ey * t));
    }
    line(d, stroke)
}

/// A scalar pattern in [0, 1]: 0 shows a texture's `paper` colour, 1 its `ink`.
#[derive(Clone, Debug, PartialEq)]
pub enum Pattern {
    Flat(f32),
    /// Multi-octave value noise (stone, soil, moss) with contrast stretch.
    Fbm {
        scale: f64,
        octaves: u32,
        contrast: f32,
    },
    /// Parallel stripes; `warp` (in periods) bends them with low-frequency noise (wood grain).
    Stripes {
        period: f64,
        angle: f64,
        duty: f64,
        warp: f64,
    },
    /// Wood: warped stripes with noisy growth rings and speckle from multi-octave noise.
    Wood {
        period: f64,
        angle: f64,
    },
    /// Two crossing stripe sets (woven fabric / tartan).
    Plaid {
        period: f64,
        angle: f64,
    },
    Checker {
        size: f64,
        angle: f64,
    },
    /// A jittered grid of dots with varying radius.
    Dots {
        period: f64,
        radius: f64,
    },
    /// Voronoi cells with dark borders and per-cell tone (lizard skin, cobbles, lichen).
    Cells {
        size: f64,
    },
    /// Concentric rings about `centre` (coin, tree ring, bottle cap).
    Rings {
        centre: Pt,
        period: f64,
    },
    /// Lines of small text-like glyphs `height` px tall, in a frame rotated by `angle`.
    Glyphs {
        height: f64,
        angle: f64,
        origin: Pt,
    },
    /// Millimetre ticks (every `tick` px, longer every 5th and 10th, numbered) along the top edge of a
    /// strip `width` px wide centred on `origin` with its long axis at `angle`.
    Ruler {
        origin: Pt,
        angle: f64,
        tick: f64,
        width: f64,
    },
    /// A smooth linear ramp from 0 to 1 across `extent` px along `dir` (smooth painted area).
    Smooth {
        origin: Pt,
        dir: f64,
        extent: f64,
    },
}

impl Pattern {
    pub fn eval(&self, x: f64, y: f64, seed: u64) -> f32 {
        match *self {
            Pattern::Flat(v) => v,
            Pattern::Fbm {
                scale,
                octaves,
                contrast,
            } => stretch(fbm(x, y, scale, octaves, seed), contrast),
            Pattern::Stripes {
                period,
                angle,
                duty,
                warp,
            } => {
                let (u, _) = rot((x, y), angle);
                let mut s = u / period;
                if warp > 0.0 {
                    s += warp * (fbm(x, y, period * 12.0, 3, seed ^ 0x57) as f64 - 0.5) * 2.0;
                }
                pulse(s, period, duty)
            }
            Pattern::Wood { period, angle } => {
                let (u, _) = rot((x, y), angle);
                let warp = (fbm(x, y, period * 14.0, 3, seed ^ 0x57) as f64 - 0.5) * 3.2;
                let duty = 0.3 + 0.3 * fbm(x, y, period * 5.0, 2, seed ^ 0x99) as f64;
                let rings = pulse(u / period + warp, period, duty);
                let speckle = stretch(fbm(x, y, 12.0, 4, seed ^ 0x3d), 2.2);
                0.6 * rings + 0.4 * speckle
            }
            Pattern::Plaid { period, angle } => {
                let (u, v) = rot((x, y), angle);
                let a = pulse(u / period, period, 0.35);
                let b = pulse(v / (period * 1.6), period * 1.6, 0.3);
                let c = pulse(u / (period * 4.0), period * 4.0, 0.12);
                (0.45 * a + 0.35 * b + 0.4 * c).min(1.0)
            }
            Pattern::Checker { size, angle } => {
                let (u, v) = rot((x, y), angle);
                let a = pulse(u / (2.0 * size), 2.0 * size, 0.5) * 2.0 - 1.0;
                let b = pulse(v / (2.0 * size), 2.0 * size, 0.5) * 2.0 - 1.0;
                0.5 + 0.5 * a * b
            }
            Pattern::Dots { period, radius } => {
                let (cx, cy) = ((x / period).floor() as i64, (y / period).floor() as i64);
                let mut best = 0.0f32;
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let h = hash3(cx + dx, cy + dy, seed ^ 0xD07);
                        let jx = (unit(h) as f64 - 0.5) * 0.5;
                        let jy = (unit(mix_bits(h)) as f64 - 0.5) * 0.5;
                        let r = radius * (0.6 + 0.6 * unit(h.rotate_left(17)) as f64);
                        let px = (cx + dx) as f64 * period + period * (0.5 + jx);
                        let py = (cy + dy) as f64 * period + period * (0.5 + jy);
                        let d = (x - px).hypot(y - py);
                        best = best.max((0.5 + r - d).clamp(0.0, 1.0) as f32);
                    }
                }
                best
            }
            Pattern::Cells { size } => {
                let (u, v) = (x / size, y / size);
                let (cx, cy) = (u.floor() as i64, v.floor() as i64);
                let (mut d1, mut d2, mut id) = (f64::INFINITY, f64::INFINITY, 0u64);
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let h = hash3(cx + dx, cy + dy, seed ^ 0xCE11);
                        let fx = (cx + dx) as f64 + 0.15 + 0.7 * unit(h) as f64;
                        let fy = (cy + dy) as f64 + 0.15 + 0.7 * unit(mix_bits(h)) as f64;
                        let d = (u - fx).hypot(v - fy);
                        if d < d1 {
                            (d2, d1, id) = (d1, d, h);
                        } else if d < d2 {
                            d2 = d;
                        }
                    }
                }
                // Half the gap between the two nearest sites approximates the distance to the border.
                let border_px = (d2 - d1) * size * 0.5;
                let edge = (border_px - 0.6).clamp(0.0, 1.0) as f32;
                let tone = 0.15 + 0.55 * unit(id.rotate_left(29));
                1.0 - edge * (1.0 - tone)
            }
            Pattern::Rings { centre, period } => {
                let r = (x - centre.0).hypot(y - centre.1);
                let wobble = (fbm(x, y, period * 6.0, 2, seed ^ 0x21) as f64 - 0.5) * 0.6;
                pulse(r / period + wobble, period, 0.4)
            }
            Pattern::Glyphs {
                height,
                angle,
                origin,
            } => {
                let (u, v) = rot((x - origin.0, y - origin.1), angle);
                let (gw, adv, pitch) = (height * 0.62, height * 0.95, height * 1.7);
                let row = (v / pitch).floor();
                let col = (u / adv).floor();
                let h = hash3(col as i64, row as i64, seed ^ 0x6117);
                if unit(h) < 0.17 {
                    return 0.0; // word space
                }
                let stroke = (height * 0.13).max(1.1);
                glyph_ink(
                    (h >> 8) as usize,
                    u - col * adv,
                    v - row * pitch,
                    gw,
                    height,
                    stroke,
                )
            }
            Pattern::Ruler {
                origin,
                angle,
                tick,
                width,
            } => {
                let (u, v) = rot((x - origin.0, y - origin.1), angle);
                let from_edge = v + width / 2.0;
                let k = (u / tick).round();
                let ki = k as i64;
                let len = width
                    * if ki % 10 == 0 {
                        0.42
                    } else if ki % 5 == 0 {
                        0.3
                    } else {
                        0.18
                    };
                let mut ink =
                    line(u - k * tick, 1.0) * (0.5 + len - from_edge).clamp(0.0, 1.0) as f32;
                // Numbers under the long ticks.
                let k10 = (u / (tick * 10.0)).round();
                let gh = width * 0.24;
                let (gx, gy) = (u - k10 * tick * 10.0 + gh * 0.3, from_edge - width * 0.52);
                let stroke = (gh * 0.14).max(1.0);
                ink = ink.max(glyph_ink(
                    (k10 as i64).rem_euclid(48) as usize,
                    gx,
                    gy,
                    gh * 0.6,
                    gh,
                    stroke,
                ));
                ink
            }
            Pattern::Smooth {
                origin,
                dir,
                extent,
            } => {
                let (u, _) = rot((x - origin.0, y - origin.1), dir);
                (0.5 + u / extent).clamp(0.0, 1.0) as f32
            }
        }
    }
}

#[inline]
fn mix_bits(h: u64) -> u64 {
    super::rng::mix64(h ^ 0xA5A5_A5A5_A5A5_A5A5)
}

/// A pattern coloured between two colours, with low-frequency tint variation and fine grain.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub pattern: Pattern,
    pub paper: Rgb,
    pub ink: Rgb,
    /// Colour drifted towards over large areas (`tint_amount` 0..=1).
    pub tint: Rgb,
    pub tint_amount: f32,
    /// Amplitude of fine (~3 px) multiplicative luminance grain, e.g. 0.1 = ±10 %.
    pub grain: f32,
    pub seed: u64,
}

impl Texture {
    pub fn flat(c: Rgb) -> Self {
        Self {
            pattern: Pattern::Flat(0.0),
            paper: c,
            ink: c,
            tint: c,
            tint_amount: 0.0,
            grain: 0.0,
            seed: 0,
        }
    }

    #[inline]
    pub fn ink_at(&self, x: f64, y: f64) -> f32 {
        self.pattern.eval(x, y, self.seed)
    }

    /// Applies tint and grain to a colour at (x, y).
    #[inline]
    pub fn modulate(&self, mut c: Rgb, x: f64, y: f64) -> Rgb {
        if self.tint_amount > 0.0 {
            let v = stretch(fbm(x, y, 70.0, 3, self.seed ^ 0x7147), 2.0);
            c = mix(c, self.tint, self.tint_amount * v);
        }
        if self.grain > 0.0 {
            let g = fbm(x, y, 3.0, 1, self.seed ^ 0x6a41) - 0.5;
            c = scale(c, 1.0 + self.grain * 2.0 * g);
        }
        c
    }

    #[inline]
    pub fn color(&self, x: f64, y: f64) -> Rgb {
        let t = self.ink_at(x, y);
        self.modulate(mix(self.paper, self.ink, t), x, y)
    }
}

/// A texture laid over part of a surface, at the surface's depth (a label, a printed patch).
#[derive(Clone, Debug, PartialEq)]
pub struct Decal {
    pub shape: Shape,
    pub texture: Texture,
    /// Only the ink is laid down (text printed on the surface); otherwise the patch is opaque.
    pub ink_only: bool,
}

/// Directional shading across an object: brightness × (1 + amount·clamp(((p − centre)·dir)/size)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub centre: Pt,
    pub dir: Pt,
    pub size: f64,
    pub amount: f32,
}

/// A photograph (RGB display values 0..=1, row-major) shared by the layers that show it.
#[derive(Debug, PartialEq)]
pub struct Photo {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<Rgb>,
}

impl Photo {
    /// An 8-bit RGB image as the simulator's display values.
    pub fn from_rgb8(img: &crate::stack::Image<u8>) -> Photo {
        Photo {
            width: img.width(),
            height: img.height(),
            rgb: img
                .data()
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]].map(|v| v as f32 / 255.0))
                .collect(),
        }
    }

    /// The photograph's colour at (u, v) in its own pixels: bilinear, mirrored beyond its edges,
    /// so a small crop covers any surface without a seam.
    pub fn sample(&self, u: f64, v: f64) -> Rgb {
        let mirror = |t: f64, n: usize| {
            if n < 2 {
                return 0.0;
            }
            let period = 2.0 * (n as f64 - 1.0);
            let t = t.rem_euclid(period);
            if t > n as f64 - 1.0 {
                period - t
            } else {
                t
            }
        };
        let (u, v) = (mirror(u, self.width), mirror(v, self.height));
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
        let at = |x: usize, y: usize| self.rgb[y * self.width + x];
        let top = mix(at(x0, y0), at(x1, y0), fx);
        let bottom = mix(at(x0, y1), at(x1, y1), fx);
        mix(top, bottom, fy)
    }
}

/// A photograph laid over a surface: surface point p shows photo pixel (p − origin)/scale, its
/// values mapped linearly into `lo..=hi` (a light or a dark surface).
#[derive(Clone, Debug, PartialEq)]
pub struct PhotoPaint {
    pub photo: std::sync::Arc<Photo>,
    pub origin: Pt,
    pub scale: f64,
    pub lo: f32,
    pub hi: f32,
}

impl PhotoPaint {
    pub fn color(&self, x: f64, y: f64) -> Rgb {
        let c = self.photo.sample(
            (x - self.origin.0) / self.scale,
            (y - self.origin.1) / self.scale,
        );
        c.map(|v| self.lo + (self.hi - self.lo) * v)
    }
}

/// Everything that decides a surface's colour.
#[derive(Clone, Debug, PartialEq)]
pub struct Paint {
    pub base: Texture,
    /// A photograph in place of `base`, under the decals and the light.
    pub photo: Option<PhotoPaint>,
    pub decals: Vec<Decal>,
    pub light: Option<Light>,
}

impl Paint {
    pub fn flat(c: Rgb) -> Self {
        Self {
            base: Texture::flat(c),
            photo: None,
            decals: Vec::new(),
            light: None,
        }
    }

    pub fn color(&self, x: f64, y: f64) -> Rgb {
        let mut c = match &self.photo {
            Some(p) => p.color(x, y),
            None => self.base.color(x, y),
        };
        for d in &self.decals {
            if !d.shape.near(x, y) {
                continue;
            }
            let a = d.shape.coverage(x, y);
            if a <= 0.0 {
                continue;
            }
            if d.ink_only {
                let t = d.texture.ink_at(x, y) * a;
                if t > 0.0 {
                    c = mix(c, d.texture.modulate(d.texture.ink, x, y), t);
                }
            } else {
                c = mix(c, d.texture.color(x, y), a);
            }
        }
        if let Some(l) = &self.light {
            let s = ((x - l.centre.0) * l.dir.0 + (y - l.centre.1) * l.dir.1) / l.size;
            c = scale(c, 1.0 + l.amount * s.clamp(-1.0, 1.0) as f32);
        }
        [
            c[0].clamp(0.0, 1.0),
            c[1].clamp(0.0, 1.0),
            c[2].clamp(0.0, 1.0),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_stay_in_range_and_vary() {
        let pats = [
            Pattern::Fbm {
                scale: 16.0,
                octaves: 4,
                contrast: 2.5,
            },
            Pattern::Stripes {
                period: 6.0,
                angle: 0.3,
                duty: 0.5,
                warp: 1.0,
            },
            Pattern::Plaid {
                period: 5.0,
                angle: 0.2,
            },
            Pattern::Wood {
                period: 6.0,
                angle: 0.2,
            },
            Pattern::Checker {
                size: 4.0,
                angle: 0.1,
            },
            Pattern::Dots {
                period: 8.0,
                radius: 2.0,
            },
            Pattern::Cells { size: 9.0 },
            Pattern::Rings {
                centre: (20.0, 20.0),
                period: 5.0,
            },
            Pattern::Glyphs {
                height: 8.0,
                angle: 0.0,
                origin: (0.0, 0.0),
            },
            Pattern::Ruler {
                origin: (32.0, 32.0),
                angle: 0.0,
                tick: 4.0,
                width: 40.0,
            },
        ];
        for p in &pats {
            let v: Vec<f32> = (0..64 * 64)
                .map(|i| p.eval((i % 64) as f64, (i / 64) as f64, 5))
                .collect();
            assert!(v.iter().all(|t| (0.0..=1.0).contains(t)), "{p:?}");
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            let var = v.iter().map(|t| (t - mean).powi(2)).sum::<f32>() / v.len() as f32;
            assert!(var > 0.004, "{p:?} is nearly flat: var {var}");
        }
    }

    #[test]
    fn hsv_primaries() {
        assert_eq!(hsv(0.0, 1.0, 1.0), [1.0, 0.0, 0.0]);
        let g = hsv(1.0 / 3.0, 1.0, 1.0);
        assert!(g[1] == 1.0 && g[0] < 1e-6 && g[2] < 1e-6);
    }
}
