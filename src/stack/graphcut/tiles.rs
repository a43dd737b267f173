//! Tile scheduling: a level solved by α-expansion in windows, in parallel, over passes with
//! the tile grid shifted, each window's costs gathered into contiguous memory first.

use super::costs::{color_diff, seam, Focus, Level};
use super::ties::Ties;
use super::GraphCutParams;
use crate::stack::expansion::{expand, neighbours, Costs, Grid, Move};
use crate::stack::image::{Image, Sample};
use crate::stack::maxflow::GridMaxflow;
use crate::stack::{Progress, Stage};
use rayon::prelude::*;

/// One tile's problem gathered into contiguous memory: the costs of the few labels worth trying,
/// for the tile and a ring of fixed pixels around it. Reading ten full-size frames at scattered
/// addresses for every edge of every move is what made the solve slow.
///
/// Only the pixels a move reads are gathered, the free ones and their neighbours; the others'
/// entries are left zero. Where few pixels of a tile are free (the later passes' strips, the
/// full resolution's band) gathering them all cost as much as the moves.
pub(super) struct TileCosts<T> {
    /// Label → slot in the tables below.
    pub(super) slot: [u8; 256],
    pub(super) slots: usize,
    pub(super) channels: usize,
    /// `[pixel][slot][channel]` colours.
    pub(super) colors: Vec<T>,
    /// `[pixel][slot]` focus costs.
    pub(super) unary: Vec<i32>,
    pub(super) kappa: i32,
}

impl<T: Sample> TileCosts<T> {
    /// Gathers the rectangle `(x0, y0, w, h)` of `level` for `labels`, at the pixels `read`
    /// marks (row-major in the rectangle).
    pub(super) fn gather(
        level: &Level<T>,
        width: usize,
        rect: (usize, usize, usize, usize),
        labels: &[u8],
        read: &[bool],
    ) -> Self {
        let (x0, y0, w, h) = rect;
        let mut slot = [u8::MAX; 256];
        for (k, &l) in labels.iter().enumerate() {
            slot[l as usize] = k as u8;
        }
        let (ns, ch) = (labels.len(), level.channels);
        let mut colors = Vec::with_capacity(w * h * ns * ch);
        let mut unary = Vec::with_capacity(w * h * ns);
        for (y, read) in (y0..y0 + h).zip(read.chunks_exact(w)) {
            for (x, &read) in (x0..x0 + w).zip(read) {
                if !read {
                    colors.resize(colors.len() + ns * ch, T::default());
                    unary.resize(unary.len() + ns, 0);
                    continue;
                }
                let p = y * width + x;
                let terms = level.pixel_terms(p);
                for &l in labels {
                    // Sample by sample: a memcpy call for each label's three samples cost more
                    // than the copy.
                    for &c in level.colors(p, l) {
                        colors.push(c);
                    }
                    unary.push(level.unary_with(p, l, terms));
                }
            }
        }
        Self {
            slot,
            slots: ns,
            channels: ch,
            colors,
            unary,
            kappa: level.kappa,
        }
    }
}

impl<T: Sample> Costs for TileCosts<T> {
    #[inline]
    fn unary(&self, p: usize, l: u8) -> i32 {
        self.unary[p * self.slots + self.slot[l as usize] as usize]
    }

    /// Each label's slot is looked up once for both pixels rather than per pixel: the lookups
    /// are a large share of the seam cost's instructions.
    #[inline]
    fn pairwise(&self, p: usize, q: usize, lp: u8, lq: u8) -> i32 {
        let ch = self.channels;
        let (a, b) = (
            self.slot[lp as usize] as usize * ch,
            self.slot[lq as usize] as usize * ch,
        );
        let row = self.slots * ch;
        seam(self.kappa, p, q, lp, lq, |i| {
            let px = &self.colors[i * row..(i + 1) * row];
            color_diff(&px[a..a + ch], &px[b..b + ch])
        })
    }
}

/// One level's problem: its frames' colours, where its focus amplitudes come from, λ.
pub(super) struct Solve<'a, T> {
    pub(super) frames: &'a [Image<T>],
    pub(super) focus: &'a Focus<'a, T>,
    pub(super) lambda: f32,
    pub(super) params: &'a GraphCutParams,
    pub(super) ties: &'a Ties<'a>,
}

