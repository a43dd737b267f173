//! Separable Gaussian blur on f32 planes and area downsampling, parallel over rows.
//!
//! The blur streams: each worker takes a strip of output rows and keeps only the 2r+1
//! horizontally filtered rows its vertical taps need (a ring that stays in L2), so no full-size
//! intermediate plane is written and read back. Both passes run one kernel, `symmetric_sum`,
//! which folds the mirrored taps together and accumulates whole blocks of pixels in registers,
//! so it vectorises.

use super::image::{Image, Plane, Sample};
use rayon::prelude::*;
use std::cell::RefCell;

/// Normalised Gaussian taps, radius ⌈3σ⌉.
pub fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k
}

/// The centre tap and the taps on one side of `gaussian_kernel(sigma)`; σ ≤ 0 gives the
/// identity `[1.0]`, which reproduces the input exactly.
pub(crate) fn gaussian_half(sigma: f32) -> Vec<f32> {
    if sigma <= 0.0 {
        return vec![1.0];
    }
    let k = gaussian_kernel(sigma);
    k[k.len() / 2..].to_vec()
}

/// Gaussian blur with replicated edges; σ ≤ 0 returns a copy.
pub fn gaussian_blur(src: &Plane, sigma: f32) -> Plane {
    if sigma <= 0.0 {
        return src.clone();
    }
    // Allocated zeroed rather than grown from empty (which clears it in place): a plane of
    // 1 MiB or more gets its own mapping, which is zero already, so it is not cleared twice.
    let (w, h) = (src.width(), src.height());
    let mut dst = Plane::from_vec(w, h, 1, vec![0.0; w * h]);
    gaussian_blur_into(src, sigma, &mut dst);
    dst
}

/// [`gaussian_blur`] into `dst`, whose buffer is reused (resized to `src`'s): for a stage that
/// blurs every frame of a stack at one size.
pub fn gaussian_blur_into(src: &Plane, sigma: f32, dst: &mut Plane) {
    if sigma <= 0.0 {
        return dst.clone_from(src);
    }
    debug_assert_eq!(src.channels(), 1);
    let (w, h) = (src.width(), src.height());
    dst.resize(w, h, 1);
    blur_rows_into(dst.data_mut(), w, h, &gaussian_half(sigma), || {
        PlaneRows(src)
    });
}

/// Each channel of `img` through `gaussian_blur`: a lens's blur on a colour frame.
pub fn gaussian_blur_channels(img: &Plane, sigma: f32) -> Plane {
    let planes: Vec<Plane> = img
        .to_planes()
        .iter()
        .map(|p| gaussian_blur(p, sigma))
        .collect();
    Plane::from_planes(&planes)
}

/// Convolves a single-channel plane with a symmetric odd-length kernel along x then y: the
/// plain convolution the tests check the streamed blur's kernel against.
#[cfg(test)]
fn convolve_separable(src: &Plane, k: &[f32]) -> Plane {
    debug_assert_eq!(src.channels(), 1);
    debug_assert!(k.len() % 2 == 1 && k.iter().eq(k.iter().rev()));
    let (w, h) = (src.width(), src.height());
    let mut dst = vec![0.0f32; w * h];
    blur_rows_into(&mut dst, w, h, &k[k.len() / 2..], || PlaneRows(src));
    Plane::from_vec(w, h, 1, dst)
}

/// Writes to `dst` the `w`×`h` convolution (kernel `half`, see `gaussian_half`) of the rows
/// that `source()` streams; one source per strip, so a source can compute its rows on the fly.
pub(crate) fn blur_rows_into<S: Rows>(
    dst: &mut [f32],
    w: usize,
    h: usize,
    half: &[f32],
    source: impl Fn() -> S + Sync,
) {
    assert_eq!(dst.len(), w * h, "blur buffer size");
    par_strips(dst, w, h, |y0, strip| {
        let mut rows = RowBlur::new(source(), w, h, half);
        for (y, out) in (y0..).zip(strip.chunks_exact_mut(w)) {
            rows.row(y, out);
        }
    });
}

