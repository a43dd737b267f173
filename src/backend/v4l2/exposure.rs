//! When a frame was exposed, from its buffer's timestamp and flags and the sensor's controls:
//! the IMU window of a take, and whether the lens had settled before it began.

use crate::capture::Nanos;

use crate::backend::videodev::abi::{
    BUF_FLAG_TIMESTAMP_MASK as TIMESTAMP_MASK, BUF_FLAG_TIMESTAMP_MONOTONIC as TIMESTAMP_MONOTONIC,
    BUF_FLAG_TSTAMP_SRC_EOF as TSTAMP_SRC_EOF, BUF_FLAG_TSTAMP_SRC_MASK as TSTAMP_SRC_MASK,
    BUF_FLAG_TSTAMP_SRC_SOE as TSTAMP_SRC_SOE,
};

/// A `struct timeval` in ns; generic because `time_t` is 32-bit on some 32-bit ABIs.
pub fn timeval_ns(sec: impl Into<i64>, usec: impl Into<i64>) -> Nanos {
    sec.into() * 1_000_000_000 + usec.into() * 1000
}

/// `(exposure_start, exposure_end)` on CLOCK_MONOTONIC of a frame stamped `stamp` with buffer
/// `flags`. A start-of-exposure stamp opens the window; an end-of-frame stamp (the default,
/// and what rkisp1 does) comes after the last line is read out, which itself ends `readout`
/// after the exposure.
pub fn window(
    flags: u32,
    stamp: Nanos,
    exposure: Nanos,
    readout: Nanos,
) -> Result<(Nanos, Nanos), String> {
    if flags & TIMESTAMP_MASK != TIMESTAMP_MONOTONIC {
        return Err(format!(
            "its buffer timestamps are not on CLOCK_MONOTONIC (timestamp type 0x{:04x}), so \
             frames cannot be matched with IMU samples",
            flags & TIMESTAMP_MASK
        ));
    }
    match flags & TSTAMP_SRC_MASK {
        TSTAMP_SRC_SOE => Ok((stamp, stamp + exposure)),
        TSTAMP_SRC_EOF => Ok((stamp - readout - exposure, stamp - readout)),
        src => Err(format!(
            "its buffers have an unknown timestamp source 0x{src:05x}"
        )),
    }
}

pub use crate::backend::videodev::abi::{
    CID_EXPOSURE, CID_EXPOSURE_ABSOLUTE, CID_HBLANK, CID_PIXEL_RATE,
};

/// What the sensor's controls say about its timing; each is `None` where it has no such
/// control.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SensorTiming {
    /// V4L2_CID_EXPOSURE_ABSOLUTE, in 100 µs.
    pub exposure_absolute: Option<i64>,
    /// V4L2_CID_EXPOSURE, in lines (imx258 and most raw sensors).
    pub exposure_lines: Option<i64>,
    /// V4L2_CID_HBLANK, pixels.
    pub hblank: Option<i64>,
    /// V4L2_CID_PIXEL_RATE, pixels per second.
    pub pixel_rate: Option<i64>,
}

impl SensorTiming {
    /// One line's time: (width + HBLANK) / PIXEL_RATE. `width` is the captured width, which
    /// stands in for the sensor's output width (an ISP that scales makes this approximate).
    fn line_ns(&self, width: u32) -> Option<f64> {
        match (self.hblank, self.pixel_rate) {
            (Some(hb), Some(rate)) if rate > 0 && hb >= 0 => {
                Some((i64::from(width) + hb) as f64 * 1e9 / rate as f64)
            }
            _ => None,
        }
    }

    /// The exposure time, from the controls, else the frame interval (an exposure never lasts
    /// longer than a frame, so the window errs on the long side), else unknown.
    pub fn exposure_ns(&self, width: u32, frame_interval: Option<Nanos>) -> Option<Nanos> {
        if let Some(e) = self.exposure_absolute.filter(|&e| e > 0) {
            return Some(e * 100_000);
        }
        if let (Some(lines), Some(line)) =
            (self.exposure_lines.filter(|&l| l > 0), self.line_ns(width))
        {
            return Some((lines as f64 * line).round() as Nanos);
        }
        frame_interval.filter(|&i| i > 0)
    }

