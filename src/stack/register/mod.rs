//! Registration of a hand-held focus stack: a global affine per frame, reference → frame.
//!
//! Frames differ by a small pose (shift, roll, focus breathing, exposure) and, more, by focus: each
//! is sharp at one depth and blurred elsewhere. Following section 2.1 of Zhang et al.:
//!
//! 1. [`keypoints`]: upright difference-of-Gaussian blobs on a reduced plane (≤
//!    `detect_pixels`), which defocus widens but does not move; [`descriptor`]: SIFT-style
//!    descriptors scaled with each blob.
//! 2. [`matching`]: nearest neighbours within a hand-held search radius, ratio test, cross-check.
//! 3. [`ransac`]: a seeded RANSAC affine, refined by least squares on its inliers. A frame too
//!    differently focused to match the reference is chained through its neighbours towards it.
//! 4. [`refine`]: dense robust Lucas–Kanade against the reference, coarse to fine up to
//!    `refine_pixels`, for sub-pixel accuracy; on its finest level the frame and the reference
//!    are first brought to equal local defocus ([`equalise`]), which removes most of the bias
//!    defocus puts into an intensity fit.
//! 5. [`local`] (`local`, on by default): a dense displacement field on top of the global affine
//!    for near objects that move against the background by parallax, chained between
//!    neighbouring frames, kept only where it explains the frames clearly better.

mod descriptor;
mod equalise;
mod keypoints;
mod levels;
mod local;
mod matching;
pub(crate) mod ransac;
mod refine;

use super::image::{Image, Plane, Sample};
use super::transform::{Affine, OffsetField};
use super::{NoProgress, Progress, Stage};
use levels::{level_within, Levels, MIN_SIDE};
use matching::Features;
use ransac::{Fit, Pair};
use rayon::prelude::*;
use refine::Template;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Tuning of [`register`]; the defaults were tuned on 0.2–3 MP synthetic hand-held stacks.
#[derive(Clone, Debug, PartialEq)]
pub struct RegisterParams {
    /// Keypoints are found on the largest pyramid level with at most this many pixels: finer
    /// levels add time, not matches, since most of every frame is defocused anyway, and the
    /// dense refinement that follows lands on the same affines from a coarser start.
    pub detect_pixels: usize,
    /// The dense refinement stops at the largest level with at most this many pixels, and at
    /// half size at the finest (at full size the defocus equalisation's blurs no longer span a
    /// stack's defocus). Finer is more precise: sub-pixel misregistration is most of what keeps
    /// the output from the truth away from depth steps; beyond this, more pixels cost CPU and
    /// gained nothing measurable (the speed and quality records in `docs/records/`).
    pub refine_pixels: usize,
    /// Pyramid levels the dense refinement visits, coarse to fine; 0 keeps the keypoint affine.
    pub refine_levels: usize,
    /// Gauss–Newton steps per level at most.
    pub refine_iterations: usize,
    /// Local registration ([`local`]): a dense displacement field on top of each affine, chained
    /// between neighbouring frames, for near objects moving against the background by parallax.
    /// It replaced a smooth offset field fitted against the reference (the paper's smoothly
    /// varying affine, σ ≈ 80 px), which on 800×600 stacks with 6 px of parallax took the error
    /// where frames are sharp only from 1.97 to 1.86 px on the nearest frame.
    pub local: bool,
    /// Local registration works on the largest pyramid level with at most this many pixels: the
    /// level registration detects keypoints on or a coarser one, so it costs no memory of its
    /// own. Tuned on 1600×1200 frames (level 2, 400×300); smaller frames work on level 1.
    pub local_pixels: usize,
    /// Most keypoints kept per frame, strongest first.
    pub max_keypoints: usize,
    /// Smallest DoG contrast of a keypoint, in luma units (0..1): above the noise of a phone
    /// sensor, low enough for defocused texture.
    pub contrast: f32,
    /// How far a keypoint may move between frames, as a fraction of the frame diagonal: shift plus
    /// roll and breathing at the corners of a hand-held sweep, with margin.
    pub search_radius: f64,
    /// Lowe's ratio: best match distance over second best.
    pub ratio: f32,
    /// RANSAC inlier distance in pixels of the detection level.
    pub inlier_px: f64,
    /// Fewest inlier matches that register a frame. Measured on the synthetic stacks: an
    /// unrelated image reaches 0–4 by chance, the worst real frame 24 directly (more through a
    /// neighbour).
    pub min_inliers: usize,
    /// RANSAC samples at most (fewer once the consensus is certain).
    pub ransac_iterations: usize,
    /// Seed of RANSAC's sampling: the same input gives the same result.
    pub seed: u64,
}

