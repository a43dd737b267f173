//! Error messages cut to a sane length before they reach a terminal, the journal or the bus.
//!
//! A message names the files and values it is about, and those come from callers: a path of
//! megabytes would make a Failed signal too big to send (so `trigger --wait` never hears the end)
//! and bury the log. The start of a message says what went wrong; its length is capped.

/// Bytes of a message kept.
pub const MAX_MESSAGE_BYTES: usize = 4096;

/// `message`, cut at a character boundary to at most [`MAX_MESSAGE_BYTES`] bytes with a note of
/// how much was left out.
pub fn clip(message: &str) -> String {
    if message.len() <= MAX_MESSAGE_BYTES {
        return message.to_string();
    }
    let mut end = MAX_MESSAGE_BYTES - 64;
    while !message.is_char_boundary(end) {
        end -= 1;
    }
    format!(
        "{}… ({} more bytes cut)",
        &message[..end],
        message.len() - end
    )
}

/// An error and its causes, `: `-joined as `focusd: error:` prints them: what a user reads.
pub fn chain(error: &dyn std::error::Error) -> String {
    let mut out = error.to_string();
    let mut cause = error.source();
    while let Some(e) = cause {
        out.push_str(": ");
        out.push_str(&e.to_string());
        cause = e.source();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_messages_pass_and_long_ones_are_cut_at_a_character() {
        assert_eq!(clip("no such file"), "no such file");
        let long = "é".repeat(1_000_000);
        let c = clip(&long);
        assert!(c.len() <= MAX_MESSAGE_BYTES, "{}", c.len());
        assert!(c.starts_with("éé") && c.ends_with("more bytes cut)"), "{c}");
    }
}
