//! Raw takes as DNG (Adobe's Digital Negative, a TIFF): written so that raw tools (darktable,
//! RawTherapee, LibRaw) open focusd's mosaics, and read so that `fuse` takes other cameras'.
//!
//! Only what a Bayer mosaic needs: one uncompressed CFA image, its 2×2 pattern, black and white
//! levels, orientation, and a colour matrix. Where a camera profile gives no colour data,
//! focusd develops camera RGB as linear sRGB; the matrix written then says exactly that
//! (ColorMatrix1 = XYZ to linear sRGB under D65), so other tools render what focusd does.

mod read;
mod write;

pub use read::{decode, load, probe, DngFrame};
pub use write::{encode, DngInfo};

use crate::develop::BayerOrder;
use nalgebra::Matrix3;
use std::path::Path;

/// Whether `path` names a DNG, by its extension (any case).
pub fn is_dng(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("dng"))
}

/// The TIFF and DNG tags focusd writes or reads, by number.
mod tag {
    pub const NEW_SUBFILE_TYPE: u16 = 254;
    pub const IMAGE_WIDTH: u16 = 256;
    pub const IMAGE_LENGTH: u16 = 257;
    pub const BITS_PER_SAMPLE: u16 = 258;
    pub const COMPRESSION: u16 = 259;
    pub const PHOTOMETRIC: u16 = 262;
    pub const STRIP_OFFSETS: u16 = 273;
    pub const ORIENTATION: u16 = 274;
    pub const SAMPLES_PER_PIXEL: u16 = 277;
    pub const ROWS_PER_STRIP: u16 = 278;
    pub const STRIP_BYTE_COUNTS: u16 = 279;
    pub const PLANAR_CONFIGURATION: u16 = 284;
    pub const TILE_WIDTH: u16 = 322;
    pub const TILE_LENGTH: u16 = 323;
    pub const TILE_OFFSETS: u16 = 324;
    pub const TILE_BYTE_COUNTS: u16 = 325;
    pub const SUB_IFDS: u16 = 330;
    pub const SAMPLE_FORMAT: u16 = 339;
    pub const CFA_REPEAT_PATTERN_DIM: u16 = 33421;
    pub const CFA_PATTERN: u16 = 33422;
    pub const EXPOSURE_TIME: u16 = 33434;
    pub const DATE_TIME_ORIGINAL: u16 = 36867;
    pub const DNG_VERSION: u16 = 50706;
    pub const DNG_BACKWARD_VERSION: u16 = 50707;
    pub const UNIQUE_CAMERA_MODEL: u16 = 50708;
    pub const CFA_PLANE_COLOR: u16 = 50710;
    pub const CFA_LAYOUT: u16 = 50711;
    pub const LINEARIZATION_TABLE: u16 = 50712;
    pub const BLACK_LEVEL_REPEAT_DIM: u16 = 50713;
    pub const BLACK_LEVEL: u16 = 50714;
    pub const BLACK_LEVEL_DELTA_H: u16 = 50715;
    pub const BLACK_LEVEL_DELTA_V: u16 = 50716;
    pub const WHITE_LEVEL: u16 = 50717;
    pub const COLOR_MATRIX_1: u16 = 50721;
    pub const COLOR_MATRIX_2: u16 = 50722;
    pub const AS_SHOT_NEUTRAL: u16 = 50728;
    pub const CALIBRATION_ILLUMINANT_1: u16 = 50778;
    pub const CALIBRATION_ILLUMINANT_2: u16 = 50779;
    pub const ACTIVE_AREA: u16 = 50829;
}

/// PhotometricInterpretation of a colour filter array image.
const CFA: u16 = 32803;
/// CalibrationIlluminant: D65.
const D65: u16 = 21;

/// CFAPattern's four colours (0 red, 1 green, 2 blue) of a Bayer order, row by row.
fn cfa_pattern(order: BayerOrder) -> [u8; 4] {
    [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(x, y)| order.channel(x, y) as u8)
}

/// The Bayer order of a CFAPattern, if it is one.
fn bayer_order(pattern: &[u32]) -> Option<BayerOrder> {
    [
        BayerOrder::Rggb,
        BayerOrder::Bggr,
        BayerOrder::Grbg,
        BayerOrder::Gbrg,
    ]
    .into_iter()
    .find(|&o| {
        cfa_pattern(o)
            .iter()
            .map(|&c| u32::from(c))
            .eq(pattern.iter().copied())
    })
}

/// Linear sRGB to CIE XYZ, D65 white (IEC 61966-2-1).
fn srgb_to_xyz() -> Matrix3<f64> {
    Matrix3::new(
        0.4124564, 0.3575761, 0.1804375, //
        0.2126729, 0.7151522, 0.0721750, //
        0.0193339, 0.1191920, 0.9503041,
    )
}

fn matrix3(m: [[f32; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| f64::from(m[r][c]))
}

/// ColorMatrix1 (XYZ to camera RGB under D65) of a development matrix (white-balanced camera
/// RGB to linear sRGB, rows summing to 1): camera RGB = M⁻¹ · (XYZ to sRGB) · XYZ. With the
/// identity, the XYZ-to-sRGB matrix. `None` for a singular matrix.
fn color_matrix(develop: [[f32; 3]; 3]) -> Option<Matrix3<f64>> {
    Some(matrix3(develop).try_inverse()? * srgb_to_xyz().try_inverse()?)
}

/// The development matrix of a ColorMatrix (XYZ to camera RGB under D65): camera RGB, balanced
/// so that D65 white is (1, 1, 1), to linear sRGB; [`color_matrix`]'s inverse.
fn development_matrix(cm: Matrix3<f64>) -> Option<[[f32; 3]; 3]> {
    let cam_from_srgb = cm * srgb_to_xyz();
    let neutral = cam_from_srgb * nalgebra::Vector3::repeat(1.0);
    if neutral.iter().any(|&n| !(n.is_finite() && n > 1e-6)) {
        return None;
    }
    let m = cam_from_srgb.try_inverse()? * Matrix3::from_diagonal(&neutral);
    let out = [0, 1, 2].map(|r| [0, 1, 2].map(|c| m[(r, c)] as f32));
    out.iter().flatten().all(|v| v.is_finite()).then_some(out)
}

#[cfg(test)]
mod tests;