impl<T: Sample> Solve<'_, T> {
    /// Runs α-expansion over tiles in parallel, `passes` times with the tile grid shifted by
    /// half a tile between passes so no tile border stays fixed. With banded focus amplitudes,
    /// the windows of a pass are solved a band of rows at a time; every window of a pass still
    /// sees the labels as they were before the pass, so the bands change nothing.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn tiled(
        &self,
        w: usize,
        h: usize,
        labels: &mut [u8],
        free: Option<&[bool]>,
        tile: usize,
        passes: usize,
        progress: &dyn Progress,
    ) {
        let windows_for = |offset: usize| -> Vec<Window> {
            let starts = |n: usize| -> Vec<usize> {
                let mut s = vec![0];
                let mut v = if offset > 0 && offset < n {
                    offset
                } else {
                    tile
                };
                while v < n {
                    s.push(v);
                    v += tile;
                }
                s
            };
            let (xs, ys) = (starts(w), starts(h));
            let mut out = Vec::new();
            for (j, &y0) in ys.iter().enumerate() {
                let y1 = ys.get(j + 1).copied().unwrap_or(h);
                for (i, &x0) in xs.iter().enumerate() {
                    let x1 = xs.get(i + 1).copied().unwrap_or(w);
                    out.push(Window {
                        x0,
                        y0,
                        w: x1 - x0,
                        h: y1 - y0,
                    });
                }
            }
            out
        };
        let plans: Vec<Vec<Window>> = (0..passes)
            .map(|k| windows_for(if k % 2 == 1 { tile / 2 } else { 0 }))
            .collect();
        progress.stage(Stage::Labels, plans.iter().map(Vec::len).sum());
        // After the first pass each tile is optimal for its fixed borders, so later passes
        // only re-solve the strips along the first pass's tile borders (`border_strips`).
        let reach = tile / self.params.border_strips;
        let near_border = |v: usize| v % tile < reach || v % tile >= tile - reach;
        let strips: Vec<bool> = (0..w * h)
            .into_par_iter()
            .map(|p| free.is_none_or(|f| f[p]) && (near_border(p % w) || near_border(p / w)))
            .collect();
        for (k, windows) in plans.into_iter().enumerate() {
            let mut results: Vec<(Window, Vec<u8>)> = Vec::new();
            let grid = Grid {
                width: w,
                height: h,
                labels,
                free: if k == 0 { free } else { Some(&strips) },
            };
            // Windows come row of tiles by row of tiles: a band is as many rows of them as fit.
            let mut rest = &windows[..];
            while let Some(first) = rest.first() {
                let limit = first.y0.saturating_add(self.focus.rows());
                let n = rest
                    .iter()
                    .position(|v| v.y0 + v.h > limit.max(first.y0 + v.h))
                    .unwrap_or(rest.len());
                let (band, next) = rest.split_at(n.max(1));
                rest = next;
                let y1 = band.iter().map(|v| v.y0 + v.h).max().unwrap_or(h);
                let rows = first.y0.saturating_sub(1)..(y1 + 1).min(h);
                self.focus.with(rows, |amps| {
                    let level = Level::new(self.frames, amps, self.lambda, self.params, self.ties);
                    results.par_extend(
                        band.par_iter()
                            .map_init(GridMaxflow::new, |solver, &win| {
                                let r = solve_window(&grid, win, &level, self.params, solver);
                                progress.advance(1);
                                r.map(|out| (win, out))
                            })
                            .flatten(),
                    );
                });
            }
            for (win, out) in results {
                for y in 0..win.h {
                    let s = (win.y0 + y) * w + win.x0;
                    labels[s..s + win.w].copy_from_slice(&out[y * win.w..(y + 1) * win.w]);
                }
            }
        }
    }
}

/// A rectangle of the label grid.
#[derive(Clone, Copy, Debug)]
pub(super) struct Window {
    x0: usize,
    y0: usize,
    pub(super) w: usize,
    pub(super) h: usize,
}