impl Default for RegisterParams {
    fn default() -> Self {
        Self {
            detect_pixels: 200_000,
            refine_pixels: 480_000,
            refine_levels: 4,
            refine_iterations: 10,
            local: true,
            local_pixels: 200_000,
            max_keypoints: 1500,
            contrast: 0.003,
            search_radius: 0.1,
            ratio: 0.8,
            inlier_px: 2.0,
            min_inliers: 16,
            ransac_iterations: 2000,
            seed: 0x5eed,
        }
    }
}

/// How a frame's affine was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// The reference itself: the identity.
    Reference,
    /// Keypoints matched against the reference.
    Direct,
    /// Matched against frame `via` (nearer the reference in the sweep, already registered) and
    /// composed with its affine: the focus gap to the reference was too wide to match across.
    Chained { via: usize },
    /// Too little texture to match at all (a blank or wholly blurred frame): given the affine of
    /// frame `from`, its nearest registered neighbour towards the reference, as the likeliest
    /// pose of a frame taken just before or after it.
    Inherited { from: usize },
}

/// The result of [`register`], one entry per frame in each vector.
#[derive(Clone, Debug, PartialEq)]
pub struct Registration {
    /// Per frame: the affine taking reference pixel coords to that frame's pixel coords
    /// (the convention of [`Affine`]; identity for the reference).
    pub ref_to_frame: Vec<Affine>,
    /// Per frame: how it was registered.
    pub how: Vec<Placement>,
    /// Inlier keypoint matches of the fit that registered the frame (0 for the reference and
    /// inherited frames).
    pub inliers: Vec<usize>,
    /// RMS distance of those inliers from the keypoint affine, full-resolution pixels.
    pub residual_px: Vec<f64>,
    /// Normalised cross-correlation with the reference after dense refinement (on the finest
    /// refinement level; NaN where not refined, 1 for the reference).
    pub correlation: Vec<f64>,
    /// Per frame: the local displacement added to `ref_to_frame` (see
    /// [`crate::stack::transform::Warp`] and [`local`]); None for the reference, inherited frames,
    /// frames beyond an inherited one, and where it stayed within a fraction of a pixel.
    pub field: Vec<Option<OffsetField>>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RegisterError {
    #[error("no frames to register")]
    NoFrames,
    #[error("reference frame {reference} does not exist in a stack of {frames}")]
    Reference { reference: usize, frames: usize },
    #[error("frame {frame} is {width}x{height}, unlike the reference's {ref_width}x{ref_height}")]
    Size {
        frame: usize,
        width: usize,
        height: usize,
        ref_width: usize,
        ref_height: usize,
    },
    #[error("frames of {width}x{height} are too small to register (at least {min}x{min})", min = MIN_SIDE)]
    TooSmall { width: usize, height: usize },
    #[error(
        "frame {frame} cannot be registered: only {inliers} consistent keypoint matches with the \
         reference or its neighbours, {needed} needed (is it from this stack?)"
    )]
    Unmatched {
        frame: usize,
        inliers: usize,
        needed: usize,
    },
    #[error("cancelled")]
    Cancelled,
}

/// One frame ready to match and refine.
struct Prepared {
    levels: Levels,
    features: Features,
}

/// Registers every frame of `lumas` (0..1 luma planes, one size) to frame `reference`.
pub fn register(
    lumas: &[Plane],
    reference: usize,
    p: &RegisterParams,
) -> Result<Registration, RegisterError> {
    register_with(lumas, reference, p, 0, &NoProgress)
}

/// The finest pyramid level registration keeps of a `width`×`height` frame: 0, its luma
/// whole, only where the frame is small enough (or too thin) for its keypoints or, local
/// registration on, its local motion to be found at full size; the refinement never works
/// there. The memory plan counts that plane (`stack::memory`).
pub fn finest_level(width: usize, height: usize, p: &RegisterParams) -> usize {
    let det = level_within(width, height, p.detect_pixels);
    let fine = level_within(width, height, p.refine_pixels).max(1);
    let near = level_within(width, height, p.local_pixels);
    det.min(fine).min(if p.local { near } else { det })
}

