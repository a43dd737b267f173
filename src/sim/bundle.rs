//! Synthetic replay bundles: a rendered stack's frames as the takes of a sweep, with an IMU
//! trace of hand tremor and shake bursts during the takes chosen to be shaken.
//!
//! Timeline: the trace starts with the phone held still (tremor only), then each plane gets a
//! lens settle and its takes, one exposure every frame interval. A shaken take's image is the
//! frame smeared along the shake, so fusing it would visibly hurt.

use super::rng::Rng;
use crate::capture::{ImuSample, Nanos, Sensor};
use crate::develop::raw::{self, Packing};
use crate::develop::{decode, BayerOrder, Mosaic, RawFrame, IDENTITY};
use crate::stack::image::Image;

/// RNG stream of the IMU trace (the stack's own streams are below 1000 + frames).
const STREAM_IMU: u64 = 900;
/// Trace start: one second after boot, like a real monotonic clock.
const T0: Nanos = 1_000_000_000;
/// Held still before the sweep, ns.
const STILL: Nanos = 600_000_000;
const SETTLE: Nanos = 20_000_000;
const EXPOSURE: Nanos = 33_000_000;
const FRAME_INTERVAL: Nanos = 50_000_000;
const SAMPLE_INTERVAL: Nanos = 5_000_000;
/// Lens range of the simulated dw9714.
pub const LENS_RANGE: (i32, i32) = (0, 1023);

/// A raw take's sensor: 10-bit samples over a black level of 64 in a GRBG mosaic, with no
/// colour data (camera RGB is linear sRGB), as the PinePhone Pro's imx258 delivers.
const RAW_ORDER: BayerOrder = BayerOrder::Grbg;
const RAW_BLACK: u16 = 64;
const RAW_WHITE: u16 = 1023;

/// A rendered frame as the raw take a sensor would have recorded: its linear light sampled
/// through the Bayer mosaic and quantised to [`RAW_WHITE`] above [`RAW_BLACK`].
pub fn raw_take(picture: &Image<u8>) -> RawFrame {
    let m = Mosaic::sample(&decode(picture), RAW_ORDER);
    let span = f32::from(RAW_WHITE - RAW_BLACK);
    let samples: Vec<u16> = m
        .data
        .iter()
        .map(|&v| (v.clamp(0.0, 1.0) * span).round() as u16 + RAW_BLACK)
        .collect();
    RawFrame {
        bytes: raw::pack(Packing::Le10, m.width, &samples),
        packing: Packing::Le10,
        stride: Packing::Le10.row_bytes(m.width),
        width: m.width,
        height: m.height,
        order: RAW_ORDER,
        black_level: u32::from(RAW_BLACK),
        matrix: IDENTITY,
        // Camera RGB is the scene's linear sRGB: a grey is grey as it comes.
        white_balance: Some([1.0; 3]),
    }
}

/// One take of the synthetic sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct SimTake {
    pub plane: usize,
    pub lens: i32,
    pub exposure: (Nanos, Nanos),
    pub shaken: bool,
}

/// Which takes shake: plane `plane`'s first `takes` takes; then one steady take follows,
/// unless `recovers` is false.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shake {
    pub plane: usize,
    pub takes: usize,
    pub recovers: bool,
}

/// The takes of a sweep over `planes` planes with `shakes`, and its IMU trace.
pub fn plan(planes: usize, shakes: &[Shake], seed: u64) -> (Vec<SimTake>, Vec<ImuSample>) {
    let mut takes = Vec::new();
    let mut t = T0 + STILL;
    for plane in 0..planes {
        let lens = lens_of(plane, planes);
        t += SETTLE;
        let (shaken, steady) = match shakes.iter().find(|s| s.plane == plane) {
            Some(s) => (s.takes, usize::from(s.recovers)),
            None => (0, 1),
        };
        for k in 0..shaken + steady {
            takes.push(SimTake {
                plane,
                lens,
                exposure: (t, t + EXPOSURE),
                shaken: k < shaken,
            });
            t += FRAME_INTERVAL;
        }
    }
    let end = t + 100_000_000;
    (takes.clone(), trace(&takes, end, seed))
}

