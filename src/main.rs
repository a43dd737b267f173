mod cli;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[global_allocator]
static ALLOCATOR: focusd::base::malloc::HugePages = focusd::base::malloc::HugePages;

/// Hand-held focus stacking for Linux phones.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Sweep the focus (or replay a recorded sweep), reshoot shaken frames, register and fuse.
    Capture(cli::capture::CaptureArgs),
    /// Sweep (or replay) and write every take and the IMU trace as a replay bundle.
    Record(cli::capture::RecordArgs),
    /// Run the D-Bus service that captures on request.
    Serve(cli::serve::ServeArgs),
    /// Ask the service for a capture (the one-button client).
    Trigger(cli::serve::TriggerArgs),
    /// Check a configuration file: unknown keys and bad values name the line.
    CheckConfig(cli::CheckConfigArgs),
    /// Fuse a focus stack into one all-in-focus image.
    Fuse(cli::fuse::FuseArgs),
    /// Render a synthetic focus stack with ground truth (frames, truth, depth, transforms).
    Simulate(cli::simulate::SimulateArgs),
}

fn main() -> ExitCode {
    focusd::base::malloc::tune();
    let args = Args::parse();
    let writes_files = matches!(
        args.command,
        Command::Capture(_) | Command::Record(_) | Command::Fuse(_) | Command::Simulate(_)
    );
    let result = if writes_files {
        cli::interrupt::clean_up_on_interrupt()
    } else {
        Ok(())
    };
    let result = result.and_then(|()| match &args.command {
        Command::Capture(a) => cli::capture::run(a),
        Command::Record(a) => cli::capture::record(a),
        Command::CheckConfig(a) => cli::check_config(a),
        Command::Serve(a) => cli::serve::serve(a),
        Command::Trigger(a) => cli::serve::trigger(a),
        Command::Fuse(a) => cli::fuse::run(a),
        Command::Simulate(a) => cli::simulate::run(a),
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!(
                "focusd: error: {}",
                focusd::base::clip::clip(&format!("{e:#}"))
            );
            ExitCode::FAILURE
        }
    }
}
