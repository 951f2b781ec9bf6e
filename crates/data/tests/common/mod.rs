//! Shared helpers for the data tests: where the real frames live.

use std::path::PathBuf;

/// `../shared/data` beside the repository. Tests that need it fail loudly when it is missing.
#[allow(dead_code)]
pub fn shared_data(rel: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "real test data missing: {} (expected ../shared/data beside the repo)", p.display());
    p
}
