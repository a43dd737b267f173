//! Which way a stack was focused, nearest first or farthest first, read from its occlusion
//! edges: what a spill-free composition needs to know which of two frames is nearer.
//!
//! The cue: where a near object occludes a far one, the frame focused on the near object shows
//! their shared edge crisp (the occluder is sharp; only the background behind it is blurred),
//! while the frame focused on the far one shows it blurred (the defocused occluder spills over
//! the sharp background). The label map marks such edges: a near region labelled with one frame
//! beside a far region labelled with another. So along every boundary between labels `a` and
//! `b` at least [`MIN_STEP`] frames apart, the crisper of frames `a` and `b` is the nearer one.
//! Labels one frame apart are left out: a slanted surface changes label that way without any
//! occlusion, and so are boundaries where one frame is the sharper on both sides (a mislabelled
//! patch, no depth step). Each boundary pixel votes with the difference of the two frames'
//! steepest steps across it, so long and contrasty edges weigh most; the order needs
//! [`MIN_VOTES`] votes and a [`MAJORITY`] of their contrast, else it is `Unknown`.
//!
//! Focus breathing cannot decide it: real lenses shrink the image towards far focus, the
//! simulator grows it, and a focus-by-rail stack does not breathe at all.

use super::align::Coverage;
use super::image::{Image, Sample};
use rayon::prelude::*;

/// Labels closer than this many frames do not vote (see the module's doc).
pub const MIN_STEP: u8 = 2;

/// Pixels either side of a label boundary searched for the edge: the labelling places its
/// boundary near, not on, the occlusion edge (a crisp edge's focus measure reaches past it; 3 px
/// on the simulator's 1200 px stacks), so each frame's edge strength is its steepest step within
/// this reach. Measured on three simulated stacks (before the rule of [`MIN_OWN`]): at 4 px
/// edges fall out of reach and 79–87 % of the votes' contrast goes to the true order, at 6 px
/// 82–89 %, at 8 px no more.
pub const REACH: usize = 6;

/// A boundary pixel votes only when frames `a` and `b` differ by at least this much in their
/// steepest step (0..=1 of full scale; about 5 of 255): smaller differences are noise and
/// compression. Steps are taken per colour channel, not on luma: objects of different hue often
/// have nearly the same luma (on luma, 75–81 % of the simulated stacks' votes went to the true
/// order, against 81–89 % per channel).
pub const MIN_CONTRAST: f32 = 0.02;

/// How much steeper than the other each frame must be on its own label's side of a boundary
/// (full scale 1; about 1.3 of 255, above 8-bit quantisation) for the boundary to vote: see
/// `Edges::vote`. Measured through the fuse on simulated stacks (640×480 display-value,
/// 640×480 hand-held with 3 px parallax and 1200×900 linear-light) it raises the votes' share
/// for the true order from 88–90 % to 92–96 %, keeping 62–68 % of them.
pub const MIN_OWN: f32 = 0.005;

/// Fewer voting boundary pixels than this decide nothing: about the outline of one object of
/// 30 px radius, below which a few textured pixels could outvote the edges.
pub const MIN_VOTES: usize = 200;

/// The contrast-weighted share of the votes the winning order needs: twice the other's.
pub const MAJORITY: f64 = 2.0 / 3.0;

/// The order of a stack's frames along the focus axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// Frame 0 is focused nearest (the documented input order).
    NearestFirst,
    /// Frame 0 is focused farthest.
    FarthestFirst,
    /// Too little or too split evidence to tell.
    Unknown,
}

impl Order {
    /// The order to act on: `Unknown` is taken as the documented nearest first.
    pub fn assumed(self) -> Order {
        match self {
            Order::Unknown => Order::NearestFirst,
            o => o,
        }
    }

    /// The frame at depth rank `depth` (0 nearest) of a stack of `n`, by the assumed order.
    pub fn frame_at(self, depth: usize, n: usize) -> usize {
        match self.assumed() {
            Order::FarthestFirst => n - 1 - depth,
            _ => depth,
        }
    }

    /// The depth rank (0 nearest) of frame `frame` of a stack of `n`, by the assumed order: the
    /// inverse of [`Order::frame_at`], which is its own inverse.
    pub fn depth_of(self, frame: usize, n: usize) -> usize {
        self.frame_at(frame, n)
    }
}

/// The votes of a stack's occlusion edges and the order they decide.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrderEvidence {
    pub order: Order,
    /// Boundary pixels that voted.
    pub votes: usize,
    /// Summed contrast (differences of steepest steps, full scale 1) of the votes that found the lower-numbered frame crisper,
    /// that is nearer: for nearest first.
    pub nearest_first: f64,
    /// Likewise for the higher-numbered frame: for farthest first.
    pub farthest_first: f64,
}

