//! What a fuse holds in memory, and how it is fitted to a budget.
//!
//! The frames and the label map are held whole for the whole fuse; what a budget shrinks is the
//! rest: the compose works in row bands of the output (see `compose::bands`), the graph cut's
//! focus maps are recomputed per band of rows instead of held whole, and registration prepares
//! fewer frames at once. Below what even the smallest bands need, the fuse still runs, in the
//! smallest bands: a phone that swaps is slower, one whose job aborted has nothing. Estimates are
//! in bytes and are checked against `/usr/bin/time -v` by `benches/bench-memory`.

use super::align::{refine_lanes, warp_lanes, warp_scratch_rows};
use super::compose::{band_grid, bytes_per_row, pyramid_levels};
use super::params::{FuseParams, Method};
use super::register::finest_level;
use super::repair::flat_regions;
use super::spill;
use std::fmt;

/// Label bands are whole rows of the graph cut's 64-pixel tiles.
const LABEL_GRID: usize = 64;

/// Resident memory of the process before any frame: code, thread stacks, allocator.
const RUNTIME: usize = 8 << 20;

/// A stack's geometry.
#[derive(Clone, Copy, Debug)]
pub struct Stack {
    pub frames: usize,
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    /// 1 for 8-bit frames, 2 for 16-bit.
    pub sample_bytes: usize,
    /// Bytes held beside the frames until the compose: a lazily developed stack's raw frames
    /// (`refine`), 0 for developed ones.
    pub held: usize,
    /// Bytes developing one of those frames takes while it runs.
    pub developing: usize,
}

/// How a fuse spends its memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub budget: usize,
    /// Output rows composed at once (`usize::MAX`: the whole image in one band).
    pub band_rows: usize,
    /// Rows whose focus amplitudes the labelling holds at once (`usize::MAX`: all of them).
    pub label_rows: usize,
    /// Frames registered at once: one per thread, or fewer when the budget is tight.
    pub concurrent_frames: usize,
    /// Estimated peak of this plan, and of the leanest one (bands as tall as their margins, one
    /// frame registered at once).
    pub peak: usize,
    pub floor: usize,
}

impl Plan {
    pub fn fits(&self) -> bool {
        self.floor <= self.budget
    }
}

/// Bytes in MiB, rounded up.
pub fn mib(bytes: usize) -> usize {
    bytes.div_ceil(1 << 20)
}

impl fmt::Display for Plan {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let mut bands = match self.band_rows {
            usize::MAX => "whole-image compose".to_string(),
            r => format!("compose in bands of {r} rows"),
        };
        if self.label_rows != usize::MAX {
            bands += &format!(", focus maps in bands of {} rows", self.label_rows);
        }
        if self.fits() {
            let (peak, budget) = (mib(self.peak), mib(self.budget));
            write!(f, "about {peak} MiB of the {budget} MiB budget ({bands})")
        } else {
            let (floor, budget) = (mib(self.floor), mib(self.budget));
            write!(
                f,
                "this stack needs about {floor} MiB even in the smallest bands, over the \
                 {budget} MiB memory budget; fused anyway ({bands})"
            )
        }
    }
}