/// Solves one window as its own grid, with a ring of fixed pixels around it; returns the
/// window's new labels, or `None` when nothing in it may change.
pub(super) fn solve_window<T: Sample>(
    grid: &Grid,
    win: Window,
    level: &Level<T>,
    params: &GraphCutParams,
    solver: &mut GridMaxflow,
) -> Option<Vec<u8>> {
    let (gw, gh) = (grid.width, grid.height);
    let (rx0, ry0) = (win.x0.saturating_sub(1), win.y0.saturating_sub(1));
    let (rx1, ry1) = ((win.x0 + win.w + 1).min(gw), (win.y0 + win.h + 1).min(gh));
    let (rw, rh) = (rx1 - rx0, ry1 - ry0);
    let mut labels = Vec::with_capacity(rw * rh);
    let mut free = Vec::with_capacity(rw * rh);
    for y in ry0..ry1 {
        labels.extend_from_slice(&grid.labels[y * gw + rx0..y * gw + rx1]);
        for x in rx0..rx1 {
            let inside =
                (win.x0..win.x0 + win.w).contains(&x) && (win.y0..win.y0 + win.h).contains(&y);
            free.push(inside && grid.free.is_none_or(|f| f[y * gw + x]));
        }
    }
    let local = Grid {
        width: rw,
        height: rh,
        labels: &labels,
        free: Some(&free),
    };
    let moves = moves(&local, (rx0, ry0, gw), level, params.candidates)?;
    let offered: Vec<u8> = moves.iter().map(|m| m.label).collect();
    let read: Vec<bool> = (0..rw * rh)
        .map(|p| free[p] || neighbours(rw, rh, p).any(|q| free[q]))
        .collect();
    let costs = TileCosts::gather(level, gw, (rx0, ry0, rw, rh), &offered, &read);
    let out = expand(&local, moves, &costs, params.max_cycles, solver);
    let (ox, oy) = (win.x0 - rx0, win.y0 - ry0);
    Some(
        (0..win.h)
            .flat_map(|y| {
                out[(oy + y) * rw + ox..(oy + y) * rw + ox + win.w]
                    .iter()
                    .copied()
            })
            .collect(),
    )
}

/// The expansion moves of a window's grid (`local`, at `(x0, y0)` of a level `width` wide): each
/// free pixel is offered its `k` sharpest frames, the fallback where that ties with them
/// ([`GraphCutParams::tie_bias`]), and the labels it and its 4 neighbours hold (without the
/// fallback, exhaustive expansion takes it over pixels the candidates never offer it). In label
/// order; `None` when no pixel is free.
pub(super) fn moves<T: Sample>(
    local: &Grid,
    (x0, y0, width): (usize, usize, usize),
    level: &Level<T>,
    k: usize,
) -> Option<Vec<Move>> {
    let (w, h) = (local.width, local.height);
    let mut pixels: Vec<Vec<u32>> = vec![Vec::new(); 256];
    let mut top = Vec::new();
    let mut any_free = false;
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            if !local.free.is_none_or(|f| f[p]) {
                continue;
            }
            any_free = true;
            let at = (y0 + y) * width + x0 + x;
            level.sharpest(at, k, &mut top);
            if level.ties(at) {
                top.push(level.ties.fallback);
            }
            // The labels offered, as a set of 256 bits: sorting and deduplicating a list of
            // them costs more than the bits.
            let mut offer = [0u64; 4];
            let own = neighbours(w, h, p).chain([p]).map(|q| local.labels[q]);
            for l in top.iter().copied().chain(own) {
                offer[l as usize / 64] |= 1 << (l % 64);
            }
            for (word, mut bits) in offer.into_iter().enumerate() {
                while bits != 0 {
                    pixels[word * 64 + bits.trailing_zeros() as usize].push(p as u32);
                    bits &= bits - 1;
                }
            }
        }
    }
    any_free.then(|| {
        (0..=255u8)
            .zip(pixels)
            .filter(|(_, px)| !px.is_empty())
            .map(|(label, pixels)| Move { label, pixels })
            .collect()
    })
}
