//! Occlusion-aware layered defocus compositing, hand-held resampling, gain and sensor noise.
//!
//! Every layer is rasterised in full (also where nearer layers hide it) as premultiplied colour
//! α·C and coverage α, both blurred with that layer's defocus sigma, and composited far to near:
//! `out = blur(α·C) + (1 − blur(α))·behind`. The background is opaque everywhere, so blurred
//! edges blend into real content behind them: no dark gaps or halos.
//!
//! Rendering happens on a *canvas*: the reference frame extended by a margin on every side, so
//! that blur near the image border sees real scene content and hand-held frames, resampled from
//! the canvas with `warp_affine`, have no empty borders. That bilinear resampling softens the
//! finest detail of hand-held frames (other than the reference) by up to ~0.5 px; aligned frames
//! are exact crops of the canvas.

use super::optics::Optics;
use super::pose::{draw_poses, Pose};
use super::rng::Rng;
use super::scene::{Depth, Layer, Scene};
use super::warp::warp_affine;
use super::{FrameInfo, SimParams, SimStack};
use crate::stack::blur::gaussian_blur;
use crate::stack::image::{Image, Plane};
use crate::stack::transform::Affine;
use rayon::prelude::*;

/// RNG streams besides the scene's (see `scene::STREAM_SCENE`).
pub const STREAM_POSES: u64 = 2;
pub const STREAM_GAINS: u64 = 3;
pub const STREAM_WHITE_BALANCE: u64 = 4;
/// Frame i's noise uses stream `STREAM_NOISE + i`.
pub const STREAM_NOISE: u64 = 1000;

/// The reference frame grown by `margin` px on each side: canvas pixel (X, Y) is reference pixel
/// (X − margin, Y − margin).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub margin: usize,
}

impl Canvas {
    /// Canvas for `p`: room for the worst hand-held displacement plus the defocus kernel radius.
    pub fn for_params(p: &SimParams, optics: &Optics) -> Canvas {
        let (w, h) = (p.width as f64, p.height as f64);
        let pad = blur_pad(optics);
        let geo = if p.handheld {
            let half_diag = w.hypot(h) / 2.0;
            p.max_shift * w
                + half_diag * (p.max_rotation_deg.to_radians() + p.breathing)
                + p.parallax_px
                + 2.0
        } else {
            w.hypot(h) / 2.0 * p.tripod_breathing
        };
        let margin = (geo + pad).ceil() as usize;
        Canvas {
            width: p.width + 2 * margin,
            height: p.height + 2 * margin,
            margin,
        }
    }

    /// The affine taking canvas coordinates to reference coordinates' inverse: reference → canvas.
    pub fn ref_to_canvas(&self) -> Affine {
        let m = self.margin as f64;
        Affine([[1.0, 0.0, m], [0.0, 1.0, m]])
    }
}

/// Distance blur can carry content: the Gaussian kernel radius ⌈3σ⌉ of the worst sigma, plus 2.
fn blur_pad(optics: &Optics) -> f64 {
    (3.0 * optics.worst_sigma()).ceil() + 2.0
}

/// Extra shift of a layer against the far background in one frame: `v` at plane 0, falling
/// linearly to zero at the far plane `q_far`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Parallax {
    pub v: (f64, f64),
    pub q_far: f64,
}

impl Parallax {
    pub const NONE: Parallax = Parallax {
        v: (0.0, 0.0),
        q_far: 1.0,
    };

    #[inline]
    pub fn shift(&self, q: f64) -> (f64, f64) {
        let k = ((self.q_far - q) / self.q_far).clamp(0.0, 1.0);
        (self.v.0 * k, self.v.1 * k)
    }

    fn moves(&self, layer: &Layer) -> bool {
        if self.v == (0.0, 0.0) {
            return false;
        }
        match layer.depth {
            Depth::Plane(q) => q < self.q_far,
            Depth::Slant { .. } | Depth::Curve { .. } => true,
        }
    }

    fn magnitude(&self) -> f64 {
        self.v.0.hypot(self.v.1)
    }
}

/// A layer rasterised over a crop of the canvas at (x0, y0): planes α·R, α·G, α·B, α.
#[derive(Clone, Debug)]
pub struct Raster {
    pub x0: usize,
    pub y0: usize,
    pub planes: [Plane; 4],
}

impl Raster {
    fn width(&self) -> usize {
        self.planes[0].width()
    }
    fn height(&self) -> usize {
        self.planes[0].height()
    }
}

