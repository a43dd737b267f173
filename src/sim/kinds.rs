//! Scenes beyond the layered table-top: one surface whose depth changes smoothly with no occlusion
//! (a tilted plane, a dome or cylinder), and dark objects over a light ground or light ones over a
//! dark ground. Each can show a photograph (mirrored to cover any size) in place of procedural
//! texture: on the smooth surface, on the light ground, or on the light objects.

use super::rng::Rng;
use super::scene::{background, blob, colour, tex, Depth, Layer, STREAM_SCENE};
use super::shape::Shape;
use super::texture::{Paint, Pattern, Photo, PhotoPaint};
use super::{SceneKind, SimParams};
use std::sync::Arc;

/// The layers of a scene of `kind` (any but `Layers`), far to near.
pub fn layers(kind: SceneKind, p: &SimParams, photo: Option<Arc<Photo>>) -> Vec<Layer> {
    let mut rng = Rng::stream(p.seed, STREAM_SCENE);
    let (w, h) = (p.width as f64, p.height as f64);
    let q_far = (p.planes - 1) as f64;
    match kind {
        SceneKind::Layers => unreachable!("the table-top is built by Scene::generate"),
        SceneKind::Tilted | SceneKind::Curved => {
            let mut surface = background(&mut rng, w, h, q_far);
            surface.kind = "surface";
            if let Some(photo) = photo {
                surface.paint = photo_paint(&mut rng, photo, 0.0, 1.0);
            }
            surface.depth = if kind == SceneKind::Tilted {
                tilt(&mut rng, w, h, 0.0, q_far)
            } else {
                let centre = (w * rng.range(0.4, 0.6), h * rng.range(0.4, 0.6));
                // Nearest plane at the centre, the farthest at the nearer side edge.
                let reach = centre.0.min(w - centre.0).max(1.0);
                let k = q_far / (reach * reach);
                let along_y = if rng.chance(0.5) { k } else { 0.0 };
                Depth::Curve {
                    centre,
                    q0: 0.0,
                    curvature: (k, along_y),
                    lo: 0.0,
                    hi: q_far,
                }
            };
            vec![surface]
        }
        SceneKind::DarkOnLight | SceneKind::LightOnDark => {
            let dark_objects = kind == SceneKind::DarkOnLight;
            let (ground_range, object_range) = if dark_objects {
                ((0.55, 0.95), (0.03, 0.16))
            } else {
                ((0.03, 0.2), (0.6, 0.95))
            };
            let mut ground = background(&mut rng, w, h, q_far);
            ground.paint = match (&photo, dark_objects) {
                (Some(photo), true) => {
                    photo_paint(&mut rng, photo.clone(), ground_range.0, ground_range.1)
                }
                _ => fbm_paint(&mut rng, ground_range, 18.0),
            };
            ground.depth = tilt(&mut rng, w, h, q_far / 2.0, q_far);
            let mut out = vec![ground];
            let count = 3 + rng.below(3);
            let s = w.min(h);
            let mut objects: Vec<Layer> = (0..count)
                .map(|i| {
                    let c = (w * rng.range(0.15, 0.85), h * rng.range(0.15, 0.85));
                    let r = s * rng.range(0.1, 0.18);
                    let shape = match i % 3 {
                        0 => Shape::Disc { c, r },
                        1 => {
                            let angle = rng.range(0.0, std::f64::consts::PI);
                            blob(&mut rng, c, r, 9, 0.8, 1.1, None, 1.2, angle)
                        }
                        _ => Shape::RoundRect {
                            c,
                            hw: r * 1.2,
                            hh: r * 0.7,
                            radius: r * 0.15,
                            angle: rng.range(-0.6, 0.6),
                        },
                    };
                    let paint = match (&photo, dark_objects) {
                        (Some(photo), false) => {
                            photo_paint(&mut rng, photo.clone(), object_range.0, object_range.1)
                        }
                        _ => fbm_paint(&mut rng, object_range, 7.0),
                    };
                    // The nearest third of the planes, nearer objects composited later.
                    let q = rng.below(p.planes.div_ceil(3)) as f64;
                    Layer {
                        kind: if dark_objects { "dark" } else { "light" },
                        shape,
                        paint,
                        depth: Depth::Plane(q),
                        textured: true,
                    }
                })
                .collect();
            objects.sort_by(|a, b| b.depth.nominal().total_cmp(&a.depth.nominal()));
            out.extend(objects);
            out
        }
    }
}

