//! A replay bundle's `bundle.toml` and `imu.csv`, which may come from another machine.
#![no_main]

use focusd::backend::replay::bundle::{parse_imu, parse_manifest};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(samples) = parse_imu(data) {
        assert!(samples.windows(2).all(|w| w[0].t <= w[1].t));
        assert!(samples.iter().all(|s| s.v.iter().all(|v| v.is_finite())));
    }
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(m) = parse_manifest(text) {
        assert!(!m.takes.is_empty());
    }
});
