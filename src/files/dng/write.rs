//! Writing a raw take as a DNG: one uncompressed CFA image in IFD0 (8-bit samples as bytes,
//! deeper ones as 16-bit words), its tags, and an EXIF directory for the exposure and date.
//!
//! The `tiff` crate's encoder lays out the file: it takes any tag by number, so the DNG tags
//! need no hand-written TIFF; only PhotometricInterpretation is set over the grey image it
//! would otherwise declare.

use super::{cfa_pattern, color_matrix, tag, CFA, D65};
use crate::base::civil;
use crate::develop::{grey_world, RawFrame};
use crate::files::error::FileError;
use crate::files::orientation::Orientation;
use std::io::Cursor;
use std::time::Duration;
use tiff::encoder::{colortype, Rational, SRational, TiffEncoder};
use tiff::tags::Tag;

/// What a DNG says besides the mosaic.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DngInfo {
    /// The turns that make the picture upright (the sensor's mounting and the hold).
    pub orientation: Orientation,
    /// The camera's maker, where known.
    pub make: Option<String>,
    /// The camera model (Model and UniqueCameraModel): the device profile's name.
    pub model: String,
    pub exposure: Option<Duration>,
    /// When the take was made, in seconds since the Unix epoch.
    pub taken: Option<u64>,
}

/// The DNG of `frame`. The black level is the frame's, the white level the largest code of
/// its depth; ColorMatrix1 is the one matching its development matrix ([`color_matrix`]), and
/// AsShotNeutral the frame's white balance (grey-world measured on it where it has none), so a
/// raw tool balances as focusd does.
pub fn encode(frame: &RawFrame, info: &DngInfo) -> Result<Vec<u8>, FileError> {
    let bad = |reason: String| FileError::Unsupported {
        path: format!("DNG of {}", info.model),
        reason,
    };
    let samples = frame.samples().map_err(bad)?;
    let cm = color_matrix(frame.matrix).ok_or_else(|| {
        bad(format!(
            "colour matrix {:?} is singular: no DNG ColorMatrix1 maps to it",
            frame.matrix
        ))
    })?;
    let gains = match frame.white_balance {
        Some(gains) => gains,
        None => grey_world(&[&frame.mosaic().map_err(bad)?]),
    };
    let (w, h) = (frame.width as u32, frame.height as u32);
    let bits = frame.bits();

    let mut out = Cursor::new(Vec::new());
    let mut tiff = TiffEncoder::new(&mut out)?;
    let exif = match (info.exposure, info.taken) {
        (None, None) => None,
        (exposure, taken) => {
            let mut dir = tiff.extra_directory()?;
            if let Some(t) = exposure {
                let us = u32::try_from(t.as_micros()).unwrap_or(u32::MAX);
                dir.write_tag(
                    Tag::Unknown(tag::EXPOSURE_TIME),
                    Rational {
                        n: us,
                        d: 1_000_000,
                    },
                )?;
            }
            if let Some(secs) = taken {
                let [y, mo, d, h, mi, s] = civil::utc(secs);
                let date = format!("{y:04}:{mo:02}:{d:02} {h:02}:{mi:02}:{s:02}");
                dir.write_tag(Tag::Unknown(tag::DATE_TIME_ORIGINAL), date.as_str())?;
            }
            Some(dir.finish_with_offsets()?.offset)
        }
    };
    macro_rules! image {
        ($color:ty, $data:expr) => {{
            let mut img = tiff.new_image::<$color>(w, h)?;
            let dir = img.encoder();
            dir.write_tag(Tag::Unknown(tag::NEW_SUBFILE_TYPE), 0u32)?;
            dir.write_tag(Tag::Unknown(tag::PHOTOMETRIC), CFA)?;
            dir.write_tag(Tag::Unknown(tag::ORIENTATION), info.orientation.exif())?;
            if let Some(make) = &info.make {
                dir.write_tag(Tag::Make, make.as_str())?;
            }
            dir.write_tag(Tag::Model, info.model.as_str())?;
            dir.write_tag(Tag::Software, "focusd")?;
            if let Some(offset) = exif {
                // LONG, as EXIF specifies for the pointer (some readers refuse the IFD type).
                dir.write_tag(Tag::ExifDirectory, offset)?;
            }
            dir.write_tag(Tag::Unknown(tag::CFA_REPEAT_PATTERN_DIM), &[2u16, 2][..])?;
            dir.write_tag(
                Tag::Unknown(tag::CFA_PATTERN),
                &cfa_pattern(frame.order)[..],
            )?;
            dir.write_tag(Tag::Unknown(tag::DNG_VERSION), &[1u8, 4, 0, 0][..])?;
            dir.write_tag(Tag::Unknown(tag::DNG_BACKWARD_VERSION), &[1u8, 1, 0, 0][..])?;
            dir.write_tag(Tag::Unknown(tag::UNIQUE_CAMERA_MODEL), info.model.as_str())?;
            dir.write_tag(Tag::Unknown(tag::BLACK_LEVEL_REPEAT_DIM), &[1u16, 1][..])?;
            dir.write_tag(Tag::Unknown(tag::BLACK_LEVEL), frame.black_level)?;
            dir.write_tag(Tag::Unknown(tag::WHITE_LEVEL), (1u32 << bits) - 1)?;
            let cm: Vec<SRational> = cm
                .transpose()
                .iter()
                .map(|&v| SRational {
                    n: (v * 1e6).round() as i32,
                    d: 1_000_000,
                })
                .collect();
            dir.write_tag(Tag::Unknown(tag::COLOR_MATRIX_1), &cm[..])?;
            dir.write_tag(Tag::Unknown(tag::CALIBRATION_ILLUMINANT_1), D65)?;
            let neutral = gains.map(|g| Rational {
                n: (1e6 / g).round() as u32,
                d: 1_000_000,
            });
            dir.write_tag(Tag::Unknown(tag::AS_SHOT_NEUTRAL), &neutral[..])?;
            img.write_data($data)?;
        }};
    }
    if bits == 8 {
        let bytes: Vec<u8> = samples.iter().map(|&s| s as u8).collect();
        image!(colortype::Gray8, &bytes);
    } else {
        image!(colortype::Gray16, &samples);
    }
    Ok(out.into_inner())
}
