//! Flat regions take the frame that shows their outline crisp.
//!
//! Where no frame has texture (a plain object, a clear sky) the focus cost ties, so the label
//! there says nothing of depth. Inside such a region that costs nothing, every frame showing it
//! alike, but at its rim it does: next to a plain near object's edge, the frames focused
//! farther show the background's texture through the object's defocused edge, which the focus
//! measure takes for the sharpest detail there. The rim is then labelled with a far frame, the
//! object is composed with a blurred, haloed edge, and the spill removal finds no near region to
//! take the halo out of (the replay bundles' magenta disc).
//!
//! The cue is the region's outline. The frame focused on a plain object shows it flat right up
//! to a crisp edge; a defocused frame shows a blurred ramp there, or texture seen through it,
//! before any edge. So each flat region is grown, in each frame, through the pixels that frame
//! shows flat (at most [`REACH`] px beyond it), and the frame whose grown region is bounded by a
//! crisp edge on the largest share of its outline shows the region's own edge. That frame labels
//! the grown region and the crisp edge around it when three things hold:
//! - the answer is clear ([`MIN_SHARE`], [`MARGIN`]);
//! - the frame is focused at least [`MIN_STEP`] planes nearer than the one labelled around the
//!   region: the failure mended here is always a far frame on a plain near object's rim, and
//!   neighbouring planes blur each other too little for it to show. Allowed both ways, the rule
//!   moved many small patches of the layered test stacks' textured backgrounds to wrong frames;
//! - the crisp outline is the region's own ([`OWN_EDGE`]): what lies just beyond it is labelled
//!   farther still. An occluder's edge bounds the background it hides crisply too, in the
//!   occluder's frame; without this test a strip of `bundles/calm`'s cloudy background beside a
//!   near star went to the star's frame and lost its soft texture.

use crate::stack::align::Coverage;
use crate::stack::image::{Image, Sample};
use crate::stack::morphology::{dilate, distance};
use crate::stack::order::MIN_STEP;
use rayon::prelude::*;
use std::ops::Range;

/// Pixels a flat region needs to be decided: smaller ones are gaps in texture, not objects.
pub const MIN_AREA: usize = 64;
/// A flat region whose bounding box is larger than this share of the frame (its inverse) is a
/// background, not a plain near object, and is left as it is: deciding one costs as much as its
/// box, and a background region sprawling over most of the frame is never taken anyway.
pub const LARGEST: usize = 4;
/// How far beyond a flat region (px) a frame may show it flat: the widest rim over which a
/// defocused frame shows texture through a plain object's edge, about 2σ of the deepest blur
/// (σ up to 9 px on the simulated stacks). A wider rim is not reached, and then nothing moves.
pub const REACH: usize = 20;
/// The steepest step to a neighbour (full scale 1, after a 3×3 binomial smoothing) of a pixel
/// shown flat: about 5 of 255, above sensor noise and JPEG ringing on a plain surface.
pub const FLAT: f32 = 0.02;
/// The steepest step of a crisp edge: a step of 0.18 (the bundle's disc against its background
/// in green) blurred by σ = 2 px peaks at 0.036 a pixel.
pub const CRISP: f32 = 0.05;
/// An outline pixel counts as crisp when a crisp step lies within this many pixels of it: a
/// region stops at the foot of its edge, not at its steepest point.
pub const POOL: usize = 2;
/// The share of its outline a frame must show crisp to claim a region, and its lead over every
/// other frame. On the replay bundles' scene the disc's own frame shows 0.65 of its outline
/// crisp and the next frame 0.30; patches of a textured background reach 0.2–0.45 in several
/// frames at once.
pub const MIN_SHARE: f64 = 0.6;
pub const MARGIN: f64 = 0.2;
/// Pixels past a region's grown edge where what lies beyond it is read.
pub const BEYOND: Range<usize> = 3..6;
/// The share of what lies beyond a region's crisp outline (its pixels [`BEYOND`] the grown
/// region) that must be labelled farther than the claiming frame: the disc of `bundles/shaken`
/// has 153 of 160 such pixels, the two strips of `bundles/calm` beside occluders 2 of 79 and 0
/// of 59.
pub const OWN_EDGE: f64 = 0.5;

/// Beyond the pixels a region may grow into and their pooling: distances are capped here.
const FAR: u8 = (REACH + POOL + 2) as u8;

