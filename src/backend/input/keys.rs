//! Key names as evdev spells them (`linux/input-event-codes.h`), for the keys a phone, a
//! headset or a Bluetooth remote (a selfie stick sends `KEY_VOLUMEUP` or `KEY_ENTER`) can
//! trigger with. The codes are checked against the kernel header (`abi`'s test).

/// `(name, code)`, the names the config's `[trigger] keys` takes.
pub const KEYS: &[(&str, u16)] = &[
    ("KEY_CAMERA", 212),
    ("KEY_VOLUMEUP", 115),
    ("KEY_VOLUMEDOWN", 114),
    ("KEY_MUTE", 113),
    ("KEY_POWER", 116),
    ("KEY_ENTER", 28),
    ("KEY_KPENTER", 96),
    ("KEY_SPACE", 57),
    ("KEY_OK", 0x160),
    ("KEY_SELECT", 0x161),
    ("KEY_PLAYPAUSE", 164),
    ("KEY_PLAY", 207),
    ("KEY_PAUSE", 119),
    ("KEY_PLAYCD", 200),
    ("KEY_PAUSECD", 201),
    ("KEY_STOPCD", 166),
    ("KEY_NEXTSONG", 163),
    ("KEY_PREVIOUSSONG", 165),
    ("KEY_RECORD", 167),
    ("KEY_PHONE", 169),
    ("KEY_MEDIA", 226),
    ("KEY_ASSISTANT", 0x247),
    ("KEY_PROG1", 148),
    ("KEY_PROG2", 149),
    ("KEY_PROG3", 202),
    ("KEY_PROG4", 203),
    ("KEY_CAMERA_ZOOMIN", 0x215),
    ("KEY_CAMERA_ZOOMOUT", 0x216),
    ("KEY_CAMERA_UP", 0x217),
    ("KEY_CAMERA_DOWN", 0x218),
    ("KEY_CAMERA_LEFT", 0x219),
    ("KEY_CAMERA_RIGHT", 0x21a),
];

/// The camera key's half-press. Every full press of a two-stage camera key comes after it, so
/// as a trigger it would start a stack before the person has pressed.
const HALF_PRESS: &str = "KEY_CAMERA_FOCUS";

/// The code of the key named `name`, or why it cannot be a trigger.
pub fn code(name: &str) -> Result<u16, String> {
    if name == HALF_PRESS {
        return Err(format!(
            "{HALF_PRESS} is the camera key's half-press, which comes before every full press: \
             use KEY_CAMERA"
        ));
    }
    KEYS.iter()
        .find(|(n, _)| *n == name)
        .map(|(_, c)| *c)
        .ok_or_else(|| {
            let names: Vec<&str> = KEYS.iter().map(|(n, _)| *n).collect();
            format!(
                "{name:?} is not a key focusd knows; one of {}",
                names.join(", ")
            )
        })
}

/// The name of key `code`, for the log.
pub fn name(code: u16) -> String {
    KEYS.iter()
        .find(|(_, c)| *c == code)
        .map_or_else(|| format!("key {code}"), |(n, _)| n.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_give_codes_and_the_half_press_is_refused() {
        assert_eq!(code("KEY_CAMERA"), Ok(212));
        assert_eq!(code("KEY_VOLUMEUP"), Ok(115));
        assert!(code("KEY_CAMERA_FOCUS").unwrap_err().contains("half-press"));
        let e = code("KEY_CAMRA").unwrap_err();
        assert!(e.contains("\"KEY_CAMRA\" is not a key") && e.contains("KEY_VOLUMEUP"));
        assert_eq!(name(212), "KEY_CAMERA");
        assert_eq!(name(1), "key 1");
    }
}
