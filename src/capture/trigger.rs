//! The hardware key that triggers a capture: a short press starts one, a long press cancels the
//! running one (the paper's phone took a whole stack with one press of the camera key).
//!
//! The keys are behind [`Keys`] (evdev on a phone, `backend::input`; a scripted fake in the
//! tests), which reports presses and releases with their times; [`Presses`] turns them into
//! [`Gesture`]s, and [`watch`] runs the two on the watcher's thread, handing each gesture to the
//! daemon's main loop, which decides what it does.

use super::Nanos;

/// One key on one device: the same key code on two devices is two keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KeyId {
    pub device: u64,
    pub code: u16,
}

/// What [`Keys::wait`] saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Seen {
    /// A trigger key went down (`down`) or up, at `at` on CLOCK_MONOTONIC.
    Key { key: KeyId, down: bool, at: Nanos },
    /// What the keys of `device` are doing is no longer known: it went away, or the kernel
    /// dropped some of its events. A key held on it is forgotten, not taken as released.
    Lost { device: u64 },
    /// Nothing before the deadline; it is now `now`.
    Timeout { now: Nanos },
}

/// The trigger keys.
pub trait Keys: Send {
    /// Waits for the next press or release of a trigger key, until `until` on CLOCK_MONOTONIC
    /// (`None`: no limit). `None` when no key can ever come (no device and no way to learn
    /// of a new one).
    fn wait(&mut self, until: Option<Nanos>) -> Option<Seen>;
}

/// What the person holding the phone asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gesture {
    /// Released before the long-press time: take a stack.
    Press,
    /// Held for the long-press time: stop the running job.
    LongPress,
}

/// Turns key presses and releases into gestures: a press released before `long` is a
/// [`Gesture::Press`]; one held for `long` is a [`Gesture::LongPress`] as soon as that time has
/// passed (the person does not have to let go to cancel), and its release then does nothing.
/// One key at a time: others pressed while it is held are ignored.
pub struct Presses {
    long: Nanos,
    held: Option<Held>,
}

struct Held {
    key: KeyId,
    since: Nanos,
    /// The long press was reported.
    fired: bool,
}

impl Presses {
    pub fn new(long: Nanos) -> Self {
        Self { long, held: None }
    }

    /// When a held key becomes a long press, if one is held and has not yet.
    pub fn deadline(&self) -> Option<Nanos> {
        self.held
            .as_ref()
            .filter(|h| !h.fired)
            .map(|h| h.since.saturating_add(self.long))
    }

    pub fn seen(&mut self, seen: Seen) -> Option<Gesture> {
        match seen {
            Seen::Key {
                key,
                down: true,
                at,
            } => {
                if self.held.is_none() {
                    self.held = Some(Held {
                        key,
                        since: at,
                        fired: false,
                    });
                }
                None
            }
            Seen::Key {
                key,
                down: false,
                at,
            } => {
                let h = self.held.take_if(|h| h.key == key)?;
                if h.fired {
                    None
                } else if at.saturating_sub(h.since) >= self.long {
                    // The release came late (the thread was busy): the hold still counts.
                    Some(Gesture::LongPress)
                } else {
                    Some(Gesture::Press)
                }
            }
            Seen::Lost { device } => {
                self.held.take_if(|h| h.key.device == device);
                None
            }
            Seen::Timeout { now } => {
                let h = self.held.as_mut().filter(|h| !h.fired)?;
                (now.saturating_sub(h.since) >= self.long).then(|| {
                    h.fired = true;
                    Gesture::LongPress
                })
            }
        }
    }
}