/// Bytes [`settle`] holds at most besides the frames and the maps it is given, for the memory
/// plan: with `threads` regions or frames decided at once, each a window (up to the whole frame)
/// of three maps of one byte a pixel for its region and two for a frame's flags and growth.
pub fn working_bytes(pixels: usize, threads: usize) -> usize {
    threads * 5 * pixels + pixels
}

/// Per-pixel flags of one frame on a window.
const SHOWN_FLAT: u8 = 1;
const STEEP: u8 = 2;

/// What settling the flat regions did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Settled {
    /// Flat regions given a nearer frame.
    pub regions: usize,
    /// Pixels whose label changed.
    pub pixels: usize,
}

/// Gives each flat region of `labels` (the pixels `told` leaves out: on entry, where the
/// labelling's focus measure found no texture) the frame that shows its outline crisp, where
/// that frame is clear and nearer than the frame labelled around it (see the module's doc), and
/// marks the pixels it labels in `told`: their labels now say something of depth. `depth_of`
/// maps a frame to its rank along the focus axis, 0 nearest.
pub fn settle<T: Sample>(
    frames: &[Image<T>],
    coverage: &[Coverage],
    labels: &mut [u8],
    told: &mut [bool],
    depth_of: &(dyn Fn(usize) -> usize + Sync),
) -> Settled {
    let textured = &*told;
    let Some(f0) = frames.first() else {
        return Settled::default();
    };
    let (w, h) = (f0.width(), f0.height());
    debug_assert_eq!((labels.len(), textured.len()), (w * h, w * h));
    let regions = flat_regions(textured, labels, w, h);
    let moves: Vec<(u8, Vec<usize>)> = regions
        .par_iter()
        .filter(|r| depth_of(r.rim as usize) >= MIN_STEP as usize)
        .filter_map(|r| {
            let window = Window::around(r, w, h, textured);
            window.decide(frames, coverage, labels, r.rim, depth_of)
        })
        .collect();
    let mut settled = Settled {
        regions: moves.len(),
        pixels: 0,
    };
    for (k, pixels) in moves {
        for p in pixels {
            settled.pixels += usize::from(labels[p] != k);
            labels[p] = k;
            told[p] = true;
        }
    }
    settled
}

/// `told` (false where no frame has texture and no repair settled the label) with the flat
/// pixels whose label still says something of depth marked: all but those labelled `tie`, the
/// frame the labelling gives where every frame ties, [`MIN_STEP`] planes nearer than the label
/// most of the told pixels around their region hold. There the label is the tie's on a plain
/// patch of what lies around it: taken for a near object, its "halo" would be taken out of the
/// background around it. A plain near object whose rim holds a farther label keeps its labels
/// when they are another frame's, as where the labelling found its depth by the blur of its
/// edges.
pub fn tied_nearer(
    told: &[bool],
    labels: &[u8],
    tie: u8,
    w: usize,
    h: usize,
    depth_of: &(dyn Fn(usize) -> usize + Sync),
) -> Vec<bool> {
    let flat = Flat {
        textured: told,
        labels,
        w,
        h,
    };
    let mut out = told.to_vec();
    let mut seen = vec![0; w * h];
    let mut stack = Vec::new();
    for seed in 0..w * h {
        if told[seed] || seen[seed] != 0 {
            continue;
        }
        // Once to find the label around the region, once to mark its pixels.
        let rim = flat.walk(seed, &mut seen, 1, &mut stack, |_| {});
        let rim = rim.map(|r| depth_of(r as usize));
        flat.walk(seed, &mut seen, 2, &mut stack, |p| {
            let nearer = |r| depth_of(tie as usize) + (MIN_STEP as usize) <= r;
            out[p] = labels[p] != tie || !rim.is_some_and(nearer);
        });
    }
    out
}

/// A flat region worth deciding: one of its pixels, its bounding box and the label most of the
/// pixels around it hold.
struct Region {
    seed: usize,
    xs: Range<usize>,
    ys: Range<usize>,
    rim: u8,
}

