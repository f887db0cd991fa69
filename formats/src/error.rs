//! One error type for every reader and writer: it always names the file and the problem,
//! so the CLI can print it as a single line.

use std::fmt;
use std::path::{Path, PathBuf};

#[derive(Debug)]
pub struct FormatError {
    pub path: PathBuf,
    pub kind: ErrorKind,
    pub message: String,
}

/// Broad classes of failure, so callers (and tests) can tell bad input from missing files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// The file could not be opened, read or written.
    Io,
    /// The file is malformed, truncated or contradicts itself.
    Invalid,
    /// The file is well-formed but uses a feature we do not read.
    Unsupported,
    /// The file declares more data than the memory limit allows.
    TooLarge,
    /// The request is ambiguous (e.g. a directory holding several DICOM series).
    Ambiguous,
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.message)
    }
}

impl std::error::Error for FormatError {}

impl FormatError {
    pub fn new(path: impl AsRef<Path>, kind: ErrorKind, message: impl Into<String>) -> Self {
        FormatError { path: path.as_ref().to_path_buf(), kind, message: one_line(message.into()) }
    }
    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::new(path, ErrorKind::Invalid, message)
    }
    pub fn unsupported(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::new(path, ErrorKind::Unsupported, message)
    }
    pub fn io(path: impl AsRef<Path>, err: std::io::Error) -> Self {
        Self::new(path, ErrorKind::Io, io_reason(&err))
    }
}

/// What an I/O error says, in the words our errors use.
pub fn io_reason(err: &std::io::Error) -> String {
    match err.kind() {
        std::io::ErrorKind::NotFound => "no such file".to_string(),
        std::io::ErrorKind::UnexpectedEof => "file is truncated".to_string(),
        _ => err.to_string(),
    }
}

pub type Result<T> = std::result::Result<T, FormatError>;

/// Messages quote what a file holds (names, types, values); a hostile file can put line
/// breaks and megabytes there. Control characters are escaped and the message is cut at
/// `MAX_MESSAGE` characters, so an error stays one readable line.
fn one_line(message: String) -> String {
    const MAX_MESSAGE: usize = 300;
    if message.len() <= MAX_MESSAGE && !message.chars().any(char::is_control) {
        return message;
    }
    let mut out = String::with_capacity(MAX_MESSAGE + 8);
    let mut n = 0;
    for c in message.chars() {
        if n >= MAX_MESSAGE {
            out.push('…');
            break;
        }
        if c.is_control() {
            for e in c.escape_default() {
                out.push(e);
                n += 1;
            }
        } else {
            out.push(c);
            n += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn messages_are_one_bounded_line() {
        let e = super::FormatError::invalid("f.vtp", format!("type '{}'", "A\nB".repeat(500)));
        assert!(!e.to_string().contains('\n'));
        assert!(e.message.chars().count() <= 310);
        assert!(e.message.starts_with("type 'A\\nB"));
    }
}