    /// The time to read `height` lines out, or 0 when the line time is unknown.
    pub fn readout_ns(&self, width: u32, height: u32) -> Nanos {
        self.line_ns(width)
            .map_or(0, |line| (f64::from(height) * line).round() as Nanos)
    }
}

/// A stream's frame interval in ns from VIDIOC_G_PARM's fraction of a second.
pub fn interval_ns(numerator: u32, denominator: u32) -> Option<Nanos> {
    (numerator > 0 && denominator > 0)
        .then(|| i64::from(numerator) * 1_000_000_000 / i64::from(denominator))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MONO: u32 = 0x2000;

    #[test]
    fn timeval_to_ns() {
        assert_eq!(timeval_ns(12, 345_678), 12_345_678_000);
    }

    #[test]
    fn start_of_exposure_stamp_opens_the_window() {
        assert_eq!(
            window(MONO | 0x1_0000, 1_000_000, 30_000, 5_000),
            Ok((1_000_000, 1_030_000))
        );
    }

    #[test]
    fn end_of_frame_stamp_is_after_readout() {
        assert_eq!(
            window(MONO, 1_000_000, 30_000, 5_000),
            Ok((965_000, 995_000))
        );
        // Other flags (DONE, MAPPED) do not matter.
        assert_eq!(
            window(MONO | 0x5, 1_000_000, 30_000, 0),
            Ok((970_000, 1_000_000))
        );
    }

    #[test]
    fn non_monotonic_timestamps_are_refused() {
        let e = window(0x4000, 1, 1, 0).expect_err("copy timestamps");
        assert!(e.contains("not on CLOCK_MONOTONIC"), "{e}");
        assert!(window(0, 1, 1, 0).is_err(), "unknown timestamp type");
        let e = window(MONO | 0x2_0000, 1, 1, 0).expect_err("unknown source");
        assert!(e.contains("unknown timestamp source"), "{e}");
    }

    #[test]
    fn exposure_from_absolute_control() {
        let t = SensorTiming {
            exposure_absolute: Some(166),
            exposure_lines: Some(1000),
            hblank: Some(100),
            pixel_rate: Some(1_000_000),
        };
        // 166 × 100 µs wins over lines.
        assert_eq!(t.exposure_ns(1280, Some(33_333_333)), Some(16_600_000));
    }

    #[test]
    fn exposure_from_lines_and_line_time() {
        // imx258-like: 4208 + 5352 pixels per line at 640 Mpx/s = 14.9375 µs per line.
        let t = SensorTiming {
            exposure_lines: Some(1000),
            hblank: Some(5352),
            pixel_rate: Some(640_000_000),
            ..SensorTiming::default()
        };
        assert_eq!(t.exposure_ns(4208, None), Some(14_937_500));
        assert_eq!(t.readout_ns(4208, 3120), 46_605_000);
        // Lines without a pixel rate say nothing: the frame interval stands in.
        let lines_only = SensorTiming {
            exposure_lines: Some(1000),
            ..SensorTiming::default()
        };
        assert_eq!(
            lines_only.exposure_ns(4208, Some(33_000_000)),
            Some(33_000_000)
        );
        assert_eq!(lines_only.readout_ns(4208, 3120), 0);
    }

    #[test]
    fn exposure_falls_back_to_the_frame_interval_or_nothing() {
        let none = SensorTiming::default();
        assert_eq!(none.exposure_ns(640, interval_ns(1, 30)), Some(33_333_333));
        assert_eq!(none.exposure_ns(640, None), None);
        assert_eq!(interval_ns(0, 30), None);
        assert_eq!(interval_ns(1, 0), None);
    }
}
