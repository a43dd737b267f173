//! `focusd fuse` on the committed hand-held stack: saved transforms against the true ones,
//! `--crop`, and an unrelated frame refused by name.

use focusd::stack::Transforms;
use std::path::PathBuf;
use std::process::{Command, Output};

mod common;
use common::stacks::{handheld, sim_data};

fn fuse(args: &[&str], frames: &[PathBuf]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_focusd"))
        .arg("fuse")
        .args(args)
        .args(frames)
        .output()
        .unwrap()
}

#[test]
fn saved_transforms_are_within_a_third_of_a_pixel_and_crop_shrinks() {
    let (frames, truth) = handheld();
    let dir = tempfile::tempdir().unwrap();
    let (out, json) = (dir.path().join("out.png"), dir.path().join("t.json"));
    let o = fuse(
        &[
            "--crop",
            "--reference",
            &truth.reference.to_string(),
            "-o",
            out.to_str().unwrap(),
            "--save-transforms",
            json.to_str().unwrap(),
        ],
        &frames,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let saved: Transforms = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(saved.reference, truth.reference);
    assert_eq!(saved.size, truth.size);
    let [w, h] = truth.size;
    let errors: Vec<f64> = saved
        .frames
        .iter()
        .zip(&truth.frames)
        .map(|(s, t)| s.ref_to_frame.corner_error(&t.ref_to_frame, w, h))
        .collect();
    let mean = errors.iter().sum::<f64>() / (errors.len() - 1) as f64;
    assert!(mean <= 0.3, "corner errors {errors:.3?}");
    assert!(saved.frames[3].file.ends_with("frame_03.jpg"));
    let img = image::open(&out).unwrap();
    assert!(img.width() < w as u32 && img.height() < h as u32);
    assert!(err.contains("crop"), "{err}");
}

#[test]
fn unrelated_frame_is_refused_by_name() {
    let (mut frames, _) = handheld();
    let other = sim_data("aligned/frame_03.jpg");
    frames[5] = other;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.jpg");
    let o = fuse(&["-o", out.to_str().unwrap()], &frames);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("aligned/frame_03.jpg: frame 5 cannot be registered"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn alignment_options_need_alignment() {
    let (frames, _) = handheld();
    let o = fuse(&["--no-align", "--crop", "-o", "/tmp/never.png"], &frames);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot be used with"));
}
