//! A take's file as the camera would hand it over: a picture (JPEG, PNG, TIFF) as a developed
//! frame, a DNG as a raw mosaic, which the capture then develops as it does the camera's.

use crate::capture::Frame;
use crate::files::dng;
use crate::files::orientation::Orientation;
use std::path::Path;

/// Loads a take. A DNG take is stored as the sensor reads it: the bundle's `rotation` says how
/// to turn it, so one that asks to be turned (Orientation other than 1) is refused.
pub fn load(path: &Path) -> Result<Frame, String> {
    let chain = |e: &crate::files::FileError| crate::base::clip::chain(e);
    if !dng::is_dng(path) {
        return crate::files::imageio::load_rgb8(path)
            .map(Frame::Picture)
            .map_err(|e| chain(&e));
    }
    let d = dng::load(path).map_err(|e| chain(&e))?;
    if d.orientation != Orientation::UPRIGHT {
        return Err(format!(
            "{}: Orientation {} in a replay bundle; store the take as the sensor reads it \
             (Orientation 1) and give the turn as the bundle's rotation",
            path.display(),
            d.orientation.exif()
        ));
    }
    Ok(Frame::Raw(d.raw))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::dng::{encode, DngInfo};
    use crate::sim::bundle::raw_take;
    use crate::stack::image::Image;

    #[test]
    fn a_dng_take_is_raw_and_must_not_ask_to_be_turned() {
        let dir = tempfile::tempdir().unwrap();
        let raw = raw_take(&Image::from_fn(8, 6, 3, |x, y, c| {
            (x * 20 + y * 9 + c) as u8
        }));
        for (turns, name) in [(0, "a.dng"), (1, "b.DNG")] {
            let info = DngInfo {
                orientation: Orientation::clockwise(turns),
                ..DngInfo::default()
            };
            std::fs::write(dir.path().join(name), encode(&raw, &info).unwrap()).unwrap();
        }
        match load(&dir.path().join("a.dng")) {
            // The colour matrix comes back to the four places DNG stores it in.
            Ok(Frame::Raw(r)) => assert_eq!(
                (r.bytes, r.width, r.order, r.black_level),
                (raw.bytes.clone(), raw.width, raw.order, raw.black_level)
            ),
            other => panic!("{:?}", other.map(|_| "a picture")),
        }
        let e = load(&dir.path().join("b.DNG")).err().unwrap();
        assert!(e.contains("Orientation 6 in a replay bundle"), "{e}");
    }
}