/// [`register`] of frames of any sample type and channels (one size), each frame's luma made a
/// row at a time as its pyramid is reduced ([`levels::Luma`]), so no full-resolution luma
/// plane is made (12 MB a frame at 3 MP, and page faults to match).
/// `concurrent_frames` frames are prepared at once, each with its levels and keypoint scale
/// space in memory (about 6 bytes a pixel); 0: one per thread. A memory budget lowers it (see
/// `stack::memory`).
///
/// Reports one step per frame and phase (prepare, match, refine, local field) as stage
/// `Register`, and stops between steps when `progress` is cancelled: on a slow core a stack's
/// registration takes long enough that a watchdog must see it move and a cancel must not wait.
pub fn register_with<T: Sample>(
    frames: &[Image<T>],
    reference: usize,
    p: &RegisterParams,
    concurrent_frames: usize,
    progress: &dyn Progress,
) -> Result<Registration, RegisterError> {
    let n = frames.len();
    if reference >= n {
        return Err(match n {
            0 => RegisterError::NoFrames,
            _ => RegisterError::Reference {
                reference,
                frames: n,
            },
        });
    }
    let size = (frames[reference].width(), frames[reference].height());
    let (w, h) = size;
    if w.min(h) < MIN_SIDE {
        return Err(RegisterError::TooSmall {
            width: w,
            height: h,
        });
    }
    let det = level_within(w, h, p.detect_pixels);
    // Never full size: the defocus equalisation's blurs (up to 5.7 level pixels) fall short of
    // a stack's defocus there (640×480 hand-held: 0.20 px mean corner error at full size, 0.16
    // at half size).
    let fine = level_within(w, h, p.refine_pixels).max(1);
    let coarse = fine + p.refine_levels.max(1) - 1;
    let near = level_within(w, h, p.local_pixels);
    let first = finest_level(w, h, p);
    // Unlimited, rayon still prepares one frame per thread at a time.
    let at_once = match concurrent_frames {
        0 => n.max(1),
        k => k,
    };
    let prepare = |i: usize| {
        let f = &frames[i];
        if (f.width(), f.height()) != (w, h) {
            return Err(RegisterError::Size {
                frame: i,
                width: f.width(),
                height: f.height(),
                ref_width: w,
                ref_height: h,
            });
        }
        let levels = Levels::build(&levels::Luma(f), first, det.max(coarse));
        let features = features(levels.get(det.min(levels.last())), det, p);
        Ok(Prepared { levels, features })
    };
    // Every phase takes each frame once, but the local fields skip the reference.
    let phases = 2 + usize::from(p.refine_levels > 0) + usize::from(p.local);
    progress.stage(Stage::Register, phases * n - usize::from(p.local));
    let step = || {
        progress.advance(1);
        match progress.cancelled() {
            true => Err(RegisterError::Cancelled),
            false => Ok(()),
        }
    };
    let frames = in_workers(
        n,
        at_once,
        || (),
        |(), i| prepare(i).and_then(|f| step().map(|()| f)),
    )?;
    let m = Matcher {
        frames: &frames,
        p,
        radius: (p.search_radius * (w as f64).hypot(h as f64)) as f32,
        threshold: p.inlier_px * (1u64 << det) as f64,
    };
    let direct: Vec<Option<Fit>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let fit = (i != reference).then(|| m.fit(reference, i)).flatten();
            step().map(|()| fit)
        })
        .collect::<Result<_, _>>()?;
    let mut reg = Registration {
        ref_to_frame: vec![Affine::IDENTITY; n],
        how: vec![Placement::Reference; n],
        inliers: vec![0; n],
        residual_px: vec![0.0; n],
        correlation: vec![f64::NAN; n],
        field: vec![None; n],
    };
    reg.correlation[reference] = 1.0;
    // Outwards from the reference, so every frame nearer to it is settled before it is needed.
    let outwards: Vec<usize> = (0..reference).rev().chain(reference + 1..n).collect();
    for &i in &outwards {
        chain_or_inherit(&mut reg, &m, direct[i].clone(), reference, i)?;
    }
    if p.refine_levels > 0 {
        let tpl = Template::new(&frames[reference].levels, fine, coarse);
        // As many frames at once as are prepared at once: each refinement holds its frame's
        // blur stacks and the planes compared with the template's.
        let refined = in_workers(n, at_once, refine::Buffers::default, |buffers, i| {
            let matched = matches!(reg.how[i], Placement::Direct | Placement::Chained { .. });
            let r = matched.then(|| {
                let (init, levels) = (reg.ref_to_frame[i], &frames[i].levels);
                refine::refine(&tpl, levels, init, p.refine_iterations, buffers)
            });
            step().map(|()| r)
        })?;
        for (i, r) in refined.into_iter().enumerate() {
            if let Some(r) = r {
                reg.ref_to_frame[i] = r.affine;
                reg.correlation[i] = r.correlation;
            }
        }
        for &i in &outwards {
            if let Placement::Inherited { from } = reg.how[i] {
                reg.ref_to_frame[i] = reg.ref_to_frame[from];
            }
        }
    }
    if p.local {
        let plane = |i: usize| frames[i].levels.get(near.min(frames[i].levels.last()));
        // The level above, where kept: it shows texture too fine for the working level.
        let finer = |i: usize| {
            let (l, k) = (&frames[i].levels, near.min(frames[i].levels.last()));
            (k > l.first).then(|| l.get(k - 1))
        };
        let sides = [
            (0..reference).rev().collect::<Vec<_>>(),
            (reference + 1..n).collect(),
        ];
        let k = near.min(frames[reference].levels.last());
        let chains = local::Chain::both(plane(reference), k);
        let fields: Vec<Vec<(usize, Option<OffsetField>)>> = sides
            .into_par_iter()
            .zip(chains)
            .map(|(side, mut chain)| {
                // The chain ends at the first frame placed without a match of its own.
                let mut matched = true;
                let mut fields = Vec::with_capacity(side.len());
                for i in side {
                    matched &= matches!(reg.how[i], Placement::Direct | Placement::Chained { .. });
                    let a = &reg.ref_to_frame[i];
                    let field = matched
                        .then(|| chain.next(local::Warped::new(plane(i), finer(i), a, k), a))
                        .flatten();
                    step()?;
                    fields.push((i, field));
                }
                Ok(fields)
            })
            .collect::<Result<_, _>>()?;
        for (i, f) in fields.into_iter().flatten() {
            reg.field[i] = f;
        }
    }
    Ok(reg)
}