/// The 4-connected regions of at least [`MIN_AREA`] pixels, within a box of at most a
/// [`LARGEST`]th of the frame, that `textured` leaves out.
fn flat_regions(textured: &[bool], labels: &[u8], w: usize, h: usize) -> Vec<Region> {
    let flat = Flat {
        textured,
        labels,
        w,
        h,
    };
    let mut seen = vec![0; w * h];
    let mut stack = Vec::new();
    let mut regions = Vec::new();
    for seed in 0..w * h {
        if textured[seed] || seen[seed] != 0 {
            continue;
        }
        let (mut area, mut xs, mut ys) = (0, seed % w..seed % w + 1, seed / w..seed / w + 1);
        let rim = flat.walk(seed, &mut seen, 1, &mut stack, |p| {
            area += 1;
            let (x, y) = (p % w, p / w);
            xs = xs.start.min(x)..xs.end.max(x + 1);
            ys = ys.start.min(y)..ys.end.max(y + 1);
        });
        // Nothing is textured around a region only when it is the whole frame.
        if let Some(rim) =
            rim.filter(|_| area >= MIN_AREA && xs.len() * ys.len() <= w * h / LARGEST)
        {
            regions.push(Region { seed, xs, ys, rim });
        }
    }
    regions
}

/// The pixels `textured` leaves out of a `w`×`h` label map, walked a region at a time.
struct Flat<'a> {
    textured: &'a [bool],
    labels: &'a [u8],
    w: usize,
    h: usize,
}

impl Flat<'_> {
    /// Runs `visit` on each pixel of the 4-connected flat region that holds `seed`, each once:
    /// those `seen` marks below `mark` (then marked with it), so a region is walked again with a
    /// higher mark. Returns the label most of the textured pixels around the region hold
    /// (counted once for each neighbour inside), if any.
    fn walk(
        &self,
        seed: usize,
        seen: &mut [u8],
        mark: u8,
        stack: &mut Vec<usize>,
        mut visit: impl FnMut(usize),
    ) -> Option<u8> {
        let mut around = [0u32; 256];
        seen[seed] = mark;
        stack.push(seed);
        while let Some(p) = stack.pop() {
            visit(p);
            for_neighbours(p, self.w, self.h, |q| {
                if self.textured[q] {
                    around[self.labels[q] as usize] += 1;
                } else if seen[q] < mark {
                    seen[q] = mark;
                    stack.push(q);
                }
            });
        }
        let rim = (0..256).max_by_key(|&l| around[l]).unwrap_or(0);
        (around[rim] > 0).then_some(rim as u8)
    }
}

/// Runs `f` on each 4-neighbour of pixel `p` of a `w`×`h` grid.
#[inline(always)]
fn for_neighbours(p: usize, w: usize, h: usize, mut f: impl FnMut(usize)) {
    let (x, y) = (p % w, p / w);
    if x > 0 {
        f(p - 1);
    }
    if x + 1 < w {
        f(p + 1);
    }
    if y > 0 {
        f(p - w);
    }
    if y + 1 < h {
        f(p + w);
    }
}

/// The 4-connected pixels of `flat` (a `w`×`h` grid) reached from `seed`, a run of a row at a
/// time: a region can be most of a frame, and a fill pixel by pixel took 25 ns a pixel.
fn fill(flat: &[bool], w: usize, h: usize, seed: usize) -> Vec<bool> {
    let mut inside = vec![false; w * h];
    let mut stack = vec![seed];
    while let Some(p) = stack.pop() {
        if inside[p] {
            continue;
        }
        let (y, row) = (p / w, p / w * w);
        let open = |x: usize, inside: &[bool]| flat[row + x] && !inside[row + x];
        let (mut l, mut r) = (p % w, p % w);
        while l > 0 && open(l - 1, &inside) {
            l -= 1;
        }
        while r + 1 < w && open(r + 1, &inside) {
            r += 1;
        }
        inside[row + l..=row + r].fill(true);
        for next in [y.checked_sub(1), (y + 1 < h).then_some(y + 1)]
            .into_iter()
            .flatten()
        {
            let start = next * w;
            let mut x = l;
            while x <= r {
                if flat[start + x] && !inside[start + x] {
                    stack.push(start + x);
                    while x <= r && flat[start + x] && !inside[start + x] {
                        x += 1;
                    }
                } else {
                    x += 1;
                }
            }
        }
    }
    inside
}

/// A region's neighbourhood: its bounding box grown by how far it may be grown and the pooling,
/// with the region's pixels and each pixel's distance from them.
struct Window {
    xs: Range<usize>,
    ys: Range<usize>,
    /// Window pixels of the region.
    inside: Vec<bool>,
    /// The region's pixels with a neighbour outside it: where growing starts.
    border: Vec<usize>,
    /// City-block distance from the region, at most [`FAR`]: the pixels a frame's flags are
    /// read at are those within `REACH + 1` and the pooling's reach beyond them.
    dist: Vec<u8>,
}

