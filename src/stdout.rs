//! The commands' answers on standard output, written so that a failure comes back as an error:
//! `println!` panicked (exit 101 and a backtrace) on a full disk (`> /dev/full`) or a reader
//! that went away (`| head -c 10`).

use std::fmt::Display;
use std::io::Write;

/// Writing a command's answer to standard output failed.
#[derive(Debug, thiserror::Error)]
#[error("cannot write to standard output: {source}; check where it is redirected (a full disk?)")]
pub struct StdoutError {
    #[source]
    source: std::io::Error,
}

impl StdoutError {
    /// The reader closed its end (`isostream measure --json | head -c 10`): the usual CLI
    /// convention is to stop quietly, with nobody left to read an error line meant for it.
    pub fn is_closed_pipe(&self) -> bool {
        self.source.kind() == std::io::ErrorKind::BrokenPipe
    }
}

/// Writes `text` and a newline to stdout and flushes it.
pub fn line(text: impl Display) -> Result<(), StdoutError> {
    text_as_is(format_args!("{text}\n"))
}

/// Writes `text` to stdout as it is (it ends with its own newline) and flushes it.
pub fn text_as_is(text: impl Display) -> Result<(), StdoutError> {
    let mut out = std::io::stdout().lock();
    write!(out, "{text}")
        .and_then(|()| out.flush())
        .map_err(|source| StdoutError { source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_broken_pipe_is_a_closed_pipe() {
        let closed = StdoutError {
            source: std::io::ErrorKind::BrokenPipe.into(),
        };
        assert!(closed.is_closed_pipe());
        let full = StdoutError {
            source: std::io::Error::from_raw_os_error(28),
        };
        assert!(!full.is_closed_pipe());
        assert!(
            full.to_string()
                .starts_with("cannot write to standard output: No space left on device"),
            "{full}"
        );
    }
}
