//! The kernel's evdev UAPI that focusd uses, written out by hand from `linux/input.h` and
//! `linux/input-event-codes.h` (stable ABI), as the video layer's is (`videodev::abi`): no
//! bindgen. 64-bit Linux: `struct input_event` holds a `struct timeval` of two 64-bit words.
//! The test at the end compiles every size, offset, ioctl number and key code below against
//! the C headers.

use rustix::ioctl::{opcode, Opcode};

/// `struct input_event`: what a read of /dev/input/eventN returns, a whole number of them.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InputEvent {
    pub tv_sec: i64,
    pub tv_usec: i64,
    pub type_: u16,
    pub code: u16,
    pub value: i32,
}

impl InputEvent {
    pub const SIZE: usize = std::mem::size_of::<InputEvent>();

    /// The event laid out in `bytes` (at least [`InputEvent::SIZE`] of them).
    pub fn from_bytes(bytes: &[u8]) -> InputEvent {
        let b = &bytes[..Self::SIZE];
        let word = |i: usize| i64::from_ne_bytes(b[i..i + 8].try_into().expect("8 bytes"));
        InputEvent {
            tv_sec: word(0),
            tv_usec: word(8),
            type_: u16::from_ne_bytes([b[16], b[17]]),
            code: u16::from_ne_bytes([b[18], b[19]]),
            value: i32::from_ne_bytes([b[20], b[21], b[22], b[23]]),
        }
    }

    /// The bytes a write to /dev/uinput takes (the test harness's virtual key).
    pub fn to_bytes(self) -> [u8; Self::SIZE] {
        let mut b = [0u8; Self::SIZE];
        b[0..8].copy_from_slice(&self.tv_sec.to_ne_bytes());
        b[8..16].copy_from_slice(&self.tv_usec.to_ne_bytes());
        b[16..18].copy_from_slice(&self.type_.to_ne_bytes());
        b[18..20].copy_from_slice(&self.code.to_ne_bytes());
        b[20..24].copy_from_slice(&self.value.to_ne_bytes());
        b
    }

    /// The event's time in nanoseconds (on the clock set with [`EVIOCSCLOCKID`]).
    pub fn nanos(&self) -> i64 {
        self.tv_sec
            .saturating_mul(1_000_000_000)
            .saturating_add(self.tv_usec.saturating_mul(1000))
    }
}

pub const EV_SYN: u16 = 0x00;
pub const EV_KEY: u16 = 0x01;
pub const SYN_REPORT: u16 = 0;
pub const SYN_DROPPED: u16 = 3;
/// The highest key code: a key bitmap has `KEY_MAX / 8 + 1` bytes.
pub const KEY_MAX: u16 = 0x2ff;
pub const KEY_BITS_BYTES: usize = KEY_MAX as usize / 8 + 1;

/// The device's name (`EVIOCGNAME(256)`).
pub const EVIOCGNAME: Opcode = opcode::read::<[u8; 256]>(b'E', 0x06);
/// The keys the device can report (`EVIOCGBIT(EV_KEY, KEY_MAX / 8 + 1)`).
pub const EVIOCGBIT_KEY: Opcode = opcode::read::<[u8; KEY_BITS_BYTES]>(b'E', 0x20 + EV_KEY as u8);
/// The clock of the event timestamps (`EVIOCSCLOCKID`; realtime unless told).
pub const EVIOCSCLOCKID: Opcode = opcode::write::<i32>(b'E', 0xa0);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::input::keys::KEYS;
    use crate::backend::videodev::abi::tests::compile;
    use std::fmt::Write as _;
    use std::mem::{offset_of, size_of};

    #[test]
    fn layouts_and_codes_match_the_kernel_headers() {
        let mut c = String::from("#include <stddef.h>\n#include <linux/input.h>\n");
        let _ = writeln!(
            c,
            "_Static_assert(sizeof(struct input_event) == {}, \"size\");\n\
             _Static_assert(offsetof(struct input_event, type) == {}, \"type\");\n\
             _Static_assert(offsetof(struct input_event, code) == {}, \"code\");\n\
             _Static_assert(offsetof(struct input_event, value) == {}, \"value\");",
            size_of::<InputEvent>(),
            offset_of!(InputEvent, type_),
            offset_of!(InputEvent, code),
            offset_of!(InputEvent, value),
        );
        let mut value = |name: &str, v: u64| {
            let _ = writeln!(
                c,
                "_Static_assert((unsigned int)({name}) == {v}U, \"{name}\");"
            );
        };
        for (name, v) in [
            ("EV_SYN", EV_SYN.into()),
            ("EV_KEY", EV_KEY.into()),
            ("SYN_REPORT", SYN_REPORT.into()),
            ("SYN_DROPPED", SYN_DROPPED.into()),
            ("KEY_MAX", KEY_MAX.into()),
            ("EVIOCGNAME(256)", EVIOCGNAME as u64),
            ("EVIOCGBIT(EV_KEY, KEY_MAX / 8 + 1)", EVIOCGBIT_KEY as u64),
            ("EVIOCSCLOCKID", EVIOCSCLOCKID as u64),
        ] {
            value(name, v);
        }
        for (name, code) in KEYS {
            value(name, (*code).into());
        }
        let dir = tempfile::tempdir().expect("tempdir");
        let source = dir.path().join("input.c");
        std::fs::write(&source, c).expect("write");
        assert!(
            compile("cc", &source).expect("x86-64 headers"),
            "no C compiler `cc`: install gcc and linux-libc-dev"
        );
        if !compile("aarch64-linux-gnu-gcc", &source).expect("arm64 headers") {
            assert!(
                std::env::var_os("FOCUSD_REQUIRE_ARM64_HEADERS").is_none(),
                "aarch64-linux-gnu-gcc not found"
            );
        }
    }

    #[test]
    fn an_event_survives_its_bytes() {
        let e = InputEvent {
            tv_sec: 12,
            tv_usec: 345_678,
            type_: EV_KEY,
            code: 212,
            value: 1,
        };
        assert_eq!(InputEvent::from_bytes(&e.to_bytes()), e);
        assert_eq!(e.nanos(), 12_345_678_000);
    }
}
