//! Subcommand arguments (clap) and runners for the `pi3det` binary, one file per command.

pub mod project;
