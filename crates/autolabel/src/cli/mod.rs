//! Subcommand arguments (clap) and runners for the `pi3det` binary, one file per command.

pub mod bench;
pub mod fuse;
pub mod project;
pub mod track;

use std::path::Path;

use crate::AutolabelError;

/// The configuration in `path` (read by `load`), else the defaults; with `print` it is printed as
/// TOML instead and `None` returned (`--print-config`).
pub(crate) fn config_or_print<T: Default + serde::Serialize>(
    path: Option<&Path>,
    load: fn(&Path) -> Result<T, AutolabelError>,
    print: bool,
) -> Result<Option<T>, AutolabelError> {
    let cfg = match path {
        Some(p) => load(p)?,
        None => T::default(),
    };
    if print {
        print!("{}", toml::to_string_pretty(&cfg).map_err(|e| AutolabelError::Config(e.to_string()))?);
        return Ok(None);
    }
    Ok(Some(cfg))
}

pub(crate) fn refuse_existing(out: &Path, overwrite: bool) -> Result<(), AutolabelError> {
    if out.exists() && !overwrite {
        return Err(AutolabelError::invalid(out, "exists; pass --overwrite to replace it"));
    }
    Ok(())
}
