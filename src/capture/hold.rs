//! Which way the phone is held, from gravity in the IMU's device frame (x to the right of the
//! screen held in portrait, y to its top edge, z out of the screen; upright reads (0, +g, 0)),
//! as the clockwise quarter turns that make a picture taken so upright.

use serde::Serialize;

/// How the hold was found, for the report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum HoldSource {
    /// Measured when the phone was found still.
    Measured,
    /// Flat when found still: the last hold measured before, during the wait.
    FlatLastSeen,
    /// Flat throughout the wait: portrait assumed.
    FlatPortrait,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Hold {
    /// Clockwise quarter turns a picture needs (0..=3).
    pub quarter_turns: u8,
    pub source: HoldSource,
}

/// Gravity within this angle of the screen's normal counts as flat: the picture's edges tell
/// nothing then.
const FLAT_DEG: f64 = 30.0;

/// The quarter turns for gravity `g` (m/s², device frame); `None` when the phone lies flat
/// (or `g` is no reading).
pub fn turns_of(g: [f64; 3]) -> Option<u8> {
    let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !norm.is_finite() || norm < 1e-6 || g[2].abs() / norm > FLAT_DEG.to_radians().cos() {
        return None;
    }
    Some(if g[1].abs() >= g[0].abs() {
        if g[1] > 0.0 {
            0
        } else {
            2
        }
    } else if g[0] > 0.0 {
        3
    } else {
        1
    })
}

/// Tracks the hold through the still wait: the last confident hold, and whether the phone is
/// flat now.
#[derive(Clone, Copy, Debug, Default)]
pub struct HoldTracker {
    last: Option<u8>,
    flat_now: bool,
}

impl HoldTracker {
    /// One window's mean gravity.
    pub fn see(&mut self, g: [f64; 3]) {
        match turns_of(g) {
            Some(t) => {
                self.last = Some(t);
                self.flat_now = false;
            }
            None => self.flat_now = true,
        }
    }

    pub fn hold(&self) -> Hold {
        match (self.flat_now, self.last) {
            (false, Some(t)) => Hold {
                quarter_turns: t,
                source: HoldSource::Measured,
            },
            (true, Some(t)) => Hold {
                quarter_turns: t,
                source: HoldSource::FlatLastSeen,
            },
            (_, None) => Hold {
                quarter_turns: 0,
                source: HoldSource::FlatPortrait,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const G: f64 = 9.81;

    #[test]
    fn the_four_holds_and_flat() {
        // EXIF 1, 8, 6, 3 for upright, gravity along +x, along -x, upside down.
        assert_eq!(turns_of([0.0, G, 0.0]), Some(0));
        assert_eq!(turns_of([G, 0.0, 0.0]), Some(3));
        assert_eq!(turns_of([-G, 0.0, 0.0]), Some(1));
        assert_eq!(turns_of([0.0, -G, 0.0]), Some(2));
        // Tilted back from upright by `deg`: gravity 35° from the screen's normal is still a
        // hold, 25° is flat.
        let tilt = |deg: f64| [0.0, G * deg.to_radians().cos(), G * deg.to_radians().sin()];
        assert_eq!(turns_of(tilt(55.0)), Some(0));
        assert_eq!(turns_of(tilt(65.0)), None);
        assert_eq!(turns_of([0.0, 0.0, -G]), None);
        assert_eq!(turns_of([f64::NAN, 0.0, 0.0]), None);
    }

    #[test]
    fn flat_keeps_the_last_hold_seen_else_portrait() {
        let mut t = HoldTracker::default();
        t.see([0.0, 0.0, G]);
        assert_eq!(t.hold().source, HoldSource::FlatPortrait);
        assert_eq!(t.hold().quarter_turns, 0);
        t.see([G, 0.0, 0.0]);
        assert_eq!(
            (t.hold().quarter_turns, t.hold().source),
            (3, HoldSource::Measured)
        );
        t.see([0.0, 0.0, G]);
        assert_eq!(
            (t.hold().quarter_turns, t.hold().source),
            (3, HoldSource::FlatLastSeen)
        );
    }
}
