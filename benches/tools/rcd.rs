//! Ratio Corrected Demosaicing (Luis Sanz Rodríguez, 2017): a cheap directional demosaic of
//! small reach, measured against the product's residual interpolation
//! (`focusd::develop::demosaic`).
//!
//! Green at red and blue samples from its four neighbours, each corrected by the ratio of a
//! low-pass filtered mosaic (3×3 binomial, which mixes the colours evenly) between the pixel and
//! the next sample of its own colour that way, the two of each axis weighted by the inverse of
//! their side's gradient, the two axes by how much high-frequency energy the mosaic has along
//! each (a 7-tap high-pass filter squared, summed over three neighbours across). Then red at
//! blue samples and blue at red ones from the four diagonal colour differences, the diagonals
//! weighted likewise; then red and blue at green samples from the four cardinal colour
//! differences, weighted as green was. Every estimate is clamped to 0..=1.
//!
//! Written here from the algorithm's description and checked against its reference (GPL, so
//! not copied): the same values, within float rounding, on a simulator scene.

use focusd::develop::demosaic::mirrored;
use focusd::develop::{srgb_tabulated, BayerOrder, Mosaic};
use focusd::stack::Image;
use rayon::prelude::*;

/// How far an output pixel's value reaches into the mosaic: red and blue at green samples read
/// them at green's cardinal neighbours 3 away, which reach 7 (diagonals at 3, green at 2 more,
/// its discrimination 5); even, so padded coordinates keep the pattern's phase.
const REACH: usize = 10;

/// Keeps the ratios and weights finite where the mosaic is black or flat.
const EPS: f32 = 1e-5;
const EPS_SQ: f32 = 1e-10;

/// Output rows per strip, each read with `REACH` rows of halo above and below.
const STRIP_ROWS: usize = 64;

/// Linear RGB, three channels, from a linear mosaic: demosaicked on its sRGB-encoded samples
/// if `encoded`, as the product's demosaic is, on the linear ones if not.
pub fn rcd(m: &Mosaic, encoded: bool) -> Image<f32> {
    let curves = encoded.then(srgb_tabulated);
    let encode = |v: f32| curves.map_or(v, |t| t.encode.at(v));
    let decode = |v: f32| curves.map_or(v, |t| t.decode.at(v));
    let (w, h) = (m.width, m.height);
    let (pw, ph) = (w + 2 * REACH, h + 2 * REACH);
    let cols: Vec<usize> = (0..pw)
        .map(|x| mirrored(x as isize - REACH as isize, w))
        .collect();
    let mut padded = Vec::with_capacity(pw * ph);
    for y in 0..ph {
        let row = &m.data[mirrored(y as isize - REACH as isize, h) * w..][..w];
        padded.extend(cols.iter().map(|&x| encode(row[x])));
    }
    let mut out = vec![0.0f32; w * h * 3];
    out.par_chunks_mut(STRIP_ROWS * w * 3)
        .enumerate()
        .for_each_init(Workspace::default, |ws, (i, chunk)| {
            let n = chunk.len() / (w * 3);
            let strip = &padded[i * STRIP_ROWS * pw..(i * STRIP_ROWS + n + 2 * REACH) * pw];
            develop(strip, pw, m.order, ws);
            for (y, row) in chunk.chunks_exact_mut(w * 3).enumerate() {
                let at = (y + REACH) * pw + REACH;
                let planes = [&ws.r[at..][..w], &ws.g[at..][..w], &ws.b[at..][..w]];
                for (x, px) in row.chunks_exact_mut(3).enumerate() {
                    px[0] = decode(planes[0][x]);
                    px[1] = decode(planes[1][x]);
                    px[2] = decode(planes[2][x]);
                }
            }
        });
    Image::from_vec(w, h, 3, out)
}

/// The planes a window is developed in.
#[derive(Default)]
struct Workspace {
    /// High-pass energies, the low-pass mosaic, the discriminations (see [`develop`]).
    t: [Vec<f32>; 4],
    r: Vec<f32>,
    g: Vec<f32>,
    b: Vec<f32>,
}

/// The squared 7-tap high-pass filter of the mosaic `s` at `i`, along a line of step `d`.
#[inline(always)]
fn high_pass(s: &[f32], i: usize, d: usize) -> f32 {
    let v = (s[i - 3 * d] - s[i - d] - s[i + d] + s[i + 3 * d])
        - 3.0 * (s[i - 2 * d] + s[i + 2 * d])
        + 6.0 * s[i];
    v * v
}

/// A discrimination (0 one way, 1 the other) refined by its four diagonal neighbours: their
/// mean where it is the more decided.
#[inline(always)]
fn refined(d: &[f32], i: usize, w: usize) -> f32 {
    let own = d[i];
    let around = 0.25 * (d[i - w - 1] + d[i - w + 1] + d[i + w - 1] + d[i + w + 1]);
    if (0.5 - own).abs() < (0.5 - around).abs() {
        around
    } else {
        own
    }
}

/// The estimates `a` and `b` from two opposite sides, each weighted by the other side's
/// gradient.
#[inline(always)]
fn blend(a: f32, grad_a: f32, b: f32, grad_b: f32) -> f32 {
    (grad_b * a + grad_a * b) / (grad_a + grad_b)
}

/// The first x from `from` on where row `y` holds a sample of colour `c` (green if `green`,
/// red or blue if not).
fn first(order: BayerOrder, y: usize, from: usize, green: bool) -> usize {
    from + usize::from((order.channel(from, y) == 1) != green)
}

/// Each pixel `margin` or more inside the `w`×`h` window: `f(i)` for its index.
fn inside(w: usize, h: usize, margin: usize, mut f: impl FnMut(usize)) {
    for y in margin..h - margin {
        (y * w + margin..(y + 1) * w - margin).for_each(&mut f);
    }
}