impl OrderEvidence {
    /// The contrast-weighted share of the votes for nearest first; ½ without votes.
    pub fn nearest_share(&self) -> f64 {
        let total = self.nearest_first + self.farthest_first;
        if total > 0.0 {
            self.nearest_first / total
        } else {
            0.5
        }
    }

    /// The fixed rule: at least [`MIN_VOTES`] votes, and a [`MAJORITY`] of their contrast.
    fn decide(votes: usize, nearest_first: f64, farthest_first: f64) -> Self {
        let mut e = OrderEvidence {
            order: Order::Unknown,
            votes,
            nearest_first,
            farthest_first,
        };
        let share = e.nearest_share();
        if votes >= MIN_VOTES {
            if share >= MAJORITY {
                e.order = Order::NearestFirst;
            } else if 1.0 - share >= MAJORITY {
                e.order = Order::FarthestFirst;
            }
        }
        e
    }
}

impl std::fmt::Display for OrderEvidence {
    /// One line for the logs: the order found and on what, or the order assumed.
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        let on = format!(
            "{} edge pixels, {:.0} % of their contrast for nearest first",
            self.votes,
            100.0 * self.nearest_share()
        );
        match self.order {
            Order::NearestFirst => write!(f, "nearest focus first ({on})"),
            Order::FarthestFirst => write!(f, "farthest focus first ({on})"),
            Order::Unknown => write!(
                f,
                "not told by the occlusion edges ({on}; needs {MIN_VOTES} and {:.0} %): \
                 nearest focus first assumed",
                100.0 * MAJORITY
            ),
        }
    }
}

/// Reads the focus order from the occlusion edges of `labels` (one per pixel, a frame index)
/// on the aligned `frames`, where each covers (`coverage`, one per frame). Looks only at
/// boundary pixels, so it costs little beside the labelling. Inputs that do not fit together
/// (other sizes, labels naming no frame) give no votes rather than a panic.
pub fn focus_order<T: Sample>(
    frames: &[Image<T>],
    labels: &[u8],
    coverage: &[Coverage],
) -> OrderEvidence {
    let Some(f0) = frames.first() else {
        return OrderEvidence::decide(0, 0.0, 0.0);
    };
    let (w, h) = (f0.width(), f0.height());
    let fits = labels.len() == w * h
        && coverage.len() == frames.len()
        && coverage.iter().all(|c| c.spans.len() == h)
        && frames.iter().all(|f| f.width() == w && f.height() == h);
    if !fits {
        return OrderEvidence::decide(0, 0.0, 0.0);
    }
    let edges = Edges {
        frames,
        labels,
        coverage,
        w,
        h,
    };
    let (votes, near, far) = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut t = (0usize, 0.0f64, 0.0f64);
            for x in 0..w {
                for step in [(1, 0), (0, 1)] {
                    if let Some(v) = edges.vote(x, y, step) {
                        t.0 += 1;
                        if v > 0.0 {
                            t.1 += v as f64;
                        } else {
                            t.2 -= v as f64;
                        }
                    }
                }
            }
            t
        })
        .reduce(|| (0, 0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    OrderEvidence::decide(votes, near, far)
}

struct Edges<'a, T> {
    frames: &'a [Image<T>],
    labels: &'a [u8],
    coverage: &'a [Coverage],
    w: usize,
    h: usize,
}

