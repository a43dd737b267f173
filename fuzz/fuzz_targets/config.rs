//! The configuration file, reread on SIGHUP from wherever the admin put it.
#![no_main]

use focusd::service::config::Config;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Err((Some(line), _)) = Config::parse(text) {
        assert!(line >= 1 && line <= text.lines().count().max(1) + 1);
    }
});