/// Reads `keys` and hands every gesture to `send` until `send` says stop (returns false, the
/// daemon is gone) or no key can come any more.
pub fn watch(keys: &mut dyn Keys, long: Nanos, mut send: impl FnMut(Gesture) -> bool) {
    let mut presses = Presses::new(long);
    while let Some(seen) = keys.wait(presses.deadline()) {
        if let Some(g) = presses.seen(seen) {
            if !send(g) {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    const MS: Nanos = 1_000_000;
    const LONG: Nanos = 800 * MS;

    /// Keys played from a script on simulated time: a deadline before the next event's time is
    /// a timeout at the deadline.
    struct Fake {
        script: VecDeque<Seen>,
    }

    impl Keys for Fake {
        fn wait(&mut self, until: Option<Nanos>) -> Option<Seen> {
            let next = *self.script.front()?;
            let at = match next {
                Seen::Key { at, .. } => at,
                Seen::Lost { .. } | Seen::Timeout { .. } => Nanos::MIN,
            };
            match until {
                Some(t) if t < at => Some(Seen::Timeout { now: t }),
                _ => self.script.pop_front(),
            }
        }
    }

    const CAMERA: KeyId = KeyId {
        device: 1,
        code: 212,
    };

    fn key(key: KeyId, down: bool, ms: Nanos) -> Seen {
        Seen::Key {
            key,
            down,
            at: ms * MS,
        }
    }

    fn gestures(script: Vec<Seen>) -> Vec<Gesture> {
        let mut got = Vec::new();
        let mut fake = Fake {
            script: script.into(),
        };
        watch(&mut fake, LONG, |g| {
            got.push(g);
            true
        });
        got
    }

    #[test]
    fn a_short_press_takes_a_stack_and_a_long_one_cancels_before_it_is_let_go() {
        use Gesture::*;
        assert_eq!(
            gestures(vec![key(CAMERA, true, 1000), key(CAMERA, false, 1200)]),
            [Press]
        );
        // Held for 3 s: one long press, reported at 800 ms (the fake times out there), and the
        // release is nothing.
        assert_eq!(
            gestures(vec![
                key(CAMERA, true, 1000),
                key(CAMERA, false, 4000),
                key(CAMERA, true, 5000),
                key(CAMERA, false, 5100),
            ]),
            [LongPress, Press]
        );
        // A release that arrives late still counts the hold.
        let mut p = Presses::new(LONG);
        assert_eq!(p.seen(key(CAMERA, true, 0)), None);
        assert_eq!(p.deadline(), Some(LONG));
        assert_eq!(p.seen(key(CAMERA, false, 900)), Some(LongPress));
        assert_eq!(p.deadline(), None);
    }

    #[test]
    fn the_long_press_fires_at_its_deadline_and_only_once() {
        let mut p = Presses::new(LONG);
        p.seen(key(CAMERA, true, 100));
        assert_eq!(
            p.seen(Seen::Timeout {
                now: 100 * MS + LONG - 1
            }),
            None
        );
        assert_eq!(
            p.seen(Seen::Timeout {
                now: 100 * MS + LONG
            }),
            Some(Gesture::LongPress)
        );
        assert_eq!(p.deadline(), None);
        assert_eq!(p.seen(Seen::Timeout { now: 10_000 * MS }), None);
        assert_eq!(p.seen(key(CAMERA, false, 5000)), None);
    }

    #[test]
    fn a_device_that_goes_away_while_its_key_is_held_makes_no_gesture() {
        let other = KeyId {
            device: 2,
            code: 212,
        };
        // Gone mid-hold: nothing, not even at the deadline; the next device's press works.
        assert_eq!(
            gestures(vec![
                key(CAMERA, true, 0),
                Seen::Lost { device: 1 },
                key(other, true, 2000),
                key(other, false, 2100),
            ]),
            [Gesture::Press]
        );
        // Another device going away leaves the held key alone.
        assert_eq!(
            gestures(vec![
                key(CAMERA, true, 0),
                Seen::Lost { device: 2 },
                key(CAMERA, false, 300),
            ]),
            [Gesture::Press]
        );
    }

    #[test]
    fn a_second_key_while_one_is_held_is_ignored() {
        let volume = KeyId {
            device: 1,
            code: 115,
        };
        assert_eq!(
            gestures(vec![
                key(CAMERA, true, 0),
                key(volume, true, 100),
                key(volume, false, 200),
                key(CAMERA, false, 300),
            ]),
            [Gesture::Press]
        );
    }

    #[test]
    fn the_watch_stops_when_the_daemon_does() {
        let mut fake = Fake {
            script: vec![
                key(CAMERA, true, 0),
                key(CAMERA, false, 10),
                key(CAMERA, true, 20),
                key(CAMERA, false, 30),
            ]
            .into(),
        };
        let mut sent = 0;
        watch(&mut fake, LONG, |_| {
            sent += 1;
            false
        });
        assert_eq!((sent, fake.script.len()), (1, 2));
    }
}