impl<T: Sample> Edges<'_, T> {
    /// The vote of the boundary between pixel (x, y) and its neighbour one `step` on, if their
    /// labels are a step apart: positive when the lower-numbered frame shows the edge crisper,
    /// by how much.
    fn vote(&self, x: usize, y: usize, step: (usize, usize)) -> Option<f32> {
        let (a, b) = (self.labels[y * self.w + x], {
            let (u, v) = (x + step.0, y + step.1);
            if u >= self.w || v >= self.h {
                return None;
            }
            self.labels[v * self.w + u]
        });
        if a.abs_diff(b) < MIN_STEP || a.max(b) as usize >= self.frames.len() {
            return None;
        }
        // The samples across the boundary: REACH before (x, y), REACH after its neighbour.
        let (x0, y0) = (
            x.checked_sub(REACH * step.0)?,
            y.checked_sub(REACH * step.1)?,
        );
        let n = 2 * REACH + 2;
        let at = |i: usize| (x0 + i * step.0, y0 + i * step.1);
        let (xe, ye) = at(n - 1);
        if xe >= self.w || ye >= self.h {
            return None;
        }
        let (lo, hi) = (a.min(b) as usize, a.max(b) as usize);
        let covered = |k: usize| (0..n).all(|i| self.coverage[k].covers(at(i).0, at(i).1));
        if !covered(lo) || !covered(hi) {
            return None;
        }
        // Frame k's steepest step between samples i − 1 and i, over `steps` i.
        let steepest = |k: usize, steps: std::ops::Range<usize>| {
            let f = &self.frames[k];
            let v = |i: usize, c: usize| f.at(at(i).0, at(i).1, c).to_f32();
            let most = steps
                .flat_map(|i| (0..f.channels()).map(move |c| (v(i, c) - v(i - 1, c)).abs()))
                .fold(0.0f32, f32::max);
            most / T::MAX
        };
        // Each frame must be the steeper, by MIN_OWN, on its own label's side: a depth step,
        // each side sharp in its frame. Where a frame was picked for a patch that it does not
        // show sharper (a tie on a smooth patch next to texture), the other frame is as steep or
        // steeper on both sides, and it would vote for whichever frame is focused at that
        // patch's depth, not for the nearer one. The sides are their outer halves, so that the
        // crisp edge itself, a few pixels off the label boundary, counts for neither.
        let (before, after) = (1..REACH / 2 + 1, REACH + REACH / 2 + 2..n);
        let (a, b) = (a as usize, b as usize);
        if steepest(a, before.clone()) < steepest(b, before) + MIN_OWN
            || steepest(b, after.clone()) < steepest(a, after) + MIN_OWN
        {
            return None;
        }
        let d = steepest(lo, 1..n) - steepest(hi, 1..n);
        (d.abs() >= MIN_CONTRAST).then_some(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stack::blur::gaussian_blur;
    use crate::stack::image::Plane;

    const SIZE: usize = 100;
    const RADIUS: f32 = 34.0;

    /// 1 inside the near disc, 0 outside (a hard, pixel-sampled mask).
    fn disc() -> Plane {
        let c = SIZE as f32 / 2.0;
        Plane::from_fn(SIZE, SIZE, 1, |x, y, _| {
            ((x as f32 - c).hypot(y as f32 - c) <= RADIUS) as u8 as f32
        })
    }

    /// A disc of fine texture of amplitude `texture` around 0.75 over a far texture of
    /// amplitude 0.25 around 0.35, through the layered thin-lens model: the near layer blurred by
    /// `near` σ over the far one blurred by `far`.
    fn render(near: f32, far: f32, texture: f32) -> Plane {
        let alpha = disc();
        let colour = Plane::from_fn(SIZE, SIZE, 1, |x, y, _| {
            0.75 + texture * (((x / 2 + y / 3) % 2) as f32 - 0.5)
        });
        let back = Plane::from_fn(SIZE, SIZE, 1, |x, y, _| {
            0.35 + 0.25 * (((x / 2 + y / 2) % 2) as f32 - 0.5)
        });
        let premul = Plane::from_fn(SIZE, SIZE, 1, |x, y, _| {
            alpha.at(x, y, 0) * colour.at(x, y, 0)
        });
        let (c, a, b) = (
            gaussian_blur(&premul, near),
            gaussian_blur(&alpha, near),
            gaussian_blur(&back, far),
        );
        Plane::from_fn(SIZE, SIZE, 1, |x, y, _| {
            c.at(x, y, 0) + (1.0 - a.at(x, y, 0)) * b.at(x, y, 0)
        })
    }

    /// Three frames nearest first: on the disc, between, on the background.
    fn nearest_first(texture: f32) -> Vec<Plane> {
        vec![
            render(0.0, 4.0, texture),
            render(2.0, 2.0, texture),
            render(4.0, 0.0, texture),
        ]
    }

    /// `inside` on the disc grown by `grow` px, `outside` elsewhere: where a labelling that
    /// let the crisp edge's frame reach past the edge would put the boundary.
    fn labels(inside: u8, outside: u8, grow: f32) -> Vec<u8> {
        let c = SIZE as f32 / 2.0;
        (0..SIZE * SIZE)
            .map(|i| {
                let (x, y) = ((i % SIZE) as f32, (i / SIZE) as f32);
                if (x - c).hypot(y - c) <= RADIUS + grow {
                    inside
                } else {
                    outside
                }
            })
            .collect()
    }

    fn full(n: usize) -> Vec<Coverage> {
        vec![Coverage::full(SIZE, SIZE); n]
    }

    #[test]
    fn the_crisp_edge_names_the_near_frame_either_way_round() {
        let frames = nearest_first(0.25);
        let reversed: Vec<Plane> = frames.iter().rev().cloned().collect();
        for grow in [0.0, 2.0, -2.0] {
            let e = focus_order(&frames, &labels(0, 2, grow), &full(3));
            assert_eq!(e.order, Order::NearestFirst, "grown {grow}: {e:?}");
            let r = focus_order(&reversed, &labels(2, 0, grow), &full(3));
            assert_eq!(r.order, Order::FarthestFirst, "grown {grow}: {r:?}");
            assert_eq!(r.votes, e.votes);
            assert_eq!(Order::FarthestFirst.frame_at(0, 3), 2);
        }
    }

    /// A smooth near object lets the sharp background show through its defocused edge, steeper
    /// than its own texture on its own side: those boundaries do not vote (the price of
    /// `MIN_OWN`), and the ones left still vote the right way.
    #[test]
    fn a_smooth_near_object_votes_less_but_not_wrong() {
        let (smooth, textured) = (nearest_first(0.1), nearest_first(0.25));
        let (mut fewer, mut all) = (0, 0);
        for grow in [0.0, 2.0, -2.0] {
            let e = focus_order(&smooth, &labels(0, 2, grow), &full(3));
            let t = focus_order(&textured, &labels(0, 2, grow), &full(3));
            assert!(e.nearest_share() > 0.9, "grown {grow}: {e:?}");
            (fewer, all) = (fewer + e.votes, all + t.votes);
        }
        assert!(fewer < all, "{fewer} votes against {all}");
    }

    #[test]
    fn neighbouring_labels_and_uncovered_edges_do_not_vote() {
        let frames = nearest_first(0.25);
        // Labels one frame apart: a slanted surface's, no occlusion.
        let e = focus_order(&frames, &labels(0, 1, 0.0), &full(3));
        assert_eq!((e.order, e.votes), (Order::Unknown, 0));
        // Frame 2 covers nothing: its edges are not its own.
        let mut cover = full(3);
        cover[2].spans.fill((0, 0));
        let e = focus_order(&frames, &labels(0, 2, 0.0), &cover);
        assert_eq!((e.order, e.votes), (Order::Unknown, 0));
    }

    #[test]
    fn too_little_or_split_evidence_is_unknown_and_assumes_nearest_first() {
        let frames = nearest_first(0.25);
        // One label: no boundary at all.
        let e = focus_order(&frames, &vec![1; SIZE * SIZE], &full(3));
        assert_eq!(
            (e.order, e.votes, e.nearest_share()),
            (Order::Unknown, 0, 0.5)
        );
        assert_eq!(e.order.assumed(), Order::NearestFirst);
        assert_eq!(e.order.frame_at(1, 4), 1);
        assert!(e.to_string().contains("nearest focus first assumed"), "{e}");
        // The disc's left half near first, its right half as if shot the other way round.
        let reversed: Vec<Plane> = frames.iter().rev().cloned().collect();
        let mixed: Vec<Plane> = (0..3)
            .map(|k| {
                Plane::from_fn(SIZE, SIZE, 1, |x, y, _| {
                    let f = if x < SIZE / 2 { &frames } else { &reversed };
                    f[k].at(x, y, 0)
                })
            })
            .collect();
        let split: Vec<u8> = labels(0, 2, 0.0)
            .iter()
            .enumerate()
            .map(|(i, &l)| if i % SIZE < SIZE / 2 { l } else { 2 - l })
            .collect();
        let e = focus_order(&mixed, &split, &full(3));
        assert!(e.votes >= MIN_VOTES, "{e:?}");
        assert_eq!(e.order, Order::Unknown, "{e:?}");
        // The decision needs MIN_VOTES even when unanimous.
        let few = OrderEvidence::decide(MIN_VOTES - 1, 10.0, 0.0);
        assert_eq!(few.order, Order::Unknown);
    }

    #[test]
    fn inputs_that_do_not_fit_give_no_votes() {
        let frames = nearest_first(0.25);
        let none = |e: OrderEvidence| (e.order, e.votes);
        let empty: [Plane; 0] = [];
        assert_eq!(none(focus_order(&empty, &[], &[])), (Order::Unknown, 0));
        // Labels of the wrong size, labels naming no frame, a coverage missing.
        assert_eq!(
            none(focus_order(&frames, &[0, 2], &full(3))),
            (Order::Unknown, 0)
        );
        let e = focus_order(&frames, &labels(0, 9, 0.0), &full(3));
        assert_eq!(none(e), (Order::Unknown, 0));
        let e = focus_order(&frames, &labels(0, 2, 0.0), &full(2));
        assert_eq!(none(e), (Order::Unknown, 0));
        // Tiny frames: no room for the reach either side of a boundary.
        let tiny = vec![Plane::from_fn(3, 2, 1, |x, _, _| x as f32 / 2.0); 3];
        let e = focus_order(
            &tiny,
            &[0, 2, 0, 2, 0, 2],
            &[
                Coverage::full(3, 2),
                Coverage::full(3, 2),
                Coverage::full(3, 2),
            ],
        );
        assert_eq!(none(e), (Order::Unknown, 0));
    }
}
