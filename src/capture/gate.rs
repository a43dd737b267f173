//! The motion gate: was the phone still enough while a frame was exposed?
//!
//! The paper (section 2.3) rejects a frame when the quadratic sum of each axis' readings during
//! its exposure exceeds a threshold. A plain sum grows with the sample rate, so focusd sums
//! squares times the sampling interval, which makes it the integral of the squared reading over
//! the exposure:
//!
//! `S_axis = Σ v_i² · (T / N)` over the N samples inside the exposure window of length T,
//!
//! for the gyroscope in (rad/s)²·s with the bias measured while still subtracted, and for the
//! accelerometer in (m/s²)²·s with gravity (the still mean) subtracted. A take is rejected when
//! any axis of either sensor exceeds its threshold. The estimated motion blur in pixels is
//! `f_px · ∫|ω| dt = f_px · Σ |ω_i| · (T / N)`.

use super::{CaptureError, ImuSample, Nanos, Sensor};
use serde::{Deserialize, Serialize};

/// Per-axis thresholds of [`measure`]'s sums.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Thresholds {
    /// (rad/s)²·s per axis. 2e-5 is a steady ~0.025 rad/s over 33 ms, which on a PinePhone Pro
    /// (f ≈ 2100 px) smears ~1.7 px.
    pub gyro: f64,
    /// (m/s²)²·s per axis.
    pub accel: f64,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self {
            gyro: 2e-5,
            accel: 0.02,
        }
    }
}

/// What the phone does at rest: subtracted from every reading before squaring.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rest {
    /// Gyroscope zero-rate offset, rad/s.
    pub gyro_bias: [f64; 3],
    /// Gravity plus accelerometer offset, m/s².
    pub gravity: [f64; 3],
}

impl Rest {
    /// The mean readings of a still interval; `None` if a sensor has no sample in it.
    pub fn from_samples(samples: &[ImuSample]) -> Option<Rest> {
        Some(Rest {
            gyro_bias: mean(samples, Sensor::Gyro)?,
            gravity: mean(samples, Sensor::Accel)?,
        })
    }
}

fn mean(samples: &[ImuSample], sensor: Sensor) -> Option<[f64; 3]> {
    let (mut sum, mut n) = ([0.0; 3], 0usize);
    for s in samples.iter().filter(|s| s.sensor == sensor) {
        sum.iter_mut().zip(s.v).for_each(|(a, v)| *a += v);
        n += 1;
    }
    (n > 0).then(|| sum.map(|a| a / n as f64))
}

/// The motion during one exposure.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Motion {
    pub gyro_sum: [f64; 3],
    pub accel_sum: [f64; 3],
    /// Estimated motion blur, pixels.
    pub blur_px: f64,
    /// The largest sum over its threshold, across both sensors' axes: > 1 means rejected.
    pub worst_ratio: f64,
    /// Which axis that is, e.g. "gyro y".
    pub worst_axis: &'static str,
}

impl Motion {
    pub fn accepted(&self) -> bool {
        self.worst_ratio <= 1.0
    }
}

const AXES: [[&str; 3]; 2] = [
    ["gyro x", "gyro y", "gyro z"],
    ["accel x", "accel y", "accel z"],
];