/// Splits a row-major buffer into strips of `strip_rows(h)` rows and runs
/// `f(first_row, strip)` on each in parallel.
pub(crate) fn par_strips<T: Send>(
    dst: &mut [T],
    w: usize,
    h: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let rows = strip_rows(h);
    dst.par_chunks_mut(rows * w)
        .enumerate()
        .for_each(|(i, strip)| f(i * rows, strip));
}

/// Rows per parallel strip: a few strips per thread, rather than single rows, because a
/// streaming filter pays a halo of extra rows per strip.
pub(crate) fn strip_rows(h: usize) -> usize {
    h.div_ceil(4 * rayon::current_num_threads()).max(32)
}

/// A source of rows, asked for consecutive `y` (so a source may itself be a stream).
pub(crate) trait Rows {
    fn row(&mut self, y: usize, out: &mut [f32]);
}

/// The rows of a plane.
#[derive(Clone, Copy)]
pub(crate) struct PlaneRows<'a>(pub &'a Plane);

impl Rows for PlaneRows<'_> {
    fn row(&mut self, y: usize, out: &mut [f32]) {
        let w = self.0.width();
        out.copy_from_slice(&self.0.data()[y * w..y * w + w]);
    }
}

/// The luma of an image's rows from `first` on, made as they are read: a source without a
/// whole luma plane.
#[derive(Clone, Copy)]
pub(crate) struct LumaRows<'a, T> {
    pub image: &'a Image<T>,
    pub first: usize,
}

impl<T: Sample> Rows for LumaRows<'_, T> {
    fn row(&mut self, y: usize, out: &mut [f32]) {
        self.image.luma_row(self.first + y, out);
    }
}

/// The last `slots` rows a source made, kept for several readers ([`Cached`]) that each ask for
/// every row in turn: the focus measure's two blurs read the same luma rows. The source is
/// asked for each row once, in the order the readers first ask for it, which is consecutive (as
/// [`Rows`] promises a source) when the reader reaching furthest ahead asks first: each row made
/// once instead of twice, and the frame read from memory once.
pub(crate) struct RowCache<S> {
    src: S,
    w: usize,
    rows: Vec<f32>,
    /// The row each slot holds, `usize::MAX` when empty; row y lives in slot y % slots.
    held: Vec<usize>,
}

impl<S: Rows> RowCache<S> {
    /// Readers may fall up to `slots` − 1 rows behind the row most recently made without a row
    /// being made twice.
    pub(crate) fn new(src: S, w: usize, slots: usize) -> Self {
        Self {
            src,
            w,
            rows: vec![0.0; w * slots],
            held: vec![usize::MAX; slots],
        }
    }

    fn row(&mut self, y: usize, out: &mut [f32]) {
        let slot = y % self.held.len();
        let row = &mut self.rows[slot * self.w..][..self.w];
        if self.held[slot] != y {
            self.src.row(y, row);
            self.held[slot] = y;
        }
        out.copy_from_slice(row);
    }
}

/// One reader of a [`RowCache`].
#[derive(Clone, Copy)]
pub(crate) struct Cached<'c, S>(pub &'c RefCell<RowCache<S>>);

impl<S: Rows> Rows for Cached<'_, S> {
    fn row(&mut self, y: usize, out: &mut [f32]) {
        self.0.borrow_mut().row(y, out);
    }
}