/// Rasterises `layer` (moved by `parallax`) over its bounding box grown by `pad` px, clipped to the
/// canvas, its colours in `light`. `None` when the layer lies entirely off the canvas.
pub fn rasterize(
    layer: &Layer,
    cv: Canvas,
    pad: f64,
    parallax: &Parallax,
    light: Mixing,
) -> Option<Raster> {
    let m = cv.margin as f64;
    let (x0, y0, x1, y1) = match layer.shape.bbox() {
        None => (0, 0, cv.width, cv.height),
        Some(b) => {
            let e = pad + parallax.magnitude() + 2.0;
            let cl = |v: f64, hi: usize| v.clamp(0.0, hi as f64) as usize;
            (
                cl((b[0] - e + m).floor(), cv.width),
                cl((b[1] - e + m).floor(), cv.height),
                cl((b[2] + e + m).ceil() + 1.0, cv.width),
                cl((b[3] + e + m).ceil() + 1.0, cv.height),
            )
        }
    };
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let (w, h) = (x1 - x0, y1 - y0);
    let mut buf = vec![0.0f32; w * h * 4];
    buf.par_chunks_mut(w * 4).enumerate().for_each(|(ry, row)| {
        let y = (y0 + ry) as f64 - m;
        for (rx, px) in row.chunks_exact_mut(4).enumerate() {
            let x = (x0 + rx) as f64 - m;
            let (dx, dy) = parallax.shift(layer.depth.at(x, y));
            let (sx, sy) = (x - dx, y - dy);
            if !layer.shape.near(sx, sy) {
                continue;
            }
            let a = layer.shape.coverage(sx, sy);
            if a <= 0.0 {
                continue;
            }
            let c = layer.paint.color(sx, sy).map(|v| light.from_display(v));
            px.copy_from_slice(&[c[0] * a, c[1] * a, c[2] * a, a]);
        }
    });
    let planes = std::array::from_fn(|k| {
        Plane::from_vec(w, h, 1, buf.iter().skip(k).step_by(4).copied().collect())
    });
    Some(Raster { x0, y0, planes })
}

/// Blurs all four planes with one sigma (an opaque layer's alpha stays 1 and is not blurred).
fn blur_uniform(r: &Raster, sigma: f64, opaque: bool) -> Raster {
    let planes = std::array::from_fn(|k| {
        if k == 3 && opaque {
            r.planes[3].clone()
        } else {
            gaussian_blur(&r.planes[k], sigma as f32)
        }
    });
    Raster {
        x0: r.x0,
        y0: r.y0,
        planes,
    }
}

/// Spatially varying blur for a surface whose depth changes smoothly: the crop is blurred at a
/// ladder of sigmas (steps ≤ max(0.35 px, 15 %)) and each pixel interpolates between the two
/// rungs around its own sigma.
fn blur_varying(r: &Raster, sigma: &[f32]) -> Raster {
    let (lo, hi) = sigma
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &s| {
            (a.min(s), b.max(s))
        });
    if hi - lo < 0.05 {
        return blur_uniform(r, ((lo + hi) / 2.0) as f64, false);
    }
    let mut levels = vec![lo];
    while *levels.last().unwrap() < hi {
        let l = *levels.last().unwrap();
        levels.push(l + (0.15 * l).max(0.35));
    }
    let rungs: Vec<[Plane; 4]> = levels
        .iter()
        .map(|&s| std::array::from_fn(|k| gaussian_blur(&r.planes[k], s)))
        .collect();
    let n = sigma.len();
    let mut planes: [Plane; 4] = std::array::from_fn(|_| Plane::new(r.width(), r.height(), 1));
    for (k, plane) in planes.iter_mut().enumerate() {
        plane
            .data_mut()
            .par_iter_mut()
            .zip(sigma.par_iter())
            .enumerate()
            .for_each(|(i, (o, &s))| {
                let j = levels
                    .partition_point(|&l| l <= s)
                    .clamp(1, levels.len() - 1)
                    - 1;
                let t = ((s - levels[j]) / (levels[j + 1] - levels[j])).clamp(0.0, 1.0);
                *o = rungs[j][k].data()[i] * (1.0 - t) + rungs[j + 1][k].data()[i] * t;
            });
        debug_assert_eq!(plane.data().len(), n);
    }
    Raster {
        x0: r.x0,
        y0: r.y0,
        planes,
    }
}

