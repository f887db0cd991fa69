//! Outputs are written under a temporary name in the destination directory and renamed
//! into place only when complete, so an interrupted write never leaves a partial file and
//! an existing file is replaced only by a complete one.

use crate::error::{FormatError, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The temporary files being written right now, so that a signal handler can remove them
/// before the process exits (see [`remove_pending`]).
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Registers a temporary file for its lifetime.
struct Pending(PathBuf);

impl Pending {
    fn register(tmp: &Path) -> Pending {
        PENDING.lock().unwrap_or_else(|e| e.into_inner()).push(tmp.to_path_buf());
        Pending(tmp.to_path_buf())
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        let mut pending = PENDING.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = pending.iter().position(|p| *p == self.0) {
            pending.swap_remove(i);
        }
    }
}

/// Removes every temporary file still being written. For a signal handler that is about to
/// exit the process: the lock is kept, so no new temporary file is started (and left behind)
/// before the exit. A write racing with this either renamed its complete file into place
/// first or finds its temporary file gone and fails: never a partial output.
pub fn remove_pending() -> usize {
    let pending = PENDING.lock().unwrap_or_else(|e| e.into_inner());
    let removed = pending.iter().filter(|p| std::fs::remove_file(p).is_ok()).count();
    std::mem::forget(pending);
    removed
}

/// The temporary name used while `path` is being written: `.NAME.PID.tmp` beside it.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = format!(".{name}.{}.tmp", std::process::id());
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.join(tmp),
        _ => PathBuf::from(tmp),
    }
}

/// Calls `write` with a buffered writer on a temporary file, then syncs and renames it to
/// `path`. On any error the temporary file is removed and `path` is left untouched.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<()>,
{
    let tmp = temp_path(path);
    let _pending = Pending::register(&tmp);
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| FormatError::io(path, e))?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        write(&mut w)?;
        let file = w.into_inner().map_err(|e| FormatError::io(path, e.into_error()))?;
        file.sync_all().map_err(|e| FormatError::io(path, e))?;
        hold_for_interruption_test();
        std::fs::rename(&tmp, path).map_err(|e| FormatError::io(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// For outputs another program writes (ffmpeg): `write` is given the temporary path to
/// write, which is renamed to `path` when it returns Ok, removed otherwise — and removed
/// by the signal handler if the process is interrupted meanwhile.
pub fn write_via_temp_path<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&Path) -> Result<()>,
{
    let tmp = temp_path(path);
    let _pending = Pending::register(&tmp);
    let result = write(&tmp).and_then(|()| std::fs::rename(&tmp, path).map_err(|e| FormatError::io(path, e)));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Convenience for writers that produce the whole file in memory first.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |w| w.write_all(bytes).map_err(|e| FormatError::io(path, e)))
}

/// `VOLTERRA_TEST_HOLD_TEMP_MS`: keeps the finished temporary file this long before the
/// rename, so that tests/interrupt.rs can signal the process while an output is being written
/// (a window of microseconds otherwise). Unset in normal use.
fn hold_for_interruption_test() {
    if let Some(ms) = std::env::var("VOLTERRA_TEST_HOLD_TEMP_MS").ok().and_then(|v| v.parse::<u64>().ok()) {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}