/// Evenly spaced from the top of the range (nearest) to the bottom, as the sweep's defaults.
fn lens_of(plane: usize, planes: usize) -> i32 {
    let (lo, hi) = LENS_RANGE;
    let t = plane as f64 / (planes.max(2) - 1) as f64;
    (hi as f64 + (lo - hi) as f64 * t).round() as i32
}

/// Gyroscope and accelerometer at 200 Hz: bias plus a slow random walk of tremor, gravity plus
/// noise, and an 8 Hz shake around every shaken exposure.
fn trace(takes: &[SimTake], end: Nanos, seed: u64) -> Vec<ImuSample> {
    let mut rng = Rng::stream(seed, STREAM_IMU);
    let bias = [0.011, -0.006, 0.002];
    let gravity = [0.3, 9.78, 0.5];
    let mut walk = [0.0f64; 3];
    let mut out = Vec::new();
    let mut t = T0;
    while t <= end {
        let shake = takes.iter().any(|k| {
            k.shaken && (k.exposure.0 - 10_000_000..=k.exposure.1 + 10_000_000).contains(&t)
        });
        let phase = t as f64 * 1e-9 * 2.0 * std::f64::consts::PI * 8.0;
        let burst = if shake { phase.sin() } else { 0.0 };
        for w in &mut walk {
            *w = 0.95 * *w + 0.001 * rng.normal();
        }
        let gyro = std::array::from_fn(|a| bias[a] + walk[a] + 0.12 * burst * [1.0, 0.7, 0.2][a]);
        let accel = std::array::from_fn(|a| {
            gravity[a] + 0.03 * rng.normal() + 1.2 * burst * [0.5, 1.0, 0.3][a]
        });
        out.push(ImuSample {
            t,
            sensor: Sensor::Gyro,
            v: gyro,
        });
        out.push(ImuSample {
            t,
            sensor: Sensor::Accel,
            v: accel,
        });
        t += SAMPLE_INTERVAL;
    }
    out
}

/// `img` smeared horizontally over `length` pixels (a box along the shake).
pub fn smear(img: &Image<u8>, length: usize) -> Image<u8> {
    let (w, ch) = (img.width(), img.channels());
    let half = length / 2;
    Image::from_fn(img.width(), img.height(), ch, |x, y, c| {
        let (lo, hi) = (x.saturating_sub(half), (x + half).min(w - 1));
        let sum: u32 = (lo..=hi).map(|xx| img.at(xx, y, c) as u32).sum();
        (sum as f32 / (hi - lo + 1) as f32).round() as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn takes_follow_the_plan_and_the_trace_covers_them() {
        let shakes = [
            Shake {
                plane: 1,
                takes: 2,
                recovers: true,
            },
            Shake {
                plane: 2,
                takes: 3,
                recovers: false,
            },
        ];
        let (takes, imu) = plan(4, &shakes, 5);
        let per_plane: Vec<usize> = (0..4)
            .map(|p| takes.iter().filter(|t| t.plane == p).count())
            .collect();
        assert_eq!(per_plane, vec![1, 3, 3, 1]);
        let shaken: Vec<(usize, bool)> = takes.iter().map(|t| (t.plane, t.shaken)).collect();
        assert_eq!(shaken[1..4], [(1, true), (1, true), (1, false)]);
        assert!(takes[4..7].iter().all(|t| t.shaken));
        assert_eq!((takes[0].lens, takes.last().unwrap().lens), (1023, 0));
        assert!(imu.windows(2).all(|w| w[0].t <= w[1].t));
        assert!(
            imu.first().unwrap().t <= T0
                && imu.last().unwrap().t > takes.last().unwrap().exposure.1
        );
    }

    #[test]
    fn smear_blurs_along_rows_only() {
        let img = Image::from_fn(9, 3, 1, |x, _, _| if x == 4 { 255 } else { 0 });
        let s = smear(&img, 3);
        assert_eq!((s.at(3, 1, 0), s.at(4, 1, 0), s.at(5, 1, 0)), (85, 85, 85));
        assert_eq!(s.at(1, 0, 0), 0);
    }
}