/// Streams the rows of a separable symmetric convolution (replicated edges) of a row source.
/// Its reader may skip rows forward when the source is random access (a plane's rows): rows the
/// vertical pass no longer reads are then never asked for.
pub(crate) struct RowBlur<'k, S> {
    src: S,
    w: usize,
    h: usize,
    /// Centre tap, then the taps at distance 1, 2, … (see `gaussian_half`).
    half: &'k [f32],
    /// The source row padded by r replicated samples on each side.
    padded: Vec<f32>,
    /// Horizontally filtered rows; source row s lives in slot s % (2r+1).
    ring: Vec<f32>,
    /// Next source row to filter into the ring; `None` until the first output row fixes it.
    next: Option<usize>,
    /// Offsets of the taps at -j and +j, in `padded` (horizontal) or `ring` (vertical).
    hlo: Vec<usize>,
    hhi: Vec<usize>,
    vlo: Vec<usize>,
    vhi: Vec<usize>,
}

impl<'k, S: Rows> RowBlur<'k, S> {
    pub(crate) fn new(src: S, w: usize, h: usize, half: &'k [f32]) -> Self {
        let r = half.len() - 1;
        Self {
            src,
            w,
            h,
            half,
            padded: vec![0.0; w + 2 * r],
            ring: vec![0.0; (2 * r + 1) * w],
            next: None,
            hlo: (1..=r).map(|j| r - j).collect(),
            hhi: (1..=r).map(|j| r + j).collect(),
            vlo: vec![0; r],
            vhi: vec![0; r],
        }
    }
}

impl<S: Rows> Rows for RowBlur<'_, S> {
    fn row(&mut self, y: usize, out: &mut [f32]) {
        let (w, h, r) = (self.w, self.h, self.half.len() - 1);
        let slot = |s: usize| (s % (2 * r + 1)) * w;
        let first = y.saturating_sub(r);
        let mut next = self.next.map_or(first, |n| n.max(first));
        while next <= (y + r).min(h - 1) {
            let p = &mut self.padded;
            self.src.row(next, &mut p[r..r + w]);
            let (first, last) = (p[r], p[r + w - 1]);
            p[..r].fill(first);
            p[r + w..].fill(last);
            let dst = &mut self.ring[slot(next)..slot(next) + w];
            symmetric_sum(dst, p, self.half, r, &self.hlo, &self.hhi);
            next += 1;
        }
        self.next = Some(next);
        for j in 1..=r {
            self.vlo[j - 1] = slot(y.saturating_sub(j));
            self.vhi[j - 1] = slot((y + j).min(h - 1));
        }
        symmetric_sum(out, &self.ring, self.half, slot(y), &self.vlo, &self.vhi);
    }
}

/// `out[x] = half[0]·src[c + x] + Σⱼ half[j]·(src[lo[j-1] + x] + src[hi[j-1] + x])`.
///
/// Taps are whole shifted rows (offsets into `src`), so one kernel serves the horizontal pass
/// (shifted windows of a padded row) and the vertical one (rows of the ring). Each block of
/// pixels sums all its taps in registers before one store. A block is eight vector registers
/// wide, so eight independent add chains hide the add latency: 32 pixels with SSE2 (the x86-64
/// baseline), 64 with AVX, which is worth detecting at run time (a quarter less time).
fn symmetric_sum(out: &mut [f32], src: &[f32], half: &[f32], c: usize, lo: &[usize], hi: &[usize]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked just above.
        return unsafe { symmetric_sum_avx(out, src, half, c, lo, hi) };
    }
    symmetric_sum_body::<32>(out, src, half, c, lo, hi)
}

/// `symmetric_sum_body` compiled for AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn symmetric_sum_avx(
    out: &mut [f32],
    src: &[f32],
    half: &[f32],
    c: usize,
    lo: &[usize],
    hi: &[usize],
) {
    symmetric_sum_body::<64>(out, src, half, c, lo, hi)
}

