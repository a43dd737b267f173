//! Ctrl-C, SIGTERM and SIGHUP for the commands that write files: their temporary outputs are
//! removed before the process exits as the signal asks (128 + its number), so an interrupted
//! run leaves nothing behind. Outputs being renamed into place finish first.

use anyhow::{Context, Result};
use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
use signal_hook::iterator::Signals;

pub fn clean_up_on_interrupt() -> Result<()> {
    let mut signals =
        Signals::new([SIGINT, SIGTERM, SIGHUP]).context("installing the signal handlers")?;
    std::thread::Builder::new()
        .name("focusd-signals".into())
        .spawn(move || {
            if let Some(sig) = signals.forever().next() {
                focusd::files::abandon();
                let name = match sig {
                    SIGINT => "SIGINT",
                    SIGTERM => "SIGTERM",
                    _ => "SIGHUP",
                };
                eprintln!("focusd: stopped by {name}; temporary files removed");
                std::process::exit(128 + sig);
            }
        })
        .context("starting the signal thread")?;
    Ok(())
}