/// `out = P + (1 − A)·out` over the raster's crop.
fn composite(out: &mut [Plane; 3], r: &Raster) {
    let (w, h) = (r.width(), r.height());
    let cw = out[0].width();
    let alpha = r.planes[3].data();
    for (c, plane) in out.iter_mut().enumerate() {
        let src = r.planes[c].data();
        plane
            .data_mut()
            .par_chunks_mut(cw)
            .skip(r.y0)
            .take(h)
            .enumerate()
            .for_each(|(ry, row)| {
                let row = &mut row[r.x0..r.x0 + w];
                let (s, a) = (&src[ry * w..ry * w + w], &alpha[ry * w..ry * w + w]);
                for ((o, &p), &al) in row.iter_mut().zip(s).zip(a) {
                    *o = p + (1.0 - al) * *o;
                }
            });
    }
}

/// The values layers are mixed, blurred and resampled in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mixing {
    /// Display (sRGB-encoded) values, as the committed stacks were rendered.
    Display,
    /// Linear light, encoded to sRGB only when a frame is exposed, as in a camera.
    Linear,
}

impl Mixing {
    fn of(p: &SimParams) -> Mixing {
        if p.linear_light {
            Mixing::Linear
        } else {
            Mixing::Display
        }
    }

    /// A display value 0..=1 (a paint colour) in this light.
    #[inline]
    pub fn from_display(self, v: f32) -> f32 {
        match self {
            Mixing::Display => v,
            Mixing::Linear => crate::stack::srgb::curve_inverse(v),
        }
    }

    /// A value in this light back to a display value 0..=1 (clamped).
    #[inline]
    pub fn to_display(self, v: f32) -> f32 {
        let v = v.clamp(0.0, 1.0);
        match self {
            Mixing::Display => v,
            Mixing::Linear => crate::stack::srgb::curve(v),
        }
    }
}

/// Cuts the reference frame out of a canvas plane.
fn crop(p: &Plane, cv: Canvas, w: usize, h: usize) -> Plane {
    let m = cv.margin;
    Plane::from_fn(w, h, 1, |x, y, _| p.data()[(y + m) * p.width() + x + m])
}

/// The stack plus what tests and tools may want beyond it.
pub struct Rendered {
    pub stack: SimStack,
    /// Per reference pixel: index into `scene.layers` of the frontmost layer with α > 0.5.
    pub owner: Vec<usize>,
    pub canvas: Canvas,
}

