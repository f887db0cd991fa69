//! What a child process (sbatch, ffmpeg, a reference script, another volterra) said when
//! it failed, as one line for our own error message.

/// The first non-empty line of `stderr`: tools such as sbatch and ffmpeg say why first.
pub fn first_line(stderr: &[u8]) -> String {
    String::from_utf8_lossy(stderr).lines().map(str::trim).find(|l| !l.is_empty()).unwrap_or("no message").to_string()
}

/// The last non-empty line of `stderr`: a Python traceback or our own error ends with why.
pub fn last_line(stderr: &[u8]) -> String {
    String::from_utf8_lossy(stderr).lines().map(str::trim).rev().find(|l| !l.is_empty()).unwrap_or("no message").to_string()
}