impl Window {
    fn around(r: &Region, w: usize, h: usize, textured: &[bool]) -> Self {
        let m = REACH + POOL + 1;
        let xs = r.xs.start.saturating_sub(m)..(r.xs.end + m).min(w);
        let ys = r.ys.start.saturating_sub(m)..(r.ys.end + m).min(h);
        let (ww, wh) = (xs.len(), ys.len());
        let mut flat = Vec::with_capacity(ww * wh);
        for y in ys.clone() {
            flat.extend(textured[y * w + xs.start..][..ww].iter().map(|&t| !t));
        }
        // The region lies inside its bounding box, so a fill from its seed within the window
        // finds exactly it.
        let seed = (r.seed / w - ys.start) * ww + r.seed % w - xs.start;
        let inside = fill(&flat, ww, wh, seed);
        // Its pixels with a neighbour outside it, a row at a time.
        let (mut border, mut edge) = (Vec::new(), vec![false; ww]);
        for y in 0..wh {
            let row = &inside[y * ww..][..ww];
            let up = &inside[y.saturating_sub(1) * ww..][..ww];
            let down = &inside[(y + 1).min(wh - 1) * ww..][..ww];
            for (((e, &i), &u), &d) in edge.iter_mut().zip(row).zip(up).zip(down) {
                *e = i && !(u && d);
            }
            for x in 1..ww.saturating_sub(1) {
                edge[x] |= row[x] && !(row[x - 1] && row[x + 1]);
            }
            // The window's first and last columns: a region there reaches the image's edge.
            if ww > 1 {
                edge[0] |= row[0] && !row[1];
                edge[ww - 1] |= row[ww - 1] && !row[ww - 2];
            }
            border.extend((0..ww).filter(|&x| edge[x]).map(|x| y * ww + x));
        }
        let dist = distance(&inside, ww, wh, FAR);
        Window {
            xs,
            ys,
            inside,
            border,
            dist,
        }
    }

    fn width(&self) -> usize {
        self.xs.len()
    }

    /// The image index of window pixel `i`, in an image `w` wide.
    fn global(&self, i: usize, w: usize) -> usize {
        let ww = self.width();
        (self.ys.start + i / ww) * w + self.xs.start + i % ww
    }