/// Red, green and blue of the `w`-wide window `cfa` (whose first row and column have the
/// pattern's phase) into `ws.r`, `ws.g`, `ws.b`; values within `REACH` of its edges are not
/// meaningful.
fn develop(cfa: &[f32], w: usize, order: BayerOrder, ws: &mut Workspace) {
    let n = cfa.len();
    let h = n / w;
    assert!(h > 2 * REACH && w > 2 * REACH, "window {w}x{h} too small");
    for p in &mut ws.t {
        p.resize(n, 0.0);
    }
    for p in [&mut ws.r, &mut ws.g, &mut ws.b] {
        p.clear();
        p.extend_from_slice(cfa);
    }
    let Workspace { t, r, g, b } = ws;
    let [t0, t1, vh, pq] = t;
    let c = cfa;
    // High-pass energy down the columns and along the rows, 3 in; the vertical/horizontal
    // discrimination from their sums over three pixels across, 4 in.
    inside(w, h, 3, |i| t0[i] = high_pass(c, i, w));
    inside(w, h, 3, |i| t1[i] = high_pass(c, i, 1));
    inside(w, h, 4, |i| {
        let v = (t0[i - w] + t0[i] + t0[i + w]).max(EPS_SQ);
        let hz = (t1[i - 1] + t1[i] + t1[i + 1]).max(EPS_SQ);
        vh[i] = v / (v + hz);
    });
    // The low-pass mosaic, 1 in.
    let lpf = &mut *t0;
    inside(w, h, 1, |i| {
        lpf[i] = 0.25 * c[i]
            + 0.125 * (c[i - w] + c[i + w] + c[i - 1] + c[i + 1])
            + 0.0625 * (c[i - w - 1] + c[i - w + 1] + c[i + w - 1] + c[i + w + 1]);
    });
    // Green at red and blue samples, 5 in.
    let cardinal = |i: usize, s: isize| {
        let o = |k: isize| c[i.wrapping_add_signed(k * s)];
        EPS + (o(1) - o(-1)).abs() + (o(0) - o(2)).abs() + (o(1) - o(3)).abs() + (o(2) - o(4)).abs()
    };
    for y in 5..h - 5 {
        for x in (first(order, y, 5, false)..w - 5).step_by(2) {
            let i = y * w + x;
            let est = |s: isize| {
                let far = lpf[i.wrapping_add_signed(2 * s)];
                c[i.wrapping_add_signed(s)] * (1.0 + (lpf[i] - far) / (EPS + lpf[i] + far))
            };
            let (sw, sh) = (w as isize, 1);
            let vert = blend(est(-sw), cardinal(i, -sw), est(sw), cardinal(i, sw));
            let horiz = blend(est(-sh), cardinal(i, -sh), est(sh), cardinal(i, sh));
            let disc = refined(vh, i, w);
            g[i] = (disc * horiz + (1.0 - disc) * vert).clamp(0.0, 1.0);
        }
    }
    // High-pass energy along the diagonals P (down-right) and Q (down-left), 3 in, and their
    // discrimination at red and blue samples, 4 in.
    let (p, q) = (w + 1, w - 1);
    inside(w, h, 3, |i| t0[i] = high_pass(c, i, p));
    inside(w, h, 3, |i| t1[i] = high_pass(c, i, q));
    for y in 4..h - 4 {
        for x in (first(order, y, 4, false)..w - 4).step_by(2) {
            let i = y * w + x;
            let ps = (t0[i - p] + t0[i] + t0[i + p]).max(EPS_SQ);
            let qs = (t1[i - q] + t1[i] + t1[i + q]).max(EPS_SQ);
            pq[i] = ps / (ps + qs);
        }
    }
    // From the colour differences on the two sides of a pixel along step `s`, of the colour
    // whose samples or estimates `own` holds there, with green `g`: their blend, and the
    // gradient of each side (`far` the farther same-colour pixel that way, `green` the
    // nearest green sample or estimate beyond the pixel).
    let sides = |own: &[f32], g: &[f32], i: usize, s: usize, far: usize, green: usize| {
        let grad = |near: usize, across: usize, far: usize, gj: usize| {
            EPS + (own[near] - own[across]).abs()
                + (own[near] - own[far]).abs()
                + (g[i] - g[gj]).abs()
        };
        let (back, on) = (
            grad(i - s, i + s, i - far, i - green),
            grad(i + s, i - s, i + far, i + green),
        );
        blend(own[i - s] - g[i - s], back, own[i + s] - g[i + s], on)
    };
    // Red at blue samples and blue at red ones from the diagonals, 7 in.
    for y in 7..h - 7 {
        for x in (first(order, y, 7, false)..w - 7).step_by(2) {
            let i = y * w + x;
            let disc = refined(pq, i, w);
            let along_p = sides(c, g, i, p, 3 * p, 2 * p);
            let along_q = sides(c, g, i, q, 3 * q, 2 * q);
            let out = if order.channel(x, y) == 0 {
                &mut *b
            } else {
                &mut *r
            };
            out[i] = (g[i] + (1.0 - disc) * along_p + disc * along_q).clamp(0.0, 1.0);
        }
    }
    // Red and blue at green samples from the cardinal directions, REACH in.
    for y in REACH..h - REACH {
        for x in (first(order, y, REACH, true)..w - REACH).step_by(2) {
            let i = y * w + x;
            let disc = refined(vh, i, w);
            for plane in [&mut *r, &mut *b] {
                let vert = sides(plane, g, i, w, 3 * w, 2 * w);
                let horiz = sides(plane, g, i, 1, 3, 2);
                plane[i] = (g[i] + (1.0 - disc) * vert + disc * horiz).clamp(0.0, 1.0);
            }
        }
    }
}
