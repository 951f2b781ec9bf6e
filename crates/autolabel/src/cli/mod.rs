//! Subcommand arguments (clap) and runners for the `pi3det` binary, one file per command.

pub mod bench;
pub mod fuse;
pub mod project;
pub mod track;

use std::path::Path;

use crate::AutolabelError;

pub(crate) fn refuse_existing(out: &Path, overwrite: bool) -> Result<(), AutolabelError> {
    if out.exists() && !overwrite {
        return Err(AutolabelError::invalid(out, "exists; pass --overwrite to replace it"));
    }
    Ok(())
}