    /// The nearer frame that claims the region, and the pixels it then labels; `None` when no
    /// frame claims it clearly, the claim is not nearer than `rim`, or the crisp outline is not
    /// the region's own.
    fn decide<T: Sample>(
        &self,
        frames: &[Image<T>],
        coverage: &[Coverage],
        labels: &[u8],
        rim: u8,
        depth_of: &(dyn Fn(usize) -> usize + Sync),
    ) -> Option<(u8, Vec<usize>)> {
        // Only a frame at least MIN_STEP planes nearer than the rim can claim the region; the
        // others are measured only when one of those is a candidate at all.
        let can_claim = |k: usize| depth_of(k) + MIN_STEP as usize <= depth_of(rim as usize);
        let share = |k: usize| {
            self.grow(&self.flags(&frames[k], &coverage[k]))
                .crisp_share()
        };
        let shares = |claim: bool| -> Vec<(usize, f64)> {
            (0..frames.len())
                .into_par_iter()
                .filter(|&k| can_claim(k) == claim)
                .map(|k| (k, share(k)))
                .collect()
        };
        let claimants = shares(true);
        let (k, best) = claimants
            .iter()
            .copied()
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))?;
        if best < MIN_SHARE {
            return None;
        }
        let second = claimants
            .into_iter()
            .chain(shares(false))
            .filter(|&(l, _)| l != k)
            .map(|(_, s)| s)
            .fold(0.0, f64::max);
        if best - second < MARGIN {
            return None;
        }
        let flags = self.flags(&frames[k], &coverage[k]);
        let grown = self.grow(&flags);
        let inside: Vec<bool> = grown.state.iter().map(|&s| s == Grown::IN).collect();
        let (ww, wh, w) = (self.width(), self.ys.len(), frames[k].width());
        // What lies beyond its crisp outline, past the edge itself: a region's own edge has
        // something farther behind it; an occluder's edge, the occluder.
        let crisp: Vec<bool> = (0..ww * wh)
            .map(|i| grown.state[i] == Grown::RING && self.near_crisp(&flags, i))
            .collect();
        let past = dilate(&inside, ww, wh, BEYOND.start);
        let beyond = dilate(&crisp, ww, wh, BEYOND.end - BEYOND.start);
        let (mut farther, mut seen) = (0usize, 0usize);
        for i in (0..ww * wh).filter(|&i| beyond[i] && !past[i]) {
            seen += 1;
            farther += usize::from(depth_of(labels[self.global(i, w)] as usize) > depth_of(k));
        }
        if (farther as f64) < OWN_EDGE * seen.max(1) as f64 {
            return None;
        }
        let edge = dilate(&inside, ww, wh, POOL);
        // How far inside the grown region, up to just past REACH: the halo the relabelling lets
        // the spill removal take out lies beyond the outline, and the region's own pixels there
        // are composed from its frame; deeper in, every frame shows the plain region alike, so
        // only a label MIN_STEP planes behind the claiming frame moves there (the depth map
        // would show a hole in the object), and one close to it stays (moved, the output there
        // would change by the frames' noise, far from any step).
        let outside: Vec<bool> = inside.iter().map(|&i| !i).collect();
        let depth = distance(&outside, ww, wh, REACH as u8 + 1);
        let pixels = (0..ww * wh)
            .filter_map(|i| {
                let p = self.global(i, w);
                // The region grown within REACH of its outline, and the crisp edge that bounds
                // it where a farther frame holds it: the grown region stops at the edge's foot.
                let behind = depth_of(labels[p] as usize) >= depth_of(k) + MIN_STEP as usize;
                let take = if inside[i] {
                    (depth[i] as usize <= REACH || behind) && coverage[k].covers(p % w, p / w)
                } else {
                    edge[i]
                        && depth_of(labels[p] as usize) > depth_of(k)
                        && self.near_crisp(&flags, i)
                };
                take.then_some(p)
            })
            .collect();
        Some((k as u8, pixels))
    }

    /// Frame `f`'s flags on the window near the region, outside it (elsewhere they are never read):
    /// [`SHOWN_FLAT`] or [`STEEP`] (a crisp step; [`Self::near_crisp`] pools them). A pixel the
    /// frame does not cover is neither.
    fn flags<T: Sample>(&self, f: &Image<T>, cov: &Coverage) -> Vec<u8> {
        let (w, h, ch) = (f.width(), f.height(), f.channels());
        let ww = self.width();
        let mut flags = vec![0u8; ww * self.ys.len()];
        let (mut vert, mut here, mut below, mut steps) = (vec![], vec![], vec![], vec![]);
        for (y, row) in self.ys.clone().zip(flags.chunks_exact_mut(ww)) {
            let wy = y - self.ys.start;
            let (lo, hi) = cov.spans[y];
            let (lo, hi) = (lo as usize, (hi as usize).max(lo as usize));
            let dist = &self.dist[wy * ww..][..ww];
            let mut x0 = 0;
            while x0 < ww {
                // A run of pixels near the region, outside it, the frame covering them.
                let read = |x: usize| (1..FAR).contains(&dist[x]);
                if !read(x0) || !(lo..hi).contains(&(self.xs.start + x0)) {
                    x0 += 1;
                    continue;
                }
                let x1 = (x0..ww)
                    .find(|&x| !read(x) || self.xs.start + x >= hi)
                    .unwrap_or(ww);
                let cols = self.xs.start + x0..self.xs.start + x1;
                // One column more for the step right, where the image has it.
                let wide = cols.start..(cols.end + 1).min(w);
                smooth_row(f, y, wide.clone(), &mut vert, &mut here);
                let n = cols.len() * ch;
                steps.clear();
                steps.resize(n, 0.0f32);
                // Steps right: each sample against the next pixel's; at the image's last
                // column `here` has no next pixel and the step stays 0.
                for (s, (a, b)) in steps.iter_mut().zip(here.iter().zip(&here[ch..])) {
                    *s = (b - a).abs();
                }
                if y + 1 < h {
                    smooth_row(f, y + 1, wide, &mut vert, &mut below);
                    for (s, (a, b)) in steps.iter_mut().zip(here.iter().zip(&below)) {
                        *s = s.max((b - a).abs());
                    }
                }
                for (out, px) in row[x0..x1].iter_mut().zip(steps.chunks_exact(ch)) {
                    let step = px.iter().fold(0f32, |m, &s| m.max(s)) / T::MAX;
                    *out = if step < FLAT {
                        SHOWN_FLAT
                    } else if step >= CRISP {
                        STEEP
                    } else {
                        0
                    };
                }
                x0 = x1;
            }
        }
        flags
    }

    /// Whether window pixel `i` has a crisp step within [`POOL`] in `flags`.
    fn near_crisp(&self, flags: &[u8], i: usize) -> bool {
        let (ww, wh) = (self.width(), self.ys.len());
        let (x, y) = (i % ww, i / ww);
        let xs = x.saturating_sub(POOL)..(x + POOL + 1).min(ww);
        (y.saturating_sub(POOL)..(y + POOL + 1).min(wh)).any(|yy| {
            flags[yy * ww + xs.start..yy * ww + xs.end]
                .iter()
                .any(|&f| f & STEEP != 0)
        })
    }

    /// Grows the region through the pixels `flags` shows flat, within [`REACH`].
    fn grow(&self, flags: &[u8]) -> Grown {
        let (ww, wh) = (self.width(), self.ys.len());
        let mut state: Vec<u8> = self.inside.iter().map(|&i| u8::from(i)).collect();
        let mut stack = self.border.clone();
        let (mut ring, mut crisp) = (0usize, 0usize);
        while let Some(i) = stack.pop() {
            for_neighbours(i, ww, wh, |j| {
                if state[j] != Grown::OUT {
                    return;
                }
                if self.dist[j] as usize <= REACH && flags[j] & SHOWN_FLAT != 0 {
                    state[j] = Grown::IN;
                    stack.push(j);
                } else {
                    state[j] = Grown::RING;
                    ring += 1;
                    crisp += usize::from(self.near_crisp(flags, j));
                }
            });
        }
        Grown { state, ring, crisp }
    }
}

