//! What the kernel test harnesses (vivid, vimc, keys) share: the check macro, the `ok:` lines and
//! the result marker their qemu runners (run-vivid, run-vimc, run-keys) look for.

pub type Check = Result<(), String>;

/// Fails the check with the message unless the condition holds.
macro_rules! ensure {
    ($cond:expr, $($fmt:tt)+) => {
        let holds: bool = $cond;
        if !holds {
            return Err(format!($($fmt)+));
        }
    };
}

pub fn ok(what: impl AsRef<str>) {
    println!("ok: {}", what.as_ref());
}

/// Runs the checks (a panic is a failure too), prints `FAIL: ...` and `<SUITE>-RESULT: PASS`
/// or `FAIL`, and exits 1 on failure.
pub fn report(suite: &str, checks: impl FnOnce() -> Check + std::panic::UnwindSafe) {
    let result = std::panic::catch_unwind(checks).unwrap_or_else(|p| {
        let msg = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        Err(format!("panicked: {msg}"))
    });
    match result {
        Ok(()) => println!("{suite}-RESULT: PASS"),
        Err(e) => {
            println!("FAIL: {e}");
            println!("{suite}-RESULT: FAIL");
            std::process::exit(1);
        }
    }
}
