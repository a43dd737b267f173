//! The committed stacks and bundles under sim-data/, and loading their pictures.

use focusd::stack::Image;
use focusd::stack::Transforms;
use std::path::{Path, PathBuf};

/// A path under the repository's sim-data/.
pub fn sim_data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("sim-data")
        .join(rel)
}

/// A committed replay bundle (sim-data/bundles/NAME).
pub fn bundle_dir(name: &str) -> PathBuf {
    sim_data("bundles").join(name)
}

/// The committed hand-held stack: its frames' paths, in order, and its true transforms.
pub fn handheld() -> (Vec<PathBuf>, Transforms) {
    let dir = sim_data("handheld");
    let t: Transforms =
        serde_json::from_slice(&std::fs::read(dir.join("transforms.json")).unwrap()).unwrap();
    let files = t.frames.iter().map(|f| dir.join(&f.file)).collect();
    (files, t)
}

/// A picture as 8-bit RGB.
pub fn load(path: &Path) -> Image<u8> {
    let img = image::open(path).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    Image::from_vec(w as usize, h as usize, 3, img.into_raw())
}

/// The EXIF Orientation of an image file, read with an EXIF reader (kamadak-exif).
pub fn exif_orientation(path: &Path) -> Option<u32> {
    let bytes = std::fs::read(path).ok()?;
    let exif = exif::Reader::new()
        .read_from_container(&mut std::io::Cursor::new(bytes))
        .ok()?;
    exif.get_field(exif::Tag::Orientation, exif::In::PRIMARY)?
        .value
        .get_uint(0)
}