/// `symmetric_sum` with blocks of `LANES` pixels; inlined so each caller compiles it for its own
/// target features.
#[inline(always)]
fn symmetric_sum_body<const LANES: usize>(
    out: &mut [f32],
    src: &[f32],
    half: &[f32],
    c: usize,
    lo: &[usize],
    hi: &[usize],
) {
    let n = out.len();
    let (k0, ks) = (half[0], &half[1..]);
    let mut blocks = out.chunks_exact_mut(LANES);
    for (i, o) in blocks.by_ref().enumerate() {
        let x = i * LANES;
        let mut acc = block::<LANES>(src, c + x).map(|v| k0 * v);
        for ((&k, &l), &r) in ks.iter().zip(lo).zip(hi) {
            let (a, b) = (block::<LANES>(src, l + x), block::<LANES>(src, r + x));
            for ((s, &a), &b) in acc.iter_mut().zip(a).zip(b) {
                *s += k * (a + b);
            }
        }
        o.copy_from_slice(&acc);
    }
    let tail = n - n % LANES;
    for (x, o) in (tail..n).zip(blocks.into_remainder()) {
        let mut s = k0 * src[c + x];
        for ((&k, &l), &r) in ks.iter().zip(lo).zip(hi) {
            s += k * (src[l + x] + src[r + x]);
        }
        *o = s;
    }
}

#[inline(always)]
fn block<const LANES: usize>(src: &[f32], at: usize) -> &[f32; LANES] {
    src[at..at + LANES].try_into().unwrap()
}

/// Averages `factor`×`factor` blocks of every channel (partial blocks at the right and bottom
/// edges included), straight from the interleaved samples. An output row's sums are formed
/// together, a source row at a time, all channels' sums over a block's row in one pass.
pub fn downsample_area<T: Sample>(src: &Image<T>, factor: usize) -> Image<T> {
    let (w, h, data) = (src.width(), src.height(), src.data());
    let small = match src.channels() {
        1 => downsample_channels::<T, 1>(data, w, h, factor),
        2 => downsample_channels::<T, 2>(data, w, h, factor),
        3 => downsample_channels::<T, 3>(data, w, h, factor),
        4 => downsample_channels::<T, 4>(data, w, h, factor),
        n => panic!("images have 1 to 4 channels, not {n}"),
    };
    let f = factor.max(1);
    Image::from_vec(w.div_ceil(f), h.div_ceil(f), src.channels(), small)
}

/// [`downsample_area`] of one channel's `width`×`height` samples held in a slice, not an image:
/// the focus amplitudes are downsampled where they are made, without a copy.
pub fn downsample_samples<T: Sample>(
    data: &[T],
    width: usize,
    height: usize,
    factor: usize,
) -> Vec<T> {
    assert_eq!(data.len(), width * height, "not {width}x{height} samples");
    downsample_channels::<T, 1>(data, width, height, factor)
}

