//! Resampling a plane into another frame's geometry through an affine transform, for rendering
//! simulated hand-held frames (the engine warps interleaved frames itself, in `stack::align`).

use crate::stack::image::Plane;
use crate::stack::transform::Affine;
use rayon::prelude::*;

/// Samples `src` at `dst_to_src(x, y)` for every pixel of a `width`×`height` output (bilinear).
/// Returns the warped plane and a coverage mask (1 where the source point lies inside `src`, else 0;
/// uncovered pixels take the nearest edge value so later filters see no artificial black).
pub fn warp_affine(
    src: &Plane,
    dst_to_src: &Affine,
    width: usize,
    height: usize,
) -> (Plane, Plane) {
    let mut out = vec![0.0f32; width * height];
    let mut cov = vec![0.0f32; width * height];
    let (sw, sh) = (src.width() as f64 - 1.0, src.height() as f64 - 1.0);
    out.par_chunks_mut(width)
        .zip(cov.par_chunks_mut(width))
        .enumerate()
        .for_each(|(y, (orow, crow))| {
            for x in 0..width {
                let (sx, sy) = dst_to_src.apply(x as f64, y as f64);
                orow[x] = src.sample_bilinear(sx as f32, sy as f32);
                let inside = (-0.5..=sw + 0.5).contains(&sx) && (-0.5..=sh + 0.5).contains(&sy);
                crow[x] = if inside { 1.0 } else { 0.0 };
            }
        });
    (
        Plane::from_vec(width, height, 1, out),
        Plane::from_vec(width, height, 1, cov),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn translation_shifts_content_and_marks_coverage() {
        let src = Plane::from_fn(8, 6, 1, |x, y, _| (x + 10 * y) as f32);
        let t = Affine([[1.0, 0.0, 2.0], [0.0, 1.0, 1.0]]);
        let (w, c) = warp_affine(&src, &t, 8, 6);
        assert_eq!(w.at(0, 0, 0), src.at(2, 1, 0));
        assert_eq!(w.at(5, 4, 0), src.at(7, 5, 0));
        assert_eq!(c.at(5, 4, 0), 1.0);
        assert_eq!(c.at(7, 5, 0), 0.0);
    }
}
