//! The cheap development: one RGB pixel a 2×2 Bayer cell (its red, the mean of its two greens,
//! its blue), at half the frame's size. No interpolation, so about a hundredth of the full
//! demosaic's work: what a preview shows and what the fusion registers and labels with.

use super::Mosaic;
use crate::stack::image::Image;
use rayon::prelude::*;

/// Camera RGB at half size (`width / 2` × `height / 2`; an odd last row or column is left
/// out): pixel (x, y) is the cell whose top-left sample is (2x, 2y).
pub fn half_size(m: &Mosaic) -> Image<f32> {
    let (w, h) = (m.width / 2, m.height / 2);
    let mut data = vec![0.0f32; w * h * 3];
    // Where each colour sits in a cell, as offsets into the two rows.
    let mut at = [[0usize; 2]; 3];
    let mut greens = 0;
    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
        match m.order.channel(dx, dy) {
            1 => {
                at[1][greens] = dy * m.width + dx;
                greens += 1;
            }
            c => at[c] = [dy * m.width + dx; 2],
        }
    }
    if w > 0 {
        data.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
            let cells = &m.data[2 * y * m.width..];
            for (x, px) in row.chunks_exact_mut(3).enumerate() {
                for (v, [a, b]) in px.iter_mut().zip(at) {
                    *v = 0.5 * (cells[2 * x + a] + cells[2 * x + b]);
                }
            }
        });
    }
    Image::from_vec(w, h, 3, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::develop::{decode, BayerOrder};
    use crate::sim::{self, SimParams};
    use crate::stack::metrics::psnr;

    /// The truth averaged over 2×2 cells, channel by channel: what a half-size development
    /// of a perfect sensor would give if each colour were sampled over the whole cell.
    fn box_half(rgb: &Image<f32>) -> Image<f32> {
        Image::from_fn(rgb.width() / 2, rgb.height() / 2, 3, |x, y, c| {
            let s: f32 = [(0, 0), (0, 1), (1, 0), (1, 1)]
                .iter()
                .map(|(dx, dy)| rgb.at(2 * x + dx, 2 * y + dy, c))
                .sum();
            s / 4.0
        })
    }

    #[test]
    fn each_cell_gives_its_own_colours_in_every_order() {
        // A 4×2 mosaic: cell 0 holds 0.1..0.4, cell 1 0.5..0.8, row by row.
        let data = vec![0.1, 0.2, 0.5, 0.6, 0.3, 0.4, 0.7, 0.8];
        for (order, want) in [
            (BayerOrder::Rggb, [0.1, 0.25, 0.4]),
            (BayerOrder::Bggr, [0.4, 0.25, 0.1]),
            (BayerOrder::Grbg, [0.2, 0.25, 0.3]),
            (BayerOrder::Gbrg, [0.3, 0.25, 0.2]),
        ] {
            let m = Mosaic {
                width: 4,
                height: 2,
                order,
                data: data.clone(),
            };
            let img = half_size(&m);
            assert_eq!((img.width(), img.height()), (2, 1));
            for (c, w) in want.iter().enumerate() {
                assert!(
                    (img.at(0, 0, c) - w).abs() < 1e-6,
                    "{order:?} {:?}",
                    img.data()
                );
                assert!((img.at(1, 0, c) - (w + 0.4)).abs() < 1e-6, "{order:?}");
            }
        }
    }

    #[test]
    fn an_odd_last_row_and_column_are_left_out() {
        let m = Mosaic {
            width: 5,
            height: 3,
            order: BayerOrder::Rggb,
            data: vec![0.5; 15],
        };
        let img = half_size(&m);
        assert_eq!((img.width(), img.height()), (2, 1));
        assert!(img.data().iter().all(|&v| v == 0.5));
    }

    #[test]
    fn half_size_is_close_to_the_truth_averaged_over_cells() {
        // Each colour is sampled at one or two of a cell's four sites, so sharp scenes lose
        // some accuracy against the cell average; still a faithful small picture.
        let truth = decode(&sim::render(&SimParams::demosaic_scene(3)).truth);
        let want = crate::develop::encode(&box_half(&truth));
        for order in [BayerOrder::Rggb, BayerOrder::Gbrg] {
            let got = crate::develop::encode(&half_size(&Mosaic::sample(&truth, order)));
            let db = psnr(&got, &want, 0);
            eprintln!("{order:?}: {db:.2} dB against the cell averages");
            assert!(db > 25.0, "{order:?}: {db:.2} dB");
        }
    }
}
