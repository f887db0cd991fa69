//! How much a command says on stderr, set once by the global `-q/--quiet` and
//! `-v/--verbose` flags, as GDAL's and ripgrep's tools do: quiet leaves warnings and errors
//! only (no progress, no "wrote …", no statistics); verbose adds every animation frame's
//! statistics and a closing line with the command's time and peak memory. What a command
//! prints on stdout (tables, JSON) is its output and never changes with these.

use std::sync::atomic::{AtomicI8, Ordering};

static LEVEL: AtomicI8 = AtomicI8::new(0);

/// Sets the level from the flags (clap makes them exclusive).
pub fn set(quiet: bool, verbose: bool) {
    LEVEL.store(if quiet { -1 } else { i8::from(verbose) }, Ordering::Relaxed);
}

/// `-q`: warnings and errors only.
pub fn quiet() -> bool {
    LEVEL.load(Ordering::Relaxed) < 0
}

/// `-v`: more than by default.
pub fn verbose() -> bool {
    LEVEL.load(Ordering::Relaxed) > 0
}

/// An informational line on stderr, left out under `-q` (warnings and errors use
/// `eprintln!`).
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {
        if !$crate::verbosity::quiet() {
            eprintln!($($arg)*);
        }
    };
}
