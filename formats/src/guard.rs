//! A net under third-party decoders: a panic inside one (found by fuzzing: dicom-rs's RLE
//! decoder indexes past a corrupt segment) becomes a one-line error naming the file, instead
//! of a crash. Our own code is not run under it — a panic there is a bug to fix, and the
//! fuzz targets must see it.

use crate::error::{FormatError, Result};
use std::cell::Cell;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::sync::Once;

thread_local! {
    /// How many guarded calls this thread is inside: their panics are caught and reported as
    /// errors, so the panic hook stays quiet for them.
    static GUARDED: Cell<u32> = const { Cell::new(0) };
}

fn install_quiet_hook() {
    static INSTALL: Once = Once::new();
    INSTALL.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if GUARDED.with(Cell::get) == 0 {
                previous(info);
            }
        }));
    });
}

/// Runs `decode` (a call into a third-party decoder); a panic in it becomes
/// "`what` failed on malformed data (the panic message)".
pub fn third_party<T>(path: &Path, what: &str, decode: impl FnOnce() -> Result<T>) -> Result<T> {
    install_quiet_hook();
    GUARDED.with(|g| g.set(g.get() + 1));
    let outcome = catch_unwind(AssertUnwindSafe(decode));
    GUARDED.with(|g| g.set(g.get() - 1));
    outcome.unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".to_string());
        Err(FormatError::invalid(path, format!("{what} failed on malformed data ({message})")))
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_panic_in_a_decoder_becomes_an_error() {
        let r: super::Result<()> = super::third_party(std::path::Path::new("x.dcm"), "RLE decoder", || panic!("index 7 out of range"));
        assert_eq!(r.unwrap_err().to_string(), "x.dcm: RLE decoder failed on malformed data (index 7 out of range)");
        assert_eq!(super::third_party(std::path::Path::new("x"), "d", || Ok(3)).unwrap(), 3);
    }
}
