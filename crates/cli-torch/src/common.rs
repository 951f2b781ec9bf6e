//! What the detector commands share: progress bars, and refusing to overwrite an earlier run.

use std::path::Path;

use indicatif::ProgressStyle;

use pi3det_nn::error::{NnError, Result};

/// A progress-bar style from an indicatif template (the default style if the template is bad).
pub fn progress_style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar())
}

/// Errors when `dir` already holds a file an earlier run wrote (`is_output` on its name); a
/// missing `dir` holds none.
pub fn refuse_existing(dir: &Path, is_output: impl Fn(&str) -> bool) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    match entries.flatten().map(|e| e.path()).find(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(&is_output)) {
        Some(p) => Err(NnError::Input(format!(
            "{} already exists (an earlier run's output); pass --overwrite to replace it",
            p.display()
        ))),
        None => Ok(()),
    }
}