/// Measures the motion of the exposure `[start, end]` from `samples` (which may hold more).
/// Fails when either sensor has no sample inside the window, or a reading is not finite.
pub fn measure(
    samples: &[ImuSample],
    (start, end): (Nanos, Nanos),
    rest: &Rest,
    thresholds: &Thresholds,
    focal_px: f64,
) -> Result<Motion, CaptureError> {
    let window: Vec<&ImuSample> = samples
        .iter()
        .filter(|s| (start..=end).contains(&s.t))
        .collect();
    if let Some(s) = window.iter().find(|s| s.v.iter().any(|v| !v.is_finite())) {
        return Err(CaptureError::device(
            "IMU",
            format!(
                "{:?} reading at {} ns is not a number: {:?}",
                s.sensor, s.t, s.v
            ),
        ));
    }
    let secs = (end - start).max(0) as f64 * 1e-9;
    let mut sums = [[0.0; 3]; 2];
    let mut blur = 0.0;
    for (k, (sensor, zero)) in [
        (Sensor::Gyro, rest.gyro_bias),
        (Sensor::Accel, rest.gravity),
    ]
    .into_iter()
    .enumerate()
    {
        let readings: Vec<[f64; 3]> = window
            .iter()
            .filter(|s| s.sensor == sensor)
            .map(|s| std::array::from_fn(|a| s.v[a] - zero[a]))
            .collect();
        if readings.is_empty() {
            return Err(CaptureError::device(
                "IMU",
                format!(
                    "no {sensor:?} samples during the exposure {start}..{end} ns: is the sensor \
                     running, and on the monotonic clock?"
                ),
            ));
        }
        let dt = secs / readings.len() as f64;
        for r in &readings {
            for a in 0..3 {
                sums[k][a] += r[a] * r[a] * dt;
            }
            if sensor == Sensor::Gyro {
                blur += (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt() * dt;
            }
        }
        // Finite readings whose squares overflow: no sensor moves that fast, and a report
        // cannot hold an infinite sum.
        if sums[k].iter().any(|v| !v.is_finite()) || !(blur * focal_px).is_finite() {
            return Err(CaptureError::device(
                "IMU",
                format!(
                    "{sensor:?} readings during the exposure {start}..{end} ns are too large to \
                     sum: is the sensor's scale right?"
                ),
            ));
        }
    }
    let limits = [thresholds.gyro, thresholds.accel];
    let (mut worst_ratio, mut worst_axis) = (0.0, AXES[0][0]);
    for k in 0..2 {
        for a in 0..3 {
            let r = sums[k][a] / limits[k];
            if r > worst_ratio {
                (worst_ratio, worst_axis) = (r, AXES[k][a]);
            }
        }
    }
    Ok(Motion {
        gyro_sum: sums[0],
        accel_sum: sums[1],
        blur_px: blur * focal_px,
        worst_ratio,
        worst_axis,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Constant readings at `rate_hz` over [0, 40 ms].
    fn steady(rate_hz: f64, gyro: [f64; 3], accel: [f64; 3]) -> Vec<ImuSample> {
        let n = (0.04 * rate_hz) as i64;
        (0..=n)
            .flat_map(|i| {
                let t = i * (1e9 / rate_hz) as i64;
                [
                    ImuSample {
                        t,
                        sensor: Sensor::Gyro,
                        v: gyro,
                    },
                    ImuSample {
                        t,
                        sensor: Sensor::Accel,
                        v: accel,
                    },
                ]
            })
            .collect()
    }

    const G: [f64; 3] = [0.0, 0.0, 9.81];

    #[test]
    fn sums_do_not_depend_on_the_sample_rate() {
        let rest = Rest {
            gyro_bias: [0.01, 0.0, 0.0],
            gravity: G,
        };
        let win = (5_000_000, 38_000_000);
        let th = Thresholds::default();
        let m = |rate| {
            let s = steady(rate, [0.03, 0.02, 0.0], [0.0, 0.5, 9.81]);
            measure(&s, win, &rest, &th, 2000.0).unwrap()
        };
        let (slow, fast) = (m(100.0), m(1000.0));
        // (0.03 − 0.01)² · 33 ms on x; 0.02² · 33 ms on y; 0.5² · 33 ms on accel y.
        assert!((fast.gyro_sum[0] - 4e-4 * 0.033).abs() < 1e-9, "{fast:?}");
        assert!((fast.gyro_sum[1] - 4e-4 * 0.033).abs() < 1e-9);
        assert!((fast.accel_sum[1] - 0.25 * 0.033).abs() < 1e-9);
        for a in 0..3 {
            assert!((slow.gyro_sum[a] - fast.gyro_sum[a]).abs() < 1e-9);
        }
        // Blur: |ω| = 0.02·√2 rad/s over 33 ms at 2000 px.
        assert!((fast.blur_px - 2000.0 * 0.02 * 2f64.sqrt() * 0.033).abs() < 1e-6);
    }

    #[test]
    fn a_shaken_axis_rejects_and_is_named() {
        let rest = Rest {
            gyro_bias: [0.0; 3],
            gravity: G,
        };
        let th = Thresholds::default();
        let calm = steady(200.0, [0.005, 0.0, 0.0], G);
        let m = measure(&calm, (0, 33_000_000), &rest, &th, 2000.0).unwrap();
        assert!(m.accepted(), "{m:?}");
        let shaken = steady(200.0, [0.0, 0.2, 0.0], G);
        let m = measure(&shaken, (0, 33_000_000), &rest, &th, 2000.0).unwrap();
        assert!(!m.accepted());
        assert_eq!(m.worst_axis, "gyro y");
        let bumped = steady(200.0, [0.0; 3], [0.0, 0.0, 12.0]);
        let m = measure(&bumped, (0, 33_000_000), &rest, &th, 2000.0).unwrap();
        assert_eq!((m.accepted(), m.worst_axis), (false, "accel z"));
    }

    #[test]
    fn missing_or_broken_samples_are_errors() {
        let rest = Rest::default();
        let th = Thresholds::default();
        let s = steady(200.0, [0.0; 3], G);
        let err = measure(&s, (100_000_000, 133_000_000), &rest, &th, 1.0).unwrap_err();
        assert!(err.to_string().contains("no Gyro samples"), "{err}");
        let mut bad = s.clone();
        bad[3].v[1] = f64::NAN;
        let err = measure(&bad, (0, 33_000_000), &rest, &th, 1.0).unwrap_err();
        assert!(err.to_string().contains("not a number"), "{err}");
        // Finite readings whose sums overflow, on either sensor.
        for k in [2, 3] {
            let mut huge = s.clone();
            huge[k].v[0] = 1e200;
            let err = measure(&huge, (0, 33_000_000), &rest, &th, 1.0).unwrap_err();
            let sensor = ["Gyro", "Accel"][k - 2];
            assert!(
                err.to_string().contains(&format!(
                    "{sensor} readings during the exposure 0..33000000 ns are too large to sum"
                )),
                "{err}"
            );
        }
        assert_eq!(
            Rest::from_samples(&s),
            Some(Rest {
                gyro_bias: [0.0; 3],
                gravity: G
            })
        );
        assert_eq!(Rest::from_samples(&[]), None);
    }
}
