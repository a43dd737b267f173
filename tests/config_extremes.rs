//! Every numeric key of the shipped config (config/focusd.toml, commented-out keys included) at
//! the extremes a careless or hostile file can hold: each is either refused with the key's line
//! (and its name, when the value parses but is out of range), or carried through a whole replay capture without a panic. The ranges come from the
//! validation's own messages ("is out of range LO..=HI"), so a key added later is covered
//! without touching this test, and both ends of each range must then be accepted (unless another
//! key's value rules one out).

use focusd::capture::sweep::Unmonitored;
use focusd::service::config::Config;
use focusd::service::job::{self, Rig, Source};
use focusd::stack::NoProgress;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A numeric key as the shipped file spells it.
struct Key {
    table: String,
    name: String,
    /// 0-based line of the key in the shipped file.
    line: usize,
    float: bool,
}

fn numeric_keys(text: &str) -> Vec<Key> {
    let mut table = String::new();
    let mut keys = Vec::new();
    for (line, raw) in text.lines().enumerate() {
        let l = raw.trim();
        if let Some(t) = l.strip_prefix('[').and_then(|t| t.strip_suffix(']')) {
            table = t.to_string();
            continue;
        }
        let l = l.strip_prefix("# ").unwrap_or(l);
        let Some((name, value)) = l.split_once(" = ") else {
            continue;
        };
        let plain = |c: char| c.is_ascii_lowercase() || c == '_';
        if name.chars().all(plain) && value.parse::<f64>().is_ok() {
            keys.push(Key {
                table: table.clone(),
                name: name.to_string(),
                line,
                float: value.contains(['.', 'e']),
            });
        }
    }
    keys
}

/// The shipped file with `key` set to `value` on its own line.
fn with_value(text: &str, key: &Key, value: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[key.line] = format!("{} = {value}", key.name);
    lines.join("\n") + "\n"
}

/// `LO..=HI` of an "is out of range LO..=HI" message.
fn range_in(message: &str) -> Option<(String, String)> {
    let r = message.split("is out of range ").nth(1)?;
    let (lo, hi) = r.split_once("..=")?;
    let hi = hi
        .split_whitespace()
        .next()?
        .trim_end_matches([',', ';', ')']);
    Some((lo.to_string(), hi.to_string()))
}

/// A whole replay capture of `bundle` with `config`: Ok or an error, never a panic.
fn capture(config: &Config, bundle: &Path, out: &Path) -> Result<(), String> {
    let source = Source::Replay {
        dir: bundle.to_path_buf(),
        paced: false,
        faults: Vec::new(),
    };
    let mut rig = Rig::open(config, &source).map_err(|e| format!("{e:#}"))?;
    job::run(
        &mut rig,
        &config.fuse,
        out,
        None,
        false,
        &Unmonitored,
        &NoProgress,
    )
    .map(|_| ())
    .map_err(|e| format!("{e:#}"))
}

#[test]
fn every_numeric_key_is_refused_by_name_or_carried_through_a_capture() {
    let shipped =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/focusd.toml"))
            .unwrap();
    let keys = numeric_keys(&shipped);
    assert!(keys.len() >= 20, "only {} numeric keys found", keys.len());

    let dir = tempfile::tempdir().unwrap();
    let bundle: PathBuf = dir.path().join("bundle");
    let sim = Command::new(env!("CARGO_BIN_EXE_focusd"))
        .args([
            "simulate", "--bundle", "--width", "320", "--height", "240", "-o",
        ])
        .arg(&bundle)
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );

    let extremes: &[&str] = &[
        "-9223372036854775808",
        "-1",
        "0",
        "9223372036854775807",
        "-1e300",
        "1e-300",
        "1e300",
        "nan",
        "inf",
    ];
    let mut ranged = 0;
    // Captures run, and those that went through to a picture: a stack the sweep or the
    // registration refuses for every value would test nothing downstream.
    let (mut runs, mut captured) = (0, 0);
    for key in &keys {
        // Each value accepted, with the config it made.
        let mut accepted: Vec<(String, Config)> = Vec::new();
        let mut range = None;
        for v in extremes
            .iter()
            .filter(|v| key.float || v.parse::<i64>().is_ok())
        {
            match Config::parse(&with_value(&shipped, key, v)) {
                Ok(config) => accepted.push((v.to_string(), config)),
                Err((line, message)) => {
                    // A value of the wrong type or size is refused by the parser, which names the
                    // line; a value out of range by the validation, which names the key too.
                    assert!(
                        line == Some(key.line + 1)
                            && (message.contains(&key.name) || message.starts_with("invalid")),
                        "[{}] {} = {v}: the error names line {line:?} and says {message:?}",
                        key.table,
                        key.name
                    );
                    range = range.or_else(|| range_in(&message));
                }
            }
        }
        if let Some((lo, hi)) = range {
            ranged += 1;
            // Each end is accepted, unless another key's value rules it out (drop_frames must
            // be at least buffers, still_timeout_ms at least still_ms), not by its own range.
            for end in [lo, hi] {
                match Config::parse(&with_value(&shipped, key, &end)) {
                    Ok(config) => accepted.push((end, config)),
                    Err((_, m)) => assert!(
                        !m.contains(&format!("{} = {end} is out of range", key.name)),
                        "[{}] {} = {end}, an end of its own range, is refused: {m}",
                        key.table,
                        key.name
                    ),
                }
            }
        }
        // The camera's and the IMU's settings reach only the device backends, which a replay
        // does not open; the rest run through the sweep, the gate, the fuse and the writer.
        if key.table == "camera" || key.table == "imu" {
            continue;
        }
        for (v, config) in accepted {
            let out = dir.path().join("out.jpg");
            let run = std::panic::catch_unwind(|| capture(&config, &bundle, &out));
            captured += usize::from(matches!(run, Ok(Ok(()))));
            runs += 1;
            assert!(
                run.is_ok(),
                "[{}] {} = {v} was accepted and then panicked the capture",
                key.table,
                key.name
            );
        }
    }
    assert!(
        ranged * 2 >= keys.len(),
        "ranges found for only {ranged} of {} keys",
        keys.len()
    );
    assert!(
        captured * 4 >= runs * 3,
        "only {captured} of {runs} captures made a picture"
    );
}
