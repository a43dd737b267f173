//! The halo stages do no harm where there is nothing for them to do: on simulated stacks whose
//! true motion is an affine (a tripod whose lens breathes, a hand-held sweep without parallax),
//! of content the layered table-top does not draw (dark objects on a light ground and the
//! reverse, strong defocus, photographs), local registration keeps no field; on a stack whose
//! depth is smooth (no occlusion), spill removal changes nothing.

use focusd::files::imageio::load_rgb8;
use focusd::sim::render::render_scene;
use focusd::sim::scene::Scene;
use focusd::sim::texture::Photo;
use focusd::sim::{SceneKind, SimParams};
use focusd::stack::internal::{register, Plane};
use focusd::stack::{fuse, FuseParams, NoProgress, RegisterParams};
use std::path::Path;
use std::sync::Arc;

/// A small linear-light stack of `scene` with strong defocus (σ 3 px a plane, up to 12).
fn strong(scene: SceneKind, seed: u64) -> SimParams {
    SimParams {
        width: 640,
        height: 480,
        planes: 6,
        seed,
        scene,
        blur_per_plane: 3.0,
        max_blur: 12.0,
        linear_light: true,
        ..SimParams::default()
    }
}

/// A committed photograph (sim-data/photos/SOURCES), e.g. gravel: texture the ground can be
/// registered on.
fn photo(name: &str) -> Arc<Photo> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("sim-data/photos/{name}.png"));
    Arc::new(Photo::from_rgb8(&load_rgb8(&path).unwrap()))
}

/// The 99th percentile displacement of every frame's local field (0 where it kept none).
fn fields(p: &SimParams) -> Vec<f64> {
    let s = render_scene(p, &Scene::generate_with(p, Some(photo("gravel")))).stack;
    let lumas: Vec<Plane> = s.frames.iter().map(|f| f.luma()).collect();
    let reg = register(&lumas, s.reference, &RegisterParams::default()).unwrap();
    reg.field
        .iter()
        .map(|f| f.as_ref().map_or(0.0, |f| f.reach(0.99)))
        .collect()
}

#[test]
fn a_tripod_stack_with_strong_defocus_at_a_dark_occluder_keeps_no_field() {
    let p = SimParams {
        tripod_breathing: 0.006,
        ..strong(SceneKind::DarkOnLight, 3)
    };
    let f = fields(&p);
    assert!(f.iter().all(|&r| r == 0.0), "fields (p99 px) {f:.2?}");
}

#[test]
fn a_hand_held_stack_without_parallax_keeps_no_field() {
    let p = SimParams {
        handheld: true,
        parallax_px: 0.0,
        ..strong(SceneKind::DarkOnLight, 4)
    };
    let f = fields(&p);
    assert!(f.iter().all(|&r| r == 0.0), "fields (p99 px) {f:.2?}");
}

#[test]
fn a_smooth_depth_stack_is_unchanged_by_spill_removal() {
    // A photograph on a tilted plane: depth changes smoothly everywhere, no object occludes
    // another, so there is no spill to take out and nothing to keep out of nearer labels.
    let p = SimParams {
        width: 400,
        height: 300,
        planes: 6,
        seed: 5,
        scene: SceneKind::Tilted,
        linear_light: true,
        ..SimParams::default()
    };
    let s = render_scene(&p, &Scene::generate_with(&p, Some(photo("coffee")))).stack;
    let fused = |spill: bool| {
        let params = FuseParams {
            reference: s.reference,
            // A tripod without breathing: the frames are aligned as rendered.
            align: None,
            spill,
            ..FuseParams::default()
        };
        fuse(s.frames.clone(), &params, &NoProgress).unwrap()
    };
    let (on, off) = (fused(true), fused(false));
    assert_eq!(on.labels, off.labels);
    let differ = on
        .image
        .data()
        .iter()
        .zip(off.image.data())
        .filter(|(a, b)| a != b)
        .count();
    assert_eq!(differ, 0, "{differ} samples differ");
}