/// [`downsample_area`] of `w`×`h` pixels of `N` channels (a copy for `factor` 0 or 1), so a
/// block's row is summed a pixel at a time with every channel in registers: a pass per channel,
/// striding over the others, took twice the time.
fn downsample_channels<T: Sample, const N: usize>(
    src: &[T],
    w: usize,
    h: usize,
    factor: usize,
) -> Vec<T> {
    if factor <= 1 {
        return src.to_vec();
    }
    let n = N;
    let (cw, ch) = (w.div_ceil(factor), h.div_ceil(factor));
    let mut dst = vec![T::default(); cw * ch * n];
    dst.par_chunks_mut(cw * n)
        .enumerate()
        .for_each(|(cy, out)| {
            let y0 = cy * factor;
            let y1 = (y0 + factor).min(h);
            let mut sum = vec![0.0f32; cw * n];
            // Row by row, as the sums of f32 planes have always been formed.
            for y in y0..y1 {
                let line = &src[y * w * n..(y + 1) * w * n];
                for (cx, acc) in sum.chunks_exact_mut(n).enumerate() {
                    let block = &line[cx * factor * n..((cx + 1) * factor).min(w) * n];
                    let mut row = [0.0f32; N];
                    for px in block.chunks_exact(N) {
                        for (r, v) in row.iter_mut().zip(px) {
                            *r += v.to_f32();
                        }
                    }
                    for (a, r) in acc.iter_mut().zip(row) {
                        *a += r;
                    }
                }
            }
            for (cx, (px, s)) in out.chunks_exact_mut(n).zip(sum.chunks_exact(n)).enumerate() {
                let x0 = cx * factor;
                let count = ((y1 - y0) * ((x0 + factor).min(w) - x0)) as f32;
                px.iter_mut()
                    .zip(s)
                    .for_each(|(o, s)| *o = T::from_f32(s / count));
            }
        });
    dst
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_blur_into_a_used_plane_is_the_blur() {
        let p = Plane::from_fn(37, 23, 1, |x, y, _| ((x * 7 + y * 3) % 11) as f32);
        // A larger plane's leftovers in the buffer, and a plane of another size.
        let mut dst = Plane::from_fn(50, 40, 1, |_, _, _| -5.0);
        for sigma in [1.3, 0.0, 2.1] {
            gaussian_blur_into(&p, sigma, &mut dst);
            assert_eq!(dst, gaussian_blur(&p, sigma), "σ {sigma}");
        }
    }

    /// A slice of u16 samples (the focus amplitudes) averages to the nearest whole unit, partial
    /// blocks at the edges included, as the same samples held as an image do.
    #[test]
    fn samples_downsample_to_the_rounded_block_means() {
        let (w, h, f) = (11, 7, 3);
        let data: Vec<u16> = (0..w * h).map(|i| (i * 7919 % 60001) as u16).collect();
        let small = downsample_samples(&data, w, h, f);
        let (cw, ch) = (w.div_ceil(f), h.div_ceil(f));
        assert_eq!(small.len(), cw * ch);
        for (i, &got) in small.iter().enumerate() {
            let (cx, cy) = (i % cw * f, i / cw * f);
            let block: Vec<f64> = (cy..(cy + f).min(h))
                .flat_map(|y| (cx..(cx + f).min(w)).map(move |x| (x, y)))
                .map(|(x, y)| data[y * w + x] as f64)
                .collect();
            let mean = block.iter().sum::<f64>() / block.len() as f64;
            assert_eq!(got, mean.round() as u16, "block {i}");
        }
        let image = Image::from_vec(w, h, 1, data.clone());
        assert_eq!(downsample_area(&image, f).data(), small);
        assert_eq!(downsample_samples(&data, w, h, 1), data);
    }

    #[test]
    fn blur_keeps_constant_and_mean() {
        let p = Plane::from_fn(37, 23, 1, |x, y, _| ((x * 7 + y * 13) % 11) as f32);
        let b = gaussian_blur(&p, 2.0);
        let mean = |q: &Plane| q.data().iter().sum::<f32>() / q.data().len() as f32;
        assert!((mean(&p) - mean(&b)).abs() < 0.2);
        let c = gaussian_blur(&Plane::from_fn(9, 9, 1, |_, _, _| 3.0), 1.5);
        assert!(c.data().iter().all(|v| (v - 3.0).abs() < 1e-5));
        // Blurring must reduce variance of a high-frequency pattern.
        let var = |q: &Plane| {
            let m = mean(q);
            q.data().iter().map(|v| (v - m) * (v - m)).sum::<f32>()
        };
        assert!(var(&b) < 0.5 * var(&p));
    }

    /// The direct clamped-index convolution the streaming one must match.
    fn reference(src: &Plane, k: &[f32]) -> Plane {
        let (w, h, r) = (
            src.width() as isize,
            src.height() as isize,
            k.len() as isize / 2,
        );
        let at = |p: &Plane, x: isize, y: isize| {
            p.at(x.clamp(0, w - 1) as usize, y.clamp(0, h - 1) as usize, 0)
        };
        let tap = |i: usize| (k[i], i as isize - r);
        let tmp = Plane::from_fn(src.width(), src.height(), 1, |x, y, _| {
            (0..k.len())
                .map(tap)
                .map(|(kv, d)| kv * at(src, x as isize + d, y as isize))
                .sum()
        });
        Plane::from_fn(src.width(), src.height(), 1, |x, y, _| {
            (0..k.len())
                .map(tap)
                .map(|(kv, d)| kv * at(&tmp, x as isize, y as isize + d))
                .sum()
        })
    }

    #[test]
    fn streaming_blur_matches_direct_convolution() {
        // Sizes around the register block and strip heights, and kernels wider than the plane.
        for (w, h) in [(1, 1), (3, 2), (16, 5), (37, 70), (50, 33), (129, 97)] {
            let p = Plane::from_fn(w, h, 1, |x, y, _| ((x * 31 + y * 17) % 13) as f32 / 13.0);
            for sigma in [0.7, 1.0, 2.0, 5.0] {
                let k = gaussian_kernel(sigma);
                let (got, want) = (convolve_separable(&p, &k), reference(&p, &k));
                let err = got
                    .data()
                    .iter()
                    .zip(want.data())
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f32::max);
                assert!(err < 1e-5, "{w}x{h} sigma {sigma}: max error {err}");
            }
        }
    }

    /// A reader of a random-access source may skip rows (the compose's band selection skips
    /// rows where a frame is absent): the rows it asks for are those of the whole blur, to the
    /// bit, after short skips (within the kernel's reach), long ones and none.
    #[test]
    fn a_blur_read_with_rows_skipped_gives_the_same_rows() {
        let (w, h) = (23, 61);
        let p = Plane::from_fn(w, h, 1, |x, y, _| ((x * 31 + y * 17) % 13) as f32 / 13.0);
        let half = gaussian_half(2.0);
        let mut whole = Plane::new(w, h, 1);
        blur_rows_into(whole.data_mut(), w, h, &half, || PlaneRows(&p));
        let mut blur = RowBlur::new(PlaneRows(&p), w, h, &half);
        let mut row = vec![0.0; w];
        for y in [0, 1, 3, 4, 20, 21, 22, 40, 59, 60] {
            blur.row(y, &mut row);
            assert_eq!(row, whole.data()[y * w..][..w], "row {y}");
        }
    }

    #[test]
    fn block_widths_agree_exactly() {
        // The SSE2 and AVX block widths must give the same bits; run both on any machine.
        let src: Vec<f32> = (0..300).map(|i| ((i * 37) % 101) as f32 / 101.0).collect();
        let half = gaussian_half(2.0);
        let (lo, hi): (Vec<usize>, Vec<usize>) = (1..half.len()).map(|j| (6 - j, 6 + j)).unzip();
        let (mut a, mut b) = (vec![0.0; 288], vec![0.0; 288]);
        symmetric_sum_body::<32>(&mut a, &src, &half, 6, &lo, &hi);
        symmetric_sum_body::<64>(&mut b, &src, &half, 6, &lo, &hi);
        assert_eq!(a, b);
    }

    #[test]
    fn downsample_averages_blocks() {
        let p = Plane::from_fn(5, 3, 1, |x, _, _| x as f32);
        let d = downsample_area(&p, 2);
        assert_eq!((d.width(), d.height()), (3, 2));
        assert_eq!(d.data(), vec![0.5, 2.5, 4.0, 0.5, 2.5, 4.0]);
        let rgb = Image::<u8>::from_fn(5, 3, 3, |x, y, c| (10 * x + 3 * y + 50 * c) as u8);
        let d = downsample_area(&rgb, 2);
        assert_eq!((d.width(), d.height(), d.channels()), (3, 2, 3));
        // Block (1, 0): x 2..4, y 0..2, so 25 + 1.5 + 50c, rounded half away from zero.
        assert_eq!(d.data()[3..6], [27, 77, 127]);
        assert_eq!(d.data()[15..], [46, 96, 146]);
    }
}