/// Renders frames, truth, depth and transforms of `scene` under `p` (which must be valid and match
/// the scene's size and planes).
pub fn render_scene(p: &SimParams, scene: &Scene) -> Rendered {
    assert_eq!(
        (scene.width, scene.height, scene.planes),
        (p.width, p.height, p.planes),
        "scene does not match parameters"
    );
    let (w, h, n) = (p.width, p.height, p.planes);
    let optics = Optics::new(p);
    let cv = Canvas::for_params(p, &optics);
    let pad = blur_pad(&optics);
    let reference = p.reference();
    let q_far = (n - 1) as f64;
    let light = Mixing::of(p);

    let poses = draw_poses(p, STREAM_POSES);
    let ref_to_frame: Vec<Affine> = poses.iter().map(|q| q.ref_to_frame(w, h)).collect();
    let mut gain_rng = Rng::stream(p.seed, STREAM_GAINS);
    let gains: Vec<f64> = (0..n)
        .map(|i| {
            let g = 1.0 + p.gain_jitter * (2.0 * gain_rng.uniform() - 1.0);
            if i == reference {
                1.0
            } else {
                g
            }
        })
        .collect();

    // Unshifted rasters serve the truth and every frame/layer without parallax.
    let base: Vec<Option<Raster>> = scene
        .layers
        .iter()
        .map(|l| rasterize(l, cv, pad, &Parallax::NONE, light))
        .collect();

    // Truth: the same composite without blur, and the frontmost owner of every pixel.
    let mut canvas: [Plane; 3] = std::array::from_fn(|_| Plane::new(cv.width, cv.height, 1));
    let mut owner = vec![0usize; w * h];
    for (li, r) in base.iter().enumerate() {
        let Some(r) = r else { continue };
        composite(&mut canvas, r);
        for ry in 0..r.height() {
            let Some(y) = (r.y0 + ry).checked_sub(cv.margin).filter(|&y| y < h) else {
                continue;
            };
            for rx in 0..r.width() {
                let Some(x) = (r.x0 + rx).checked_sub(cv.margin).filter(|&x| x < w) else {
                    continue;
                };
                if r.planes[3].data()[ry * r.width() + rx] > 0.5 {
                    owner[y * w + x] = li;
                }
            }
        }
    }
    let truth_planes: Vec<Plane> = canvas
        .iter()
        .map(|c| {
            let mut t = crop(c, cv, w, h);
            t.data_mut()
                .iter_mut()
                .for_each(|v| *v = light.to_display(*v));
            t
        })
        .collect();
    let truth = Image::<u8>::from_planes(&truth_planes);
    let depth = Image::from_fn(w, h, 1, |x, y, _| {
        let q = scene.layers[owner[y * w + x]].depth.at(x as f64, y as f64);
        q.round().clamp(0.0, q_far) as u8
    });

    let steps = depth_steps(scene, &owner, w, h);

    let mut wb_rng = Rng::stream(p.seed, STREAM_WHITE_BALANCE);
    let white_balance: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let wb = std::array::from_fn(|_| 1.0 + p.wb_jitter * (2.0 * wb_rng.uniform() - 1.0));
            if i == reference {
                [1.0; 3]
            } else {
                wb
            }
        })
        .collect();

    let mut frames = Vec::with_capacity(n);
    let mut info = Vec::with_capacity(n);
    for i in 0..n {
        let pose = poses[i];
        let parallax = frame_parallax(p, &pose);
        let mut canvas: [Plane; 3] = std::array::from_fn(|_| Plane::new(cv.width, cv.height, 1));
        for (li, layer) in scene.layers.iter().enumerate() {
            let moved;
            let r = if parallax.moves(layer) {
                moved = rasterize(layer, cv, pad, &parallax, light);
                moved.as_ref()
            } else {
                base[li].as_ref()
            };
            let Some(r) = r else { continue };
            let blurred = match layer.depth {
                Depth::Plane(q) => {
                    let opaque = layer.shape.bbox().is_none();
                    blur_uniform(r, optics.sigma_q(q, i), opaque)
                }
                Depth::Slant { .. } | Depth::Curve { .. } => {
                    let m = cv.margin as f64;
                    let sig = Plane::from_fn(r.width(), r.height(), 1, |x, y, _| {
                        let (rx, ry) = ((r.x0 + x) as f64 - m, (r.y0 + y) as f64 - m);
                        optics.sigma_q(layer.depth.at(rx, ry), i) as f32
                    });
                    blur_varying(r, sig.data())
                }
            };
            composite(&mut canvas, &blurred);
        }
        // Frame pixel → reference → canvas.
        let inv = ref_to_frame[i]
            .inverse()
            .expect("similarity with positive scale is invertible");
        let frame_to_canvas = cv.ref_to_canvas().compose(&inv);
        let warped: Vec<Plane> = canvas
            .iter()
            .map(|c| warp_affine(c, &frame_to_canvas, w, h).0)
            .collect();
        let gain = white_balance[i].map(|b| b * gains[i]);
        frames.push(expose(&warped, gain, light, p.noise_sigma, p.seed, i));
        info.push(FrameInfo {
            focus_diopters: optics.focus_diopters(i),
            gain: gains[i],
            white_balance: white_balance[i],
            translation: [pose.translation.0, pose.translation.1],
            rotation_deg: pose.rotation.to_degrees(),
            scale: pose.scale,
            parallax: [parallax.v.0, parallax.v.1],
        });
    }
    Rendered {
        stack: SimStack {
            frames,
            truth,
            depth,
            steps,
            max_sigma: optics.worst_sigma(),
            reference,
            ref_to_frame,
            info,
        },
        owner,
        canvas: cv,
    }
}

/// Occlusion edges of the reference view: pixels with a 4-neighbour owned by another layer whose
/// depth there differs by at least half a plane.
fn depth_steps(scene: &Scene, owner: &[usize], w: usize, h: usize) -> Image<u8> {
    let q = |x: usize, y: usize| scene.layers[owner[y * w + x]].depth.at(x as f64, y as f64);
    Image::from_fn(w, h, 1, |x, y, _| {
        let k = owner[y * w + x];
        let here = q(x, y);
        let step = [
            (x.wrapping_sub(1), y),
            (x + 1, y),
            (x, y.wrapping_sub(1)),
            (x, y + 1),
        ]
        .into_iter()
        .filter(|&(u, v)| u < w && v < h)
        .any(|(u, v)| owner[v * w + u] != k && (q(u, v) - here).abs() >= 0.5);
        if step {
            255
        } else {
            0
        }
    })
}

/// The parallax of a frame in pose `pose`: proportional to its translation, `parallax_px` at
/// full `max_shift`.
fn frame_parallax(p: &SimParams, pose: &Pose) -> Parallax {
    let tmax = p.max_shift * p.width as f64;
    if p.handheld && tmax > 0.0 {
        let k = p.parallax_px / tmax;
        Parallax {
            v: (pose.translation.0 * k, pose.translation.1 * k),
            q_far: (p.planes - 1) as f64,
        }
    } else {
        Parallax::NONE
    }
}

