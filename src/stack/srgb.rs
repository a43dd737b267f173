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

/// The sRGB curve (or its inverse) extended oddly below 0 and on above 1, so that noise
/// around black and balanced highlights keep their values through the round trip (raw
/// development). Tabulated on 0..2 and interpolated: a `powf` per sample took most of a
/// frame's development, and a tenth of the spill stage in linear light.
pub struct Curve {
    f: fn(f32) -> f32,
    /// Per step of the table, the curve at its start and the rise to the next step's start.
    table: Vec<[f32; 2]>,
}

const CURVE_RANGE: f32 = 2.0;
const CURVE_STEPS: usize = 8192;

impl Curve {
    /// Tabulates `f`: [`curve`] or [`curve_inverse`].
    fn new(f: fn(f32) -> f32) -> Curve {
        let at: Vec<f32> = (0..=CURVE_STEPS)
            .map(|i| f(i as f32 * CURVE_RANGE / CURVE_STEPS as f32))
            .collect();
        let table = at.windows(2).map(|s| [s[0], s[1] - s[0]]).collect();
        Curve { f, table }
    }

    /// The table [`Curve::at`] interpolates, and the factor from a value's magnitude to its
    /// step; magnitudes from [`Curve::RANGE`] on take the formula instead: for vector code
    /// that must give `at`'s values.
    #[cfg(target_arch = "x86_64")]
    pub fn table(&self) -> (&[[f32; 2]], f32) {
        (&self.table, CURVE_STEPS as f32 / CURVE_RANGE)
    }

    /// Magnitudes from here on take the formula, not the table.
    #[cfg(target_arch = "x86_64")]
    pub const RANGE: f32 = CURVE_RANGE;

    /// The curve at `v`, within 2e-5 of the formula.
    #[inline]
    pub fn at(&self, v: f32) -> f32 {
        let a = v.abs();
        // NaN too takes the formula (NaN either way).
        if a >= CURVE_RANGE || a.is_nan() {
            return v.signum() * (self.f)(a);
        }
        let x = a * (CURVE_STEPS as f32 / CURVE_RANGE);
        // SAFETY: 0 <= x < CURVE_STEPS, a whole step inside i32 (a saturating `as` costs
        // several instructions a sample).
        let i: i32 = unsafe { x.to_int_unchecked() };
        let [lo, rise] = self.table[i as usize];
        // `signum` with v not NaN.
        1f32.copysign(v) * (lo + (x - i as f32) * rise)
    }
}

/// sRGB's curve and its inverse as [`Curve`]s.
pub struct Tabulated {
    pub encode: Curve,
    pub decode: Curve,
}

/// [`Tabulated`] curves, made once for the process.
pub fn tabulated() -> &'static Tabulated {
    static CURVES: std::sync::OnceLock<Tabulated> = std::sync::OnceLock::new();
    CURVES.get_or_init(|| Tabulated {
        encode: Curve::new(curve),
        decode: Curve::new(curve_inverse),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tabulated_curves_follow_the_formulas() {
        for f in [curve, curve_inverse] {
            let c = Curve::new(f);
            for i in -3000..=3000 {
                let v = i as f32 / 1000.0;
                let exact = v.signum() * f(v.abs());
                assert!(
                    (c.at(v) - exact).abs() < 2e-5,
                    "{v}: {} against {exact}",
                    c.at(v)
                );
            }
        }
    }
}
