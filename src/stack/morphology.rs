//! Square-window minima and maxima and city-block distances over maps of one byte a pixel: the
//! spill stage and the flat-region rule both grow and measure regions with them.

use rayon::prelude::*;

/// The smallest value of `map` within `r` pixels (a square window, truncated at the borders).
/// Separable: along each row the minimum of its 2r+1 shifts, then down the columns the
/// minimum of each row's 2r+1 neighbours, every step a minimum of two whole rows, which the
/// compiler vectorises: at r = 8 about a pixel an instruction, where van Herk's running minima
/// cost a division and two branches a pixel and transposes between.
pub fn window_min(map: &[u8], w: usize, h: usize, r: usize) -> Vec<u8> {
    let into_min = |out: &mut [u8], src: &[u8]| {
        out.iter_mut().zip(src).for_each(|(o, &v)| *o = (*o).min(v));
    };
    let mut rows = map.to_vec();
    rows.par_chunks_mut(w)
        .zip(map.par_chunks(w))
        .for_each(|(out, row)| {
            for o in 1..=r.min(w - 1) {
                into_min(&mut out[..w - o], &row[o..]);
                into_min(&mut out[o..], &row[..w - o]);
            }
        });
    let mut out = rows.clone();
    out.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let near = y.saturating_sub(r)..=(y + r).min(h - 1);
        for yy in near.filter(|&yy| yy != y) {
            into_min(out, &rows[yy * w..][..w]);
        }
    });
    out
}

/// The largest value of `map` within `r` pixels: [`window_min`] of the complement.
pub fn window_max(map: &[u8], w: usize, h: usize, r: usize) -> Vec<u8> {
    let complement: Vec<u8> = map.iter().map(|&v| u8::MAX - v).collect();
    let mut out = window_min(&complement, w, h, r);
    out.iter_mut().for_each(|v| *v = u8::MAX - *v);
    out
}

/// Whether each pixel has a `mask` pixel within `r` (a square window): the window minimum of
/// the mask's complement.
pub fn dilate(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let outside: Vec<u8> = mask.iter().map(|&m| u8::from(!m)).collect();
    window_min(&outside, w, h, r)
        .into_iter()
        .map(|v| v == 0)
        .collect()
}

/// City-block distance of every pixel from the nearest `seed` pixel, at most `cap` (also where
/// no seed is): two raster passes, each from the row before (whole rows, in vector lanes), then
/// along the row. The image's border is not a seed.
pub fn distance(seeds: &[bool], w: usize, h: usize, cap: u8) -> Vec<u8> {
    let mut d: Vec<u8> = seeds.iter().map(|&s| if s { 0 } else { cap }).collect();
    let step = |v: &mut u8, from: u8| *v = (*v).min(from.saturating_add(1));
    for y in 0..h {
        if y > 0 {
            let (before, row) = d[(y - 1) * w..(y + 1) * w].split_at_mut(w);
            row.iter_mut()
                .zip(before.iter())
                .for_each(|(v, &b)| step(v, b));
        }
        let row = &mut d[y * w..][..w];
        for x in 1..w {
            let left = row[x - 1];
            step(&mut row[x], left);
        }
    }
    for y in (0..h).rev() {
        if y + 1 < h {
            let (row, after) = d[y * w..(y + 2) * w].split_at_mut(w);
            row.iter_mut()
                .zip(after.iter())
                .for_each(|(v, &a)| step(v, a));
        }
        let row = &mut d[y * w..][..w];
        for x in (0..w.saturating_sub(1)).rev() {
            let right = row[x + 1];
            step(&mut row[x], right);
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_minimum_is_the_minimum_over_the_window() {
        // Windows narrower than the map and wider than it either way.
        for (w, h, r) in [(23, 17, 3), (23, 17, 0), (5, 17, 8), (23, 4, 8)] {
            let map: Vec<u8> = (0..w * h).map(|i| ((i * 37 + i / 5) % 251) as u8).collect();
            let fast = window_min(&map, w, h, r);
            for y in 0..h {
                for x in 0..w {
                    let slow = (y.saturating_sub(r)..=(y + r).min(h - 1))
                        .flat_map(|yy| {
                            (x.saturating_sub(r)..=(x + r).min(w - 1)).map(move |xx| (xx, yy))
                        })
                        .map(|(xx, yy)| map[yy * w + xx])
                        .min();
                    assert_eq!(Some(fast[y * w + x]), slow, "({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn the_window_maximum_is_the_maximum_over_the_window() {
        let (w, h) = (7, 5);
        let mut map = vec![3u8; w * h];
        map[2 * w + 3] = 200;
        let max = window_max(&map, w, h, 1);
        for y in 0..h {
            for x in 0..w {
                let near = x.abs_diff(3) <= 1 && y.abs_diff(2) <= 1;
                assert_eq!(max[y * w + x], if near { 200 } else { 3 }, "({x}, {y})");
            }
        }
    }

    #[test]
    fn dilation_reaches_a_square_of_the_radius() {
        let (w, h) = (9, 7);
        let mut mask = vec![false; w * h];
        mask[3 * w + 4] = true;
        let grown = dilate(&mask, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let near = x.abs_diff(4) <= 2 && y.abs_diff(3) <= 2;
                assert_eq!(grown[y * w + x], near, "({x}, {y})");
            }
        }
    }

    #[test]
    fn the_distance_is_city_block_and_capped() {
        let (w, h) = (40, 3);
        let mut seeds = vec![false; w * h];
        seeds[w + 2] = true;
        let d = distance(&seeds, w, h, 24);
        assert_eq!(&d[w..w + 6], &[2, 1, 0, 1, 2, 3]);
        assert_eq!((d[2], d[0]), (1, 3));
        assert_eq!(d[w + 39], 24);
        // A cap at the type's limit saturates rather than wrapping.
        let far = distance(&seeds, w, h, u8::MAX);
        assert_eq!(far[w + 39], 37);
        assert!(distance(&[false; 4], 2, 2, u8::MAX)
            .iter()
            .all(|&v| v == 255));
    }
}