/// Plans a fuse of `s` with `p` in `p.memory` bytes.
pub fn plan(s: &Stack, p: &FuseParams) -> Plan {
    let px = s.width * s.height;
    let frame = px * s.channels * s.sample_bytes;
    let frames = s.frames * frame + s.held;
    let budget = p.memory;
    let room = budget.saturating_sub(RUNTIME);
    // Each frame being prepared: its reduced levels and keypoint scale space (measured at
    // 3 MP: 9.3 bytes a pixel with the full-resolution luma plane registration made then, 4
    // of them; its luma now streams into the first reduction), plus level 0 itself where
    // registration keeps it (`register::finest_level`). Then, refining, every frame's levels
    // from the finest the refinement visits (at most `refine_pixels`, half size at most) up,
    // and a stack of eight blurs of that level for the reference and each frame refined at
    // once.
    let fine = p.align.as_ref().map_or(0, |a| a.refine_pixels.min(px / 4));
    let full_level = p
        .align
        .as_ref()
        .is_some_and(|a| finest_level(s.width, s.height, a) == 0);
    let prepared = if full_level { 10 } else { 6 };
    let refine = |k: usize| s.frames * fine * 16 / 3 + (k + 1) * 8 * 4 * fine;
    let register = |k: usize| frames + (k * px * prepared).max(refine(k));
    // Warping: the frames, the spare frame each is warped into, and the rows of the frame a
    // band of the warp reads, as floats in the warp's lanes (four a pixel for colour: one
    // vector multiply-add a tap).
    let scratch = s.width * warp_scratch_rows(s.width, s.height);
    let warp = frames + frame + 4 * scratch * warp_lanes(s.channels);
    // Focus amplitudes (u16 per frame) and their maximum, the label, free, texture and strip
    // maps (a frame's luma is made a row at a time as its amplitudes are measured); in bands,
    // the amplitudes of a band's rows and, while each frame's are measured for the coarse
    // level, one frame's at full size.
    let maps = 6 * px;
    let labels_whole = frames + maps + (s.frames + 1) * 2 * px;
    let labels_banded = |rows: usize| {
        let band = (s.frames + 1) * 2 * (rows + 2) * s.width;
        frames + maps + band.max(2 * px)
    };
    let graphcut = p.method == Method::GraphCut;
    let label_rows = if !graphcut || labels_whole <= room {
        usize::MAX
    } else {
        (1..s.height.div_ceil(LABEL_GRID))
            .rev()
            .map(|k| k * LABEL_GRID)
            .find(|&r| labels_banded(r) <= room)
            .unwrap_or(LABEL_GRID)
    };
    let labels = |rows: usize| match (graphcut, rows) {
        (false, _) => 0,
        (true, usize::MAX) => labels_whole,
        (true, r) => labels_banded(r),
    };
    let levels = pyramid_levels(
        s.width,
        s.height,
        match p.method {
            Method::GraphCut => Some(p.graphcut.blend_levels),
            Method::Pyramid => None,
        },
    );
    let (grid, margin) = band_grid(levels);
    // Smaller bands than their margin would spend most of the compose on the margins.
    let least = margin;
    let per_row = bytes_per_row(s.width, s.channels, s.sample_bytes);
    // The label map, the output image and the choice map, beside the frames; after taking the
    // spill out, where the labels tell depth (`spill::Unmixed::told`).
    let told = (graphcut && p.spill) as usize * px;
    let compose_base = frames + 2 * px + told + frame;
    let compose =
        |rows: usize| compose_base + rows.saturating_add(2 * margin).min(s.height) * per_row;
    let threads = rayon::current_num_threads().min(s.frames.max(1));
    let concurrent = (1..=threads)
        .rev()
        .find(|&k| register(k) <= room)
        .unwrap_or(1);
    let fit_rows = (room.saturating_sub(compose_base) / per_row).saturating_sub(2 * margin);
    let band_rows = if fit_rows + 2 * margin >= s.height {
        usize::MAX
    } else {
        (fit_rows / grid).max(least / grid) * grid
    };
    // Taking the spill out: the frames, the label and texture maps and the un-mixing's own
    // buffers, or before them the flat regions' when the labels are repaired
    // (`flat_regions::settle`).
    let unmix = match graphcut && p.spill {
        true => {
            let own = spill::working_bytes(s.frames, s.width, s.height, s.channels);
            let settle = match p.label_repair {
                true => flat_regions::working_bytes(px, rayon::current_num_threads()),
                false => 0,
            };
            frames + 2 * px + own.max(settle)
        }
        false => 0,
    };
    // Developing lazily: the development's working planes, the regions of the frames developed
    // together both ways (at most a whole frame's worth each, `refine`), and the rows of their
    // difference and cheap development a band of the warp reads.
    let develop = match s.held {
        0 => 0,
        _ => frames + s.developing + 2 * frame + 4 * scratch * refine_lanes(s.channels),
    };
    let peak_of = |k: usize, label_rows: usize, rows: usize| {
        let stages = [
            register(k),
            warp,
            labels(label_rows),
            unmix,
            develop,
            compose(rows),
        ];
        RUNTIME + stages.into_iter().max().unwrap_or(0)
    };
    Plan {
        budget,
        band_rows,
        label_rows,
        concurrent_frames: concurrent,
        peak: peak_of(concurrent, label_rows, band_rows),
        floor: peak_of(1, LABEL_GRID, least),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stack(frames: usize, width: usize, height: usize) -> Stack {
        Stack {
            frames,
            width,
            height,
            channels: 3,
            sample_bytes: 1,
            held: 0,
            developing: 0,
        }
    }

    fn params(mb: usize) -> FuseParams {
        FuseParams {
            memory: mb << 20,
            ..FuseParams::default()
        }
    }

    #[test]
    fn raw_frames_held_until_the_compose_are_planned_for() {
        // 10 frames of 3 MP held as 16-bit mosaics, 24 bytes a pixel to develop one.
        let developed = stack(10, 2048, 1536);
        let px = 2048 * 1536;
        let raw = Stack {
            held: 10 * px * 2,
            developing: 24 * px,
            ..developed
        };
        let p = params(4096);
        let (a, b) = (plan(&developed, &p), plan(&raw, &p));
        assert!(b.peak >= a.peak + raw.held, "{} against {}", b.peak, a.peak);
        // Developing one frame while the others wait is a stage of its own.
        let lazy = RUNTIME + 10 * px * 3 + raw.held + raw.developing + 2 * px * 3;
        assert!(b.peak >= lazy, "{} below {lazy}", b.peak);
    }

    #[test]
    fn a_roomy_budget_composes_whole_and_a_tight_one_in_bands() {
        let s = stack(10, 2048, 1536);
        let roomy = plan(&s, &params(4096));
        assert_eq!(roomy.band_rows, usize::MAX);
        assert!(roomy.fits() && roomy.peak <= roomy.budget);
        let tight = plan(&s, &params(220));
        assert!(tight.band_rows < 1536, "{tight:?}");
        assert_eq!(tight.band_rows % 16, 0);
        assert!(
            tight.peak <= tight.budget && tight.peak < roomy.peak,
            "{tight:?}"
        );
    }

    #[test]
    fn below_the_floor_the_smallest_bands_are_planned_not_an_error() {
        let s = stack(15, 3000, 2000);
        let p = plan(&s, &params(100));
        assert!(!p.fits());
        assert_eq!((p.band_rows, p.label_rows), (128, 64));
        assert_eq!(p.peak, p.floor);
        assert!(p.floor > 15 * 3000 * 2000 * 3, "the frames alone are more");
    }
}
