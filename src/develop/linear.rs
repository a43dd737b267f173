//! Linear demosaics: Malvar, He and Cutler's gradient-corrected filters and bilinear
//! interpolation. Far cheaper than the residual interpolation of [`super::demosaic`] and a few
//! dB worse, but at full size: Malvar–He–Cutler on encoded samples ([`cheap`]) is the cheap
//! development a stack is registered and labelled on, fine detail and all; both are the
//! baselines the demosaic's tests compare with.

use super::demosaic::Padded;
use super::Mosaic;
use crate::stack::image::Image;
use crate::stack::srgb;
use rayon::prelude::*;

/// The cheap full-size development: [`malvar`] on the mosaic's encoded samples, as the full
/// demosaic works, decoded back to linear light.
pub fn cheap(m: &Mosaic) -> Image<f32> {
    encoded(m, malvar)
}

/// `filter` run on the mosaic's sRGB-encoded samples, its output decoded to linear light:
/// what [`super::demosaic::demosaic`] does.
pub fn encoded(m: &Mosaic, filter: fn(&Mosaic) -> Image<f32>) -> Image<f32> {
    let srgb::Tabulated { encode, decode } = srgb::tabulated();
    let encoded = Mosaic {
        data: m.data.iter().map(|&v| encode.at(v)).collect(),
        ..m.clone()
    };
    let mut rgb = filter(&encoded);
    for v in rgb.data_mut() {
        *v = decode.at(*v);
    }
    rgb
}

/// Bilinear interpolation: each missing colour the mean of its samples among the 3×3
/// neighbours, what focusd did first and the baseline the quality tests compare with.
#[cfg(test)]
pub fn bilinear(m: &Mosaic) -> Image<f32> {
    let p = Padded::new(m, |v| v);
    let mut out = Vec::with_capacity(m.width * m.height * 3);
    for y in 0..m.height {
        for x in 0..m.width {
            let mut sum = [0f32; 3];
            let mut n = [0f32; 3];
            for dy in -1..=1isize {
                for dx in -1..=1isize {
                    // The padding mirrors, so the colour at (x+dx, y+dy) is the pattern's.
                    let c = m.order.channel(
                        (x + 2).wrapping_add_signed(dx),
                        (y + 2).wrapping_add_signed(dy),
                    );
                    sum[c] += p.at(x, y, dx, dy);
                    n[c] += 1.0;
                }
            }
            let own = m.order.channel(x, y);
            for c in 0..3 {
                out.push(if c == own {
                    p.at(x, y, 0, 0)
                } else {
                    sum[c] / n[c]
                });
            }
        }
    }
    Image::from_vec(m.width, m.height, 3, out)
}

/// Malvar, He and Cutler's gradient-corrected linear interpolation ("High-quality linear
/// interpolation for demosaicing of Bayer-patterned color images", ICASSP 2004), what
/// focusd used before residual interpolation: the bilinear estimate of a missing colour
/// plus a fraction of the Laplacian of the colour the pixel has. In the mosaic's own
/// encoding.
pub fn malvar(m: &Mosaic) -> Image<f32> {
    let p = Padded::new(m, |v| v);
    let mut out = vec![0.0f32; m.width * m.height * 3];
    if m.width == 0 {
        return Image::from_vec(m.width, m.height, 3, out);
    }
    out.par_chunks_mut(m.width * 3)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, px) in row.chunks_exact_mut(3).enumerate() {
                let s = |dx: isize, dy: isize| p.at(x, y, dx, dy);
                let c = s(0, 0);
                // The filters of the paper's figure 2, each times 8.
                let cross = s(-1, 0) + s(1, 0) + s(0, -1) + s(0, 1);
                let far = s(-2, 0) + s(2, 0) + s(0, -2) + s(0, 2);
                let diag = s(-1, -1) + s(1, -1) + s(-1, 1) + s(1, 1);
                let far_h = s(-2, 0) + s(2, 0);
                let far_v = s(0, -2) + s(0, 2);
                // Green at a red or blue sample.
                let g_at_rb = (4.0 * c + 2.0 * cross - far) / 8.0;
                // Red (blue) at a green sample whose row holds red (blue): from left and right.
                let from_row =
                    (5.0 * c + 4.0 * (s(-1, 0) + s(1, 0)) - diag - far_h + 0.5 * far_v) / 8.0;
                // ... whose column holds it: from above and below.
                let from_col =
                    (5.0 * c + 4.0 * (s(0, -1) + s(0, 1)) - diag - far_v + 0.5 * far_h) / 8.0;
                // Red at blue, blue at red: from the diagonals.
                let from_diag = (6.0 * c + 2.0 * diag - 1.5 * far) / 8.0;
                let rgb = match m.order.channel(x, y) {
                    0 => [c, g_at_rb, from_diag],
                    2 => [from_diag, g_at_rb, c],
                    _ if m.order.channel(x + 1, y) == 0 => [from_row, c, from_col],
                    _ => [from_col, c, from_row],
                };
                px.copy_from_slice(&rgb);
            }
        });
    Image::from_vec(m.width, m.height, 3, out)
}
