//! An error kept to be returned again (a node's data that failed to load, an adapter
//! that could not be opened): shared, with its whole chain of causes, so callers can still
//! print every context and find the root cause's kind (`root_cause().downcast_ref`).

use std::sync::Arc;

#[derive(Debug, Clone)]
pub struct SharedError(pub Arc<anyhow::Error>);

impl SharedError {
    pub fn new(e: anyhow::Error) -> SharedError {
        SharedError(Arc::new(e))
    }
}

impl std::fmt::Display for SharedError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The outermost message; the causes follow through `source`.
        std::fmt::Display::fmt(&**self.0, f)
    }
}

impl std::error::Error for SharedError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.0.source()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shared_error_keeps_its_chain_and_its_root_cause() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = SharedError::new(anyhow::Error::new(io).context("reading v.nii"));
        let again = anyhow::Error::new(e.clone());
        assert_eq!(format!("{again:#}"), "reading v.nii: no such file");
        assert_eq!(again.root_cause().downcast_ref::<std::io::Error>().map(|e| e.kind()), Some(std::io::ErrorKind::NotFound));
    }
}