/// A region grown in one frame.
struct Grown {
    /// Per window pixel: `OUT`, `IN` (the region or grown into) or `RING` (its outline).
    state: Vec<u8>,
    ring: usize,
    /// Outline pixels near a crisp step.
    crisp: usize,
}

impl Grown {
    const OUT: u8 = 0;
    const IN: u8 = 1;
    const RING: u8 = 2;

    fn crisp_share(&self) -> f64 {
        self.crisp as f64 / self.ring.max(1) as f64
    }
}

/// Row `y` of frame `f` smoothed by the 3×3 binomial filter on columns `xs`, channels
/// interleaved, the image's edges replicated: smoothing first keeps sensor noise and JPEG
/// ringing on plain surfaces under [`FLAT`]. `vert` is scratch for the vertical sums, one
/// column either side.
fn smooth_row<T: Sample>(
    f: &Image<T>,
    y: usize,
    xs: Range<usize>,
    vert: &mut Vec<f32>,
    out: &mut Vec<f32>,
) {
    let (w, h, ch) = (f.width(), f.height(), f.channels());
    let row = |yy: usize| &f.data()[yy * w * ch..][..w * ch];
    let (a, b, c) = (row(y.saturating_sub(1)), row(y), row((y + 1).min(h - 1)));
    // Vertical sums of the columns, one either side (replicated at the image's edges).
    let (lo, hi) = (xs.start.saturating_sub(1), (xs.end + 1).min(w));
    let span = lo * ch..hi * ch;
    vert.clear();
    if xs.start == 0 {
        vert.resize(ch, 0.0);
    }
    vert.extend(
        a[span.clone()]
            .iter()
            .zip(&b[span.clone()])
            .zip(&c[span])
            .map(|((a, b), c)| a.to_f32() + 2.0 * b.to_f32() + c.to_f32()),
    );
    if xs.start == 0 {
        vert.copy_within(ch..2 * ch, 0);
    }
    if xs.end == w {
        let last = vert.len() - ch;
        vert.extend_from_within(last..);
    }
    out.clear();
    let n = xs.len() * ch;
    out.extend(
        vert[..n]
            .iter()
            .zip(&vert[ch..n + ch])
            .zip(&vert[2 * ch..n + 2 * ch])
            .map(|((l, m), r)| (l + 2.0 * m + r) / 16.0),
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::blur::gaussian_blur;
    use crate::stack::image::Plane;

    const SIZE: usize = 96;
    const RADIUS: f32 = 24.0;
    /// The region no frame has texture in: the disc's core, as far inside its edge as the
    /// background frame shows the stripes through it.
    const CORE: f32 = 16.0;

    fn radius(x: usize, y: usize) -> f32 {
        let c = SIZE as f32 / 2.0;
        (x as f32 - c).hypot(y as f32 - c)
    }

    /// A near layer (`near` its mask, `colour` its values) before a far one, through the
    /// layered thin-lens model: the near layer blurred by σ `near_blur`, the far by `far_blur`.
    fn render(
        near: impl Fn(usize, usize) -> bool,
        colour: impl Fn(usize, usize) -> f32,
        far: impl Fn(usize, usize) -> f32,
        near_blur: f32,
        far_blur: f32,
    ) -> Image<u8> {
        let alpha = Plane::from_fn(SIZE, SIZE, 1, |x, y, _| f32::from(near(x, y)));
        let back = Plane::from_fn(SIZE, SIZE, 1, |x, y, _| far(x, y));
        let premul = Plane::from_fn(SIZE, SIZE, 1, |x, y, _| colour(x, y) * alpha.at(x, y, 0));
        let (a, c, b) = (
            gaussian_blur(&alpha, near_blur),
            gaussian_blur(&premul, near_blur),
            gaussian_blur(&back, far_blur),
        );
        Image::from_fn(SIZE, SIZE, 1, |x, y, _| {
            let v = c.at(x, y, 0) + (1.0 - a.at(x, y, 0)) * b.at(x, y, 0);
            u8::from_f32(v * 255.0)
        })
    }

    /// A plain disc of 0.75 before vertical stripes of 0.2 and 0.5 (4 px period), the disc
    /// blurred by σ `disc`, the background by σ `back`.
    fn frame(disc: f32, back: f32) -> Image<u8> {
        render(
            |x, y| radius(x, y) <= RADIUS,
            |_, _| 0.75,
            |x, _| [0.2, 0.5][x / 2 % 2],
            disc,
            back,
        )
    }

    /// Nearest first: focused before the disc, on it, between it and the background, on the
    /// background.
    fn stack() -> Vec<Image<u8>> {
        vec![
            frame(3.0, 6.0),
            frame(0.0, 4.0),
            frame(3.0, 1.5),
            frame(4.0, 0.0),
        ]
    }

    fn textured() -> Vec<bool> {
        (0..SIZE * SIZE)
            .map(|i| radius(i % SIZE, i / SIZE) > CORE)
            .collect()
    }

    fn settle_labels(frames: &[Image<u8>], labels: &mut [u8]) -> Settled {
        let cover = vec![Coverage::full(SIZE, SIZE); frames.len()];
        settle(frames, &cover, labels, &mut textured(), &|f| f)
    }

    /// A compact flat patch is a region to decide; a thin one of the same area sprawling
    /// across the frame is not (its box is the whole frame).
    #[test]
    fn a_region_is_decided_only_within_a_box_of_a_quarter_of_the_frame() {
        let (w, h) = (100, 100);
        let labels = vec![0u8; w * h];
        let square: Vec<bool> = (0..w * h)
            .map(|i| !((10..30).contains(&(i % w)) && (10..30).contains(&(i / w))))
            .collect();
        let cross: Vec<bool> = (0..w * h).map(|i| i % w != 50 && i / w != 50).collect();
        assert_eq!(flat_regions(&square, &labels, w, h).len(), 1);
        assert!(flat_regions(&cross, &labels, w, h).is_empty());
    }

    #[test]
    fn a_plain_near_object_labelled_with_the_background_takes_its_own_frame() {
        let frames = stack();
        let mut labels = vec![3u8; SIZE * SIZE];
        let settled = settle_labels(&frames, &mut labels);
        assert_eq!(settled.regions, 1);
        let at = |r: Range<f32>| {
            (0..SIZE * SIZE)
                .filter(|&i| r.contains(&radius(i % SIZE, i / SIZE)))
                .map(|i| labels[i])
                .collect::<Vec<u8>>()
        };
        // The whole disc, its rim included, up to its edge; the background stays.
        assert!(at(0.0..RADIUS - 1.0).iter().all(|&l| l == 1));
        assert!(at(RADIUS + 3.0..RADIUS + 6.0).iter().all(|&l| l == 3));
        assert_eq!(
            settled.pixels,
            at(0.0..f32::MAX).iter().filter(|&&l| l == 1).count()
        );
    }

    #[test]
    fn a_label_close_to_the_claim_stays_deep_inside_the_region() {
        let frames = stack();
        // The disc's core labelled one plane behind its own frame, the rest the background's.
        let core = |i: usize| radius(i % SIZE, i / SIZE) < 2.0;
        let mut labels: Vec<u8> = (0..SIZE * SIZE)
            .map(|i| if core(i) { 2 } else { 3 })
            .collect();
        assert_eq!(settle_labels(&frames, &mut labels).regions, 1);
        // Farther than REACH inside the grown outline (the edge's foot, within POOL of RADIUS)
        // the core keeps its label; within it the disc takes its frame.
        assert!((0..SIZE * SIZE)
            .filter(|&i| core(i))
            .all(|i| labels[i] == 2));
        let ring =
            (0..SIZE * SIZE).filter(|&i| (6.0..RADIUS - 1.0).contains(&radius(i % SIZE, i / SIZE)));
        assert!(ring.clone().count() > 0 && ring.into_iter().all(|i| labels[i] == 1));
    }

    #[test]
    fn a_claim_not_two_planes_nearer_than_the_frame_around_the_region_moves_nothing() {
        let frames = stack();
        // Around the disc its own frame's neighbour: the disc's frame is one plane nearer.
        let mut labels = vec![2u8; SIZE * SIZE];
        assert_eq!(settle_labels(&frames, &mut labels), Settled::default());
        assert!(labels.iter().all(|&l| l == 2));
    }

    #[test]
    fn two_frames_that_show_the_outline_alike_move_nothing() {
        // The disc's frame twice: neither leads the other by the margin.
        let mut frames = stack();
        frames.insert(1, frames[1].clone());
        let mut labels = vec![4u8; SIZE * SIZE];
        assert_eq!(settle_labels(&frames, &mut labels), Settled::default());
        assert!(labels.iter().all(|&l| l == 4));
    }

    #[test]
    fn a_plain_background_seen_through_a_near_object_keeps_its_frame() {
        // A textured near ring, open on the right, before a plain background: the hole is flat
        // and its outline, the ring's inner edge, is crisp in the ring's frame, but the edge is
        // the ring's, with the ring, not something farther, beyond it.
        let c = SIZE as f32 / 2.0;
        let ring = |x: usize, y: usize| {
            let gap = x as f32 > c + 8.0 && (y as f32 - c).abs() < 6.0;
            (16.0..30.0).contains(&radius(x, y)) && !gap
        };
        let checker = |x: usize, y: usize| [0.3, 0.8][(x / 2 + y / 2) % 2];
        let plain = |_, _| 0.35;
        let frames: Vec<Image<u8>> = [(3.0, 6.0), (0.0, 4.0), (3.0, 1.5), (4.0, 0.0)]
            .into_iter()
            .map(|(near, far)| render(ring, checker, plain, near, far))
            .collect();
        let mut labels: Vec<u8> = (0..SIZE * SIZE)
            .map(|i| if ring(i % SIZE, i / SIZE) { 1 } else { 3 })
            .collect();
        let before = labels.clone();
        let cover = vec![Coverage::full(SIZE, SIZE); frames.len()];
        let mut textured: Vec<bool> = (0..SIZE * SIZE)
            .map(|i| radius(i % SIZE, i / SIZE) > 10.0)
            .collect();
        let settled = settle(&frames, &cover, &mut labels, &mut textured, &|f| f);
        assert_eq!(settled, Settled::default());
        assert_eq!(labels, before);
    }

    /// A flat patch of a far background labelled with the tie's frame [`MIN_STEP`] planes
    /// nearer than the texture around it is told nothing of depth; one labelled a plane nearer
    /// keeps its label's word, and so do one labelled with another frame and a plain near
    /// object whose textured rim is labelled with it.
    #[test]
    fn only_a_flat_patch_tied_well_nearer_than_its_rim_is_untold() {
        let square = |xs: Range<usize>, ys: Range<usize>| {
            move |i: usize| xs.contains(&(i % SIZE)) && ys.contains(&(i / SIZE))
        };
        let (tied, close, other) = (
            square(8..24, 8..24),
            square(40..56, 8..24),
            square(8..24, 40..56),
        );
        let (object, rim) = (square(62..78, 62..78), square(60..80, 60..80));
        let labels: Vec<u8> = (0..SIZE * SIZE)
            .map(|i| match i {
                _ if tied(i) || rim(i) => 1,
                _ if close(i) => 3,
                _ if other(i) => 0,
                _ => 4,
            })
            .collect();
        let told: Vec<bool> = (0..SIZE * SIZE)
            .map(|i| !(tied(i) || close(i) || other(i) || object(i)))
            .collect();
        let out = tied_nearer(&told, &labels, 1, SIZE, SIZE, &|f| f);
        for (i, &told) in out.iter().enumerate() {
            assert_eq!(told, !tied(i), "pixel {i}");
        }
    }
}
