//! sRGB's transfer curve: frames are stored sRGB-encoded, while light mixes (defocus, a raw
//! sensor's samples) in linear values.

/// The linear-light value `v` (clamped to 0..=1) in sRGB's transfer curve.
pub fn encode(v: f32) -> f32 {
    curve(v.clamp(0.0, 1.0))
}

/// An sRGB value `v` (clamped to 0..=1) in linear light.
pub fn decode(v: f32) -> f32 {
    curve_inverse(v.clamp(0.0, 1.0))
}

/// The inverse of [`curve`], for `v` ≥ 0, not clamped above 1.
pub fn curve_inverse(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// sRGB's transfer curve for `v` ≥ 0, not clamped above 1.
pub fn curve(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}