/// Ground truth for registration: where frame `i` shows the scene point that reference pixel
/// (x, y) shows (row-major, frame pixel coordinates). That is the frame's affine after the
/// parallax shift of the layer visible there (`r.owner`), so it departs from
/// `stack.ref_to_frame[i]` on near layers; it is ambiguous only within a pixel or two of an
/// occlusion edge, where parallax uncovers or hides background.
pub fn true_positions(p: &SimParams, scene: &Scene, r: &Rendered, i: usize) -> Vec<(f64, f64)> {
    let poses = draw_poses(p, STREAM_POSES);
    let parallax = frame_parallax(p, &poses[i]);
    let a = r.stack.ref_to_frame[i];
    let w = p.width;
    (0..w * p.height)
        .map(|k| {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            let layer = &scene.layers[r.owner[k]];
            let (dx, dy) = if parallax.moves(layer) {
                parallax.shift(layer.depth.at(x, y))
            } else {
                (0.0, 0.0)
            };
            a.apply(x + dx, y + dy)
        })
        .collect()
}

/// Per-channel gain (in `light`), encoding to display values, Gaussian read noise plus shot noise
/// (variance σ²·v/255), rounding and clamping to 8 bits.
fn expose(
    planes: &[Plane],
    gain: [f64; 3],
    light: Mixing,
    sigma: f64,
    seed: u64,
    frame: usize,
) -> Image<u8> {
    let (w, h) = (planes[0].width(), planes[0].height());
    let mut rng = Rng::stream(seed, STREAM_NOISE + frame as u64);
    let s2 = sigma * sigma;
    let mut data = Vec::with_capacity(w * h * planes.len());
    for i in 0..w * h {
        for (p, gain) in planes.iter().zip(gain) {
            let v = match light {
                Mixing::Display => p.data()[i] as f64 * 255.0 * gain,
                Mixing::Linear => {
                    light.to_display((p.data()[i] as f64 * gain) as f32) as f64 * 255.0
                }
            };
            let noisy = if sigma > 0.0 {
                v + (s2 * (1.0 + v.max(0.0) / 255.0)).sqrt() * rng.normal()
            } else {
                v
            };
            data.push(noisy.round().clamp(0.0, 255.0) as u8);
        }
    }
    Image::from_vec(w, h, planes.len(), data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::render as render_stack;

    fn small(seed: u64, handheld: bool) -> SimParams {
        SimParams {
            width: 160,
            height: 120,
            planes: 6,
            seed,
            handheld,
            ..SimParams::default()
        }
    }

    fn quiet(mut p: SimParams) -> SimParams {
        p.noise_sigma = 0.0;
        p.gain_jitter = 0.0;
        p
    }

    #[test]
    fn deterministic_for_a_seed() {
        let p = SimParams {
            gain_jitter: 0.05,
            ..small(4, true)
        };
        let (a, b) = (render_stack(&p), render_stack(&p));
        assert_eq!(a.frames, b.frames);
        assert_eq!(a.truth, b.truth);
        assert_eq!(a.depth, b.depth);
        assert_eq!(a.ref_to_frame, b.ref_to_frame);
        assert_eq!(a.info, b.info);
        let c = render_stack(&small(5, true));
        assert_ne!(a.truth, c.truth);
        assert_eq!(a.frames.len(), 6);
        assert!(a
            .frames
            .iter()
            .all(|f| (f.width(), f.height(), f.channels()) == (160, 120, 3)));
        assert_eq!((a.depth.channels(), a.truth.channels()), (1, 3));
        assert!(a.depth.data().iter().all(|&d| d < 6));
    }

    #[test]
    fn reference_pose_is_identity() {
        let p = SimParams {
            gain_jitter: 0.05,
            ..small(6, true)
        };
        let s = render_stack(&p);
        assert_eq!(s.reference, 2);
        assert_eq!(s.ref_to_frame[2], Affine::IDENTITY);
        assert_eq!(s.info[2].gain, 1.0);
        for (i, a) in s.ref_to_frame.iter().enumerate() {
            if i != 2 {
                assert!(
                    a.corner_error(&Affine::IDENTITY, 160, 120) > 0.1,
                    "frame {i}"
                );
            }
        }
        let aligned = render_stack(&small(6, false));
        assert!(aligned.ref_to_frame.iter().all(|a| *a == Affine::IDENTITY));
        // The reference frame of an aligned noise-free stack differs from the truth only by blur.
        let q = render_stack(&quiet(small(6, false)));
        let (f, t) = (&q.frames[2], &q.truth);
        let same = f
            .data()
            .iter()
            .zip(t.data())
            .filter(|(a, b)| a.abs_diff(**b) <= 1)
            .count();
        assert!(same as f64 > 0.15 * t.data().len() as f64);
    }

    /// Pixels whose owner is `li` and every pixel within `r` (Chebyshev) has the same owner.
    fn interior(owner: &[usize], w: usize, h: usize, li: usize, r: usize) -> Vec<(usize, usize)> {
        let mut v = Vec::new();
        for y in r..h - r {
            for x in r..w - r {
                if (y - r..=y + r).all(|yy| (x - r..=x + r).all(|xx| owner[yy * w + xx] == li)) {
                    v.push((x, y));
                }
            }
        }
        v
    }

    fn gradient_energy(img: &Image<u8>, px: &[(usize, usize)]) -> f64 {
        let l = img.luma();
        px.iter()
            .map(|&(x, y)| {
                let gx = l.at(x + 1, y, 0) - l.at(x - 1, y, 0);
                let gy = l.at(x, y + 1, 0) - l.at(x, y - 1, 0);
                (gx * gx + gy * gy) as f64
            })
            .sum::<f64>()
            / px.len() as f64
    }

    #[test]
    fn each_layer_is_sharpest_in_its_own_frame() {
        let p = small(7, false);
        let scene = Scene::generate(&p);
        let r = render_scene(&p, &scene);
        let mut checked = 0;
        for (li, layer) in scene.layers.iter().enumerate() {
            let Depth::Plane(q) = layer.depth else {
                continue;
            };
            if !layer.textured {
                continue;
            }
            let px = interior(&r.owner, 160, 120, li, 3);
            if px.len() < 40 {
                continue;
            }
            let e: Vec<f64> = r
                .stack
                .frames
                .iter()
                .map(|f| gradient_energy(f, &px))
                .collect();
            let best = (0..e.len()).max_by(|&a, &b| e[a].total_cmp(&e[b])).unwrap();
            assert_eq!(
                best, q as usize,
                "layer {li} ({}) energies {e:?}",
                layer.kind
            );
            // Defocus one plane away must be clearly visible.
            let next = if best + 1 < e.len() {
                e[best + 1]
            } else {
                e[best - 1]
            };
            assert!(
                next < 0.6 * e[best],
                "layer {li} ({}) energies {e:?}",
                layer.kind
            );
            checked += 1;
        }
        assert!(checked >= 5, "only {checked} layers checked");
    }

    #[test]
    fn flat_scene_has_no_gaps_or_halos() {
        // With one colour everywhere any compositing error (unrendered hidden parts, double
        // premultiplication, alpha blurred differently from colour) shows as a deviation.
        for handheld in [false, true] {
            let p = quiet(small(8, handheld));
            let mut scene = Scene::generate(&p);
            scene.flatten([0.7, 0.5, 0.3]);
            let r = render_scene(&p, &scene).stack;
            let want = [179u8, 128, 77];
            for img in r.frames.iter().chain(std::iter::once(&r.truth)) {
                for px in img.data().chunks_exact(3) {
                    for c in 0..3 {
                        assert!(px[c].abs_diff(want[c]) <= 1, "{px:?} handheld {handheld}");
                    }
                }
            }
        }
    }

    #[test]
    fn linear_light_mixes_in_linear_values() {
        // One colour everywhere stays that colour; a blurred edge between black and white mixes
        // to half the light, which displays brighter than half the display value.
        let p = SimParams {
            linear_light: true,
            ..quiet(small(8, true))
        };
        let mut scene = Scene::generate(&p);
        scene.flatten([0.7, 0.5, 0.3]);
        let r = render_scene(&p, &scene).stack;
        for img in r.frames.iter().chain(std::iter::once(&r.truth)) {
            assert!(img
                .data()
                .chunks_exact(3)
                .all(|px| px[0].abs_diff(179) <= 1 && px[1].abs_diff(128) <= 1));
        }
        let m = Mixing::Linear;
        assert!((m.to_display(m.from_display(0.3)) - 0.3).abs() < 1e-6);
        assert!((m.to_display(0.5) - 0.735).abs() < 0.001);
        assert_eq!(Mixing::Display.from_display(0.3), 0.3);
        // Same scene, display vs linear mixing: the sharp truth barely differs (edges only),
        // the defocused frames clearly do.
        let d = render_stack(&quiet(small(13, false)));
        let l = render_stack(&SimParams {
            linear_light: true,
            ..quiet(small(13, false))
        });
        let mean_diff = |a: &Image<u8>, b: &Image<u8>| {
            a.data()
                .iter()
                .zip(b.data())
                .map(|(x, y)| x.abs_diff(*y) as f64)
                .sum::<f64>()
                / a.data().len() as f64
        };
        assert!(mean_diff(&d.truth, &l.truth) < 0.5);
        assert!(mean_diff(&d.frames[0], &l.frames[0]) > 1.0);
        assert_eq!(d.depth, l.depth);
    }

    #[test]
    fn steps_mark_occlusion_edges_only() {
        let p = small(9, false);
        let scene = Scene::generate(&p);
        let r = render_scene(&p, &scene);
        let (w, h) = (160, 120);
        let s = &r.stack.steps;
        let on = s.data().iter().filter(|&&v| v == 255).count();
        assert!(on > 100 && on < w * h / 5, "{on} step pixels");
        for y in 0..h {
            for x in 0..w {
                let k = r.owner[y * w + x];
                let same = [(x + 1, y), (x, y + 1)]
                    .into_iter()
                    .filter(|&(u, v)| u < w && v < h)
                    .all(|(u, v)| r.owner[v * w + u] == k)
                    && (x == 0 || r.owner[y * w + x - 1] == k)
                    && (y == 0 || r.owner[(y - 1) * w + x] == k);
                if same {
                    assert_eq!(s.at(x, y, 0), 0, "({x},{y}) inside layer {k}");
                }
            }
        }
        // Both sides of a step are marked.
        let marked_pairs = (0..h)
            .flat_map(|y| (1..w).map(move |x| (x, y)))
            .filter(|&(x, y)| s.at(x, y, 0) == 255 && s.at(x - 1, y, 0) == 255)
            .count();
        assert!(marked_pairs > 20);
        assert_eq!(r.stack.max_sigma, 9.0);
    }

    #[test]
    fn truth_has_no_dark_gaps_at_edges() {
        // The truth is a convex blend of the layers present at each pixel, so it can never be
        // darker than the darkest of them (a gap would be darker than both sides).
        let p = quiet(small(9, false));
        let scene = Scene::generate(&p);
        let r = render_scene(&p, &scene);
        let mut edges = 0;
        for y in 0..120 {
            for x in 0..160 {
                let (fx, fy) = (x as f64, y as f64);
                let mut lo = [f32::INFINITY; 3];
                for l in &scene.layers {
                    if l.shape.coverage(fx, fy) > 0.0 {
                        let c = l.paint.color(fx, fy);
                        for (m, v) in lo.iter_mut().zip(c) {
                            *m = m.min(v);
                        }
                    }
                }
                for (k, m) in lo.iter().enumerate() {
                    let t = r.stack.truth.at(x, y, k) as f32;
                    assert!(
                        t >= m * 255.0 - 0.6,
                        "({x},{y}) ch {k}: {t} < {}",
                        m * 255.0
                    );
                }
                if x > 0 && r.owner[y * 160 + x] != r.owner[y * 160 + x - 1] {
                    edges += 1;
                }
            }
        }
        assert!(edges > 100);
    }

    #[test]
    fn handheld_frames_warp_back_onto_aligned_frames() {
        let hp = SimParams {
            parallax_px: 0.0,
            ..quiet(small(10, true))
        };
        let ap = SimParams {
            handheld: false,
            ..hp.clone()
        };
        let (hs, al) = (render_stack(&hp), render_stack(&ap));
        assert_eq!(hs.truth, al.truth);
        assert_eq!(hs.depth, al.depth);
        // Bilinear resampling twice (frame from canvas, then back) softens the finest texture, so
        // compare after a light blur, and require the true pose to fit clearly better than the
        // same pose moved by half a pixel.
        // Interior: at most ~9 px of a 160-px frame map outside it (shift 4.8, roll 2.6, scale 1).
        let b = 14;
        let mismatch = |i: usize, a: &Affine| -> f32 {
            let mut sum = 0.0;
            for c in 0..3 {
                let back = warp_affine(&hs.frames[i].to_planes()[c], a, 160, 120).0;
                let (back, want) = (
                    gaussian_blur(&back, 1.0),
                    gaussian_blur(&al.frames[i].to_planes()[c], 1.0),
                );
                for y in b..120 - b {
                    for x in b..160 - b {
                        sum += 255.0 * (back.at(x, y, 0) - want.at(x, y, 0)).abs();
                    }
                }
            }
            sum / (3 * (160 - 2 * b) * (120 - 2 * b)) as f32
        };
        for i in 0..hp.planes {
            if i == hs.reference {
                assert_eq!(hs.frames[i], al.frames[i]);
                continue;
            }
            let a = hs.ref_to_frame[i];
            let e = mismatch(i, &a);
            for (dx, dy) in [(0.5, 0.0), (0.0, 0.5)] {
                let off = Affine([[1.0, 0.0, dx], [0.0, 1.0, dy]]).compose(&a);
                let e_off = mismatch(i, &off);
                assert!(
                    e < 1.5 && e < 0.7 * e_off,
                    "frame {i}: true pose {e:.2}, half-pixel off {e_off:.2}"
                );
            }
        }
    }

    #[test]
    fn parallax_moves_near_layers_only() {
        let base = quiet(small(11, true));
        let with = SimParams {
            parallax_px: 2.0,
            ..base.clone()
        };
        let without = SimParams {
            parallax_px: 0.0,
            ..base
        };
        let (a, b) = (render_stack(&with), render_stack(&without));
        assert_eq!(a.ref_to_frame, b.ref_to_frame);
        assert_eq!(a.frames[a.reference], b.frames[b.reference]);
        let moved = (0..6).filter(|&i| a.frames[i] != b.frames[i]).count();
        assert_eq!(moved, 5);
    }

    #[test]
    fn true_positions_follow_the_affine_plus_near_layer_parallax() {
        let p = SimParams {
            parallax_px: 2.0,
            ..quiet(small(11, true))
        };
        let scene = Scene::generate(&p);
        let r = render_scene(&p, &scene);
        let i = (r.stack.reference + 1) % p.planes;
        let a = r.stack.ref_to_frame[i];
        let pos = true_positions(&p, &scene, &r, i);
        let (mut moved, mut still) = (0, 0);
        for (k, &(u, v)) in pos.iter().enumerate() {
            let (x, y) = ((k % 160) as f64, (k / 160) as f64);
            let (au, av) = a.apply(x, y);
            let d = (u - au).hypot(v - av);
            // Never more than the parallax; the far background exactly on the affine.
            assert!(d <= 2.0 + 1e-9, "{d}");
            if r.owner[k] == 0 && matches!(scene.layers[0].depth, Depth::Plane(_)) {
                assert!(d < 1e-9);
            }
            if d > 0.1 {
                moved += 1;
            } else {
                still += 1;
            }
        }
        assert!(moved > 100 && still > 100, "{moved} moved, {still} still");
        let v = r.stack.info[i].parallax;
        assert!(v[0].hypot(v[1]) > 0.1 && v[0].hypot(v[1]) <= 2.0, "{v:?}");
        let flat = SimParams {
            parallax_px: 0.0,
            ..p
        };
        let r0 = render_scene(&flat, &scene);
        let pos0 = true_positions(&flat, &scene, &r0, i);
        assert!(pos0
            .iter()
            .enumerate()
            .all(|(k, &q)| q == a.apply((k % 160) as f64, (k / 160) as f64)));
    }

    #[test]
    fn noise_and_gain_have_the_requested_size() {
        let mut p = small(12, false);
        p.gain_jitter = 0.0;
        p.noise_sigma = 3.0;
        let noisy = render_stack(&p);
        let clean = render_stack(&quiet(p.clone()));
        let d: Vec<f64> = noisy.frames[1]
            .data()
            .iter()
            .zip(clean.frames[1].data())
            .filter(|(_, &c)| c > 10 && c < 245)
            .map(|(&a, &b)| a as f64 - b as f64)
            .collect();
        let sd = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
        // Read noise 3 plus shot noise at mid grey: ≈ 3·√1.5 ≈ 3.7.
        assert!((3.2..4.3).contains(&sd), "noise sd {sd}");
        p.noise_sigma = 0.0;
        p.gain_jitter = 0.2;
        let g = render_stack(&p);
        for (i, f) in g.frames.iter().enumerate() {
            let k = g.info[i].gain;
            assert!((0.8..=1.2).contains(&k));
            let (mut s1, mut s0) = (0.0, 0.0);
            for (&a, &b) in f.data().iter().zip(clean.frames[i].data()) {
                if b > 20 && b < 200 {
                    s1 += a as f64;
                    s0 += b as f64;
                }
            }
            assert!((s1 / s0 - k).abs() < 0.01, "frame {i}: {} vs {k}", s1 / s0);
        }
    }
}
