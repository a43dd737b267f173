//! Local registration per frame on layered hand-held stacks of several sizes, for tuning it: the
//! RMS displacement error where each frame is sharp with the affine alone and with the local
//! field, and whether the frame kept a field.
//!
//! `local_fields` (no arguments): `cargo run --release --example local_fields`.

// The measurement the register tests assert on, shared with them.
#[path = "../../tests/common/parallax.rs"]
mod parallax;

use focusd::sim::SimParams;
use parallax::{layered, local_effect};

fn main() {
    for (w, h, planes) in [(480, 360, 8), (640, 480, 8), (640, 480, 6)] {
        let p = SimParams {
            width: w,
            height: h,
            planes,
            ..layered(23, 6.0)
        };
        for (i, with, without, kept) in local_effect(&p) {
            println!(
                "{w}x{h}x{planes} frame {i}: {without:.2} px affine, {with:.2} px local ({kept})"
            );
        }
    }
}
