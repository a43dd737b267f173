//! A terminal progress bar for the engine's `Progress`; draws nothing when stderr is not a terminal.

use focusd::stack::{Progress, Stage};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;

pub struct Bar(ProgressBar);

impl Bar {
    pub fn stderr() -> Self {
        let target = if std::io::stderr().is_terminal() {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        };
        let bar = ProgressBar::with_draw_target(Some(0), target);
        bar.set_style(
            ProgressStyle::with_template("{msg:>8} [{bar:30}] {pos}/{len} {elapsed}")
                .expect("static template")
                .progress_chars("=> "),
        );
        Self(bar)
    }

    /// `done` of `total` steps of `stage`, as the daemon's Progress signals report them.
    pub fn show(&self, stage: &str, done: u64, total: u64) {
        self.0.set_length(total);
        self.0.set_position(done);
        self.0.set_message(stage.to_string());
    }

    pub fn finish(&self) {
        self.0.finish_and_clear();
    }
}

impl Progress for Bar {
    fn stage(&self, stage: Stage, total: usize) {
        focusd::base::malloc::release_freed_memory();
        self.0.set_message(stage.name());
        self.0.set_length(total as u64);
        self.0.set_position(0);
    }

    fn advance(&self, steps: usize) {
        self.0.inc(steps as u64);
    }
}
