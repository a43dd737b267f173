//! The last step of both raw developments, a row at a time: encoded camera RGB decoded to
//! linear light, through the colour matrix and to 8-bit sRGB. It runs on every pixel of every
//! cheap development, so where the CPU has AVX2 eight pixels go at once, their table values
//! gathered: the same operations in the same order (no fused multiply-add), so the same bytes.

use super::{Developer, Encode8};
use crate::stack::srgb::{self, Curve};

/// [`Developer`]'s colour matrix with the tables the row's values go through.
pub struct Pixels<'a> {
    developer: &'a Developer,
    decode: &'static Curve,
    to8: Encode8,
}

impl<'a> Pixels<'a> {
    pub fn new(developer: &'a Developer) -> Pixels<'a> {
        Pixels {
            developer,
            decode: &srgb::tabulated().decode,
            to8: Encode8::table(),
        }
    }

    /// Pixels `rgb` (a row of each channel's encoded values) into `out`, three bytes a pixel.
    pub fn row(&self, rgb: [&[f32]; 3], out: &mut [u8]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2.
            unsafe { self.row_avx2(rgb, out) };
            return;
        }
        self.scalar(rgb, out);
    }

    fn scalar(&self, rgb: [&[f32]; 3], out: &mut [u8]) {
        for (k, px) in out.chunks_exact_mut(3).enumerate() {
            let linear = rgb.map(|c| self.decode.at(c[k]));
            let v = self.developer.srgb(linear);
            for (o, v) in px.iter_mut().zip(v) {
                *o = self.to8.at(v);
            }
        }
    }

    /// [`Pixels::scalar`] eight pixels at a time; a group with a value the table does not
    /// hold (beyond [`Curve::RANGE`], or NaN) goes the scalar way. Plain loops, no closures,
    /// so that every intrinsic is compiled for AVX2 in place.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn row_avx2(&self, rgb: [&[f32]; 3], out: &mut [u8]) {
        use std::arch::x86_64::*;
        let n = out.len() / 3;
        assert!(rgb.iter().all(|c| c.len() >= n), "a row of each channel");
        let (table, scale) = self.decode.table();
        let table = table.as_ptr() as *const f32;
        let bytes = self.to8.bytes();
        assert!(bytes.len() >= Encode8::STEPS + 4, "the table's padding");
        let bytes = bytes.as_ptr() as *const i32;
        let magnitude = _mm256_castsi256_ps(_mm256_set1_epi32(i32::MAX));
        let sign = _mm256_castsi256_ps(_mm256_set1_epi32(i32::MIN));
        let (zero, one, half) = (
            _mm256_setzero_ps(),
            _mm256_set1_ps(1.0),
            _mm256_set1_ps(0.5),
        );
        let (range, scale) = (_mm256_set1_ps(Curve::RANGE), _mm256_set1_ps(scale));
        let steps = _mm256_set1_ps(Encode8::STEPS as f32);
        let low_byte = _mm256_set1_epi32(0xff);
        let mut m = [[zero; 3]; 3];
        for (row, m) in self.developer.matrix.iter().zip(&mut m) {
            for (v, m) in row.iter().zip(m) {
                *m = _mm256_set1_ps(*v);
            }
        }
        let mut k = 0;
        while k + 8 <= n {
            let mut v = [zero; 3];
            let mut held = true;
            for c in 0..3 {
                // SAFETY: k + 8 <= n <= the row's length.
                v[c] = unsafe { _mm256_loadu_ps(rgb[c].as_ptr().add(k)) };
                let a = _mm256_and_ps(v[c], magnitude);
                held &= _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(a, range)) == 0xff;
            }
            if !held {
                self.scalar(
                    [&rgb[0][k..k + 8], &rgb[1][k..k + 8], &rgb[2][k..k + 8]],
                    &mut out[3 * k..3 * k + 24],
                );
                k += 8;
                continue;
            }
            // Curve::at: the sign of v times the step's start plus the fraction of its rise.
            let mut linear = [zero; 3];
            for c in 0..3 {
                let x = _mm256_mul_ps(_mm256_and_ps(v[c], magnitude), scale);
                let i = _mm256_cvttps_epi32(x);
                // SAFETY: 0 <= i < the table's steps, each two floats.
                let (lo, rise) = unsafe {
                    (
                        _mm256_i32gather_ps::<8>(table, i),
                        _mm256_i32gather_ps::<8>(table.add(1), i),
                    )
                };
                let fraction = _mm256_sub_ps(x, _mm256_cvtepi32_ps(i));
                let t = _mm256_add_ps(lo, _mm256_mul_ps(fraction, rise));
                linear[c] = _mm256_mul_ps(_mm256_or_ps(_mm256_and_ps(v[c], sign), one), t);
            }
            // The matrix, then Encode8::at: clamped to 0..=1 (NaN to 0), to the nearest step.
            let mut coded = [[0i32; 8]; 3];
            for c in 0..3 {
                let s = _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_mul_ps(m[c][0], linear[0]),
                        _mm256_mul_ps(m[c][1], linear[1]),
                    ),
                    _mm256_mul_ps(m[c][2], linear[2]),
                );
                let clamped = _mm256_min_ps(_mm256_max_ps(s, zero), one);
                let i = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(clamped, steps), half));
                // SAFETY: 0 <= i <= STEPS, and four bytes from there are in the padded table;
                // the store fills `coded[c]`'s eight words.
                unsafe {
                    let b = _mm256_and_si256(_mm256_i32gather_epi32::<1>(bytes, i), low_byte);
                    _mm256_storeu_si256(coded[c].as_mut_ptr() as *mut __m256i, b);
                }
            }
            for (j, px) in out[3 * k..3 * k + 24].chunks_exact_mut(3).enumerate() {
                px[0] = coded[0][j] as u8;
                px[1] = coded[1][j] as u8;
                px[2] = coded[2][j] as u8;
            }
            k += 8;
        }
        self.scalar(
            [&rgb[0][k..n], &rgb[1][k..n], &rgb[2][k..n]],
            &mut out[3 * k..3 * n],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_is_its_pixels_taken_one_by_one() {
        let developer = Developer::new(0, [[1.3, -0.2, -0.1], [-0.1, 1.2, -0.1], [0.0, -0.3, 1.3]]);
        let pixels = Pixels::new(&developer);
        // Values across the table and beyond it, negative ones, a NaN, and a row whose length
        // is no multiple of eight.
        let n = 203;
        let value = |k: usize, c: usize| match (k * 7 + c * 13) % 101 {
            0 => f32::NAN,
            1 => 2.5,
            2 => -2.25,
            j => (j as f32 - 20.0) / 70.0 + k as f32 * 1e-4,
        };
        let rgb: [Vec<f32>; 3] = std::array::from_fn(|c| (0..n).map(|k| value(k, c)).collect());
        let rows = [&rgb[0][..], &rgb[1][..], &rgb[2][..]];
        let mut got = vec![0u8; 3 * n];
        pixels.row(rows, &mut got);
        let mut want = vec![0u8; 3 * n];
        pixels.scalar(rows, &mut want);
        assert_eq!(got, want);
        assert!(want.contains(&255) && want.contains(&0));
        assert!(want.iter().any(|&v| v > 0 && v < 255));
    }
}
