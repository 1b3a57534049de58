//! Untrusted input quoted in messages: short enough to read, never as long as the input.
//!
//! Used by every layer that names something a file or a client supplied (a channel, a part,
//! a session id, a filter name) in an error.

use std::borrow::Cow;

/// Longest piece of untrusted input echoed in a message; longer input is cut and its length
/// said instead.
pub const ECHO_CHARS: usize = 64;

/// Untrusted input as it may appear in a message: at most [`ECHO_CHARS`] characters, with
/// the full length said when it was cut.
pub fn clip(input: &str) -> Cow<'_, str> {
    match input.char_indices().nth(ECHO_CHARS) {
        None => Cow::Borrowed(input),
        Some((at, _)) => Cow::Owned(format!("{}... ({} bytes)", &input[..at], input.len())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clip_keeps_short_input_and_cuts_long_input_on_a_character() {
        assert_eq!(clip("taa"), "taa");
        let long = "é".repeat(100);
        let c = clip(&long);
        assert!(c.starts_with(&"é".repeat(ECHO_CHARS)), "{c}");
        assert!(c.ends_with("(200 bytes)"), "{c}");
    }
}