/// A plane tilted along a random direction: `lo` at one side of the frame, `hi` at the other.
fn tilt(rng: &mut Rng, w: f64, h: f64, lo: f64, hi: f64) -> Depth {
    let dir = rng.range(0.0, std::f64::consts::TAU);
    let (s, c) = dir.sin_cos();
    let span = (w * c).abs() + (h * s).abs();
    let g = (hi - lo) / span;
    Depth::Slant {
        origin: (w / 2.0, h / 2.0),
        q0: (lo + hi) / 2.0,
        grad: (g * c, g * s),
        lo,
        hi,
    }
}

/// The photograph at a random offset, at 1 to 1.5 scene pixels a photo pixel, its values mapped
/// into `lo..=hi`.
fn photo_paint(rng: &mut Rng, photo: Arc<Photo>, lo: f32, hi: f32) -> Paint {
    let origin = (
        rng.range(0.0, photo.width as f64),
        rng.range(0.0, photo.height as f64),
    );
    Paint {
        photo: Some(PhotoPaint {
            photo,
            origin,
            scale: rng.range(1.0, 1.5),
            lo,
            hi,
        }),
        ..Paint::flat([0.0; 3])
    }
}

/// Grainy cloudy texture of a random hue with values in `range`, features of about `scale` px.
fn fbm_paint(rng: &mut Rng, range: (f32, f32), scale: f64) -> Paint {
    let hue = rng.uniform();
    let (lo, hi) = (range.0 as f64, range.1 as f64);
    let mid = (lo + hi) / 2.0;
    let mut t = tex(
        Pattern::Fbm {
            scale: rng.range(scale, 1.5 * scale),
            octaves: 5,
            contrast: 2.4,
        },
        colour(rng, hue, (0.1, 0.4), (mid, hi)),
        colour(rng, hue, (0.2, 0.5), (lo, mid)),
        rng,
    );
    t.grain = 0.1;
    Paint {
        base: t,
        ..Paint::flat([0.0; 3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scene::Scene;

    fn params(scene: SceneKind) -> SimParams {
        SimParams {
            width: 160,
            height: 120,
            planes: 6,
            seed: 4,
            scene,
            ..SimParams::default()
        }
    }

    #[test]
    fn smooth_kinds_are_one_surface_spanning_the_planes() {
        for kind in [SceneKind::Tilted, SceneKind::Curved] {
            let s = Scene::generate(&params(kind));
            assert_eq!(s.layers.len(), 1, "{kind:?}");
            let d = &s.layers[0].depth;
            let q: Vec<f64> = (0..120)
                .flat_map(|y| (0..160).map(move |x| (x as f64, y as f64)))
                .map(|(x, y)| d.at(x, y))
                .collect();
            let (lo, hi) = q
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            assert!(lo < 0.5 && hi > 4.0, "{kind:?}: depth {lo}..{hi}");
        }
    }

    #[test]
    fn occluders_are_darker_or_lighter_than_their_ground() {
        for (kind, darker) in [
            (SceneKind::DarkOnLight, true),
            (SceneKind::LightOnDark, false),
        ] {
            let s = Scene::generate(&params(kind));
            assert!(s.layers.len() >= 4, "{kind:?}");
            let luma = |l: &Layer| {
                let c = l.paint.color(80.0, 60.0);
                (c[0] + c[1] + c[2]) / 3.0
            };
            let ground = luma(&s.layers[0]);
            for o in &s.layers[1..] {
                assert!(o.depth.nominal() < 2.0, "{kind:?}");
                assert_eq!(luma(o) < ground, darker, "{kind:?}");
            }
        }
    }

    #[test]
    fn a_photo_is_mirrored_without_a_seam() {
        let photo = Photo {
            width: 3,
            height: 1,
            rgb: vec![[0.0; 3], [0.5; 3], [1.0; 3]],
        };
        assert_eq!(photo.sample(2.0, 0.0), [1.0; 3]);
        assert_eq!(photo.sample(3.0, 0.0), [0.5; 3]);
        assert_eq!(photo.sample(-1.0, 0.0), [0.5; 3]);
        assert_eq!(photo.sample(1.5, 0.0), [0.75; 3]);
    }
}