/// `f` of every frame 0..n, in order, at most `at_once` frames at a time (what the memory plan
/// allows to be held at once), by workers (no more than there are threads) that each keep a
/// state made by `init` from one frame to the next (buffers the same size for every frame)
/// and take the next frame as they come free; the first error stops them.
fn in_workers<S, T: Send>(
    n: usize,
    at_once: usize,
    init: impl Fn() -> S + Sync,
    f: impl Fn(&mut S, usize) -> Result<T, RegisterError> + Sync,
) -> Result<Vec<T>, RegisterError> {
    let workers = at_once.min(rayon::current_num_threads()).clamp(1, n.max(1));
    let next = AtomicUsize::new(0);
    let done: Vec<Vec<(usize, T)>> = (0..workers)
        .into_par_iter()
        .map(|_| {
            let mut state = init();
            let mut done = Vec::new();
            loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n {
                    return Ok(done);
                }
                match f(&mut state, i) {
                    Ok(t) => done.push((i, t)),
                    Err(e) => {
                        next.store(n, Ordering::Relaxed);
                        return Err(e);
                    }
                }
            }
        })
        .collect::<Result<_, _>>()?;
    let mut all: Vec<(usize, T)> = done.into_iter().flatten().collect();
    all.sort_unstable_by_key(|&(i, _)| i);
    Ok(all.into_iter().map(|(_, t)| t).collect())
}

/// Settles frame `i`: its direct fit if good enough, else a chain through a registered frame
/// between it and the reference (nearest first), else the pose of its neighbour if it has too
/// little texture to match, else an error.
fn chain_or_inherit(
    reg: &mut Registration,
    m: &Matcher,
    direct: Option<Fit>,
    reference: usize,
    i: usize,
) -> Result<(), RegisterError> {
    let needed = m.p.min_inliers;
    let mut most = direct.as_ref().map_or(0, |f| f.inliers.len());
    let toward: Vec<usize> = if i < reference {
        (i + 1..reference).collect()
    } else {
        (reference + 1..i).rev().collect()
    };
    let mut found = direct
        .filter(|f| f.inliers.len() >= needed)
        .map(|f| (f, Placement::Direct, Affine::IDENTITY));
    for &j in &toward {
        if found.is_some() {
            break;
        }
        if !matches!(reg.how[j], Placement::Direct | Placement::Chained { .. }) {
            continue;
        }
        if let Some(f) = m.fit(j, i) {
            most = most.max(f.inliers.len());
            if f.inliers.len() >= needed {
                found = Some((f, Placement::Chained { via: j }, reg.ref_to_frame[j]));
            }
        }
    }
    if let Some((f, how, ref_to_via)) = found {
        reg.ref_to_frame[i] = f.affine.compose(&ref_to_via);
        reg.how[i] = how;
        reg.inliers[i] = f.inliers.len();
        reg.residual_px[i] = f.rms;
        return Ok(());
    }
    if m.frames[i].features.pos.len() < needed {
        let from = toward.first().copied().unwrap_or(reference);
        reg.ref_to_frame[i] = reg.ref_to_frame[from];
        reg.how[i] = Placement::Inherited { from };
        return Ok(());
    }
    Err(RegisterError::Unmatched {
        frame: i,
        inliers: most,
        needed,
    })
}

/// Keypoints and descriptors of a detection-level plane, positions in full-resolution pixels.
fn features(plane: &Plane, level: usize, p: &RegisterParams) -> Features {
    let ss = keypoints::ScaleSpace::build(plane, 4);
    let kps = keypoints::detect(&ss, p.contrast, p.max_keypoints);
    let desc = descriptor::describe(&ss, &kps);
    let s = (1u64 << level) as f32;
    Features {
        pos: kps.iter().map(|k| (k.x * s, k.y * s)).collect(),
        desc,
    }
}

/// Matches frames of the stack pairwise.
struct Matcher<'a> {
    frames: &'a [Prepared],
    p: &'a RegisterParams,
    /// Search radius and RANSAC threshold in full-resolution pixels.
    radius: f32,
    threshold: f64,
}

impl Matcher<'_> {
    /// The robust affine taking frame `a`'s pixels to frame `b`'s, if any.
    fn fit(&self, a: usize, b: usize) -> Option<Fit> {
        let (fa, fb) = (&self.frames[a].features, &self.frames[b].features);
        let pairs: Vec<Pair> = matching::match_features(fa, fb, self.radius, self.p.ratio)
            .into_iter()
            .map(|(i, j)| {
                let (p, q) = (fa.pos[i], fb.pos[j]);
                ((p.0 as f64, p.1 as f64), (q.0 as f64, q.1 as f64))
            })
            .collect();
        let seed = self.p.seed ^ ((a as u64) << 32 | b as u64);
        ransac::ransac_affine(&pairs, self.threshold, self.p.ransac_iterations, seed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn workers_give_every_frame_in_order_keep_their_state_and_stop_at_an_error() {
        for at_once in [1, 2, 5] {
            // Each worker counts the frames it has taken: its state goes from frame to frame.
            let out = in_workers(
                7,
                at_once,
                || 0,
                |taken, i| {
                    *taken += 1;
                    Ok((i * 10, *taken))
                },
            )
            .unwrap();
            let frames: Vec<usize> = out.iter().map(|o| o.0).collect();
            assert_eq!(frames, [0, 10, 20, 30, 40, 50, 60]);
            // Every worker's first frame counts 1: no more than the workers allowed at once.
            let firsts = out.iter().filter(|o| o.1 == 1).count();
            assert!((1..=at_once).contains(&firsts), "{at_once}: {out:?}");
            assert!(out.iter().any(|o| o.1 > 1), "{at_once}: {out:?}");
            let failed = in_workers(
                7,
                at_once,
                || (),
                |_, i| match i {
                    3 => Err(RegisterError::Cancelled),
                    _ => Ok(i),
                },
            );
            assert_eq!(failed, Err(RegisterError::Cancelled));
        }
        assert_eq!(in_workers(0, 2, || (), |_, i| Ok(i)), Ok(vec![]));
    }
}
