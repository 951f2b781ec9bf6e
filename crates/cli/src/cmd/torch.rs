//! The detector commands ([`FORWARDED`]) run in a separate executable, `pi3det-torch`
//! (crates/cli-torch), the only one that links libtorch: `pi3det` itself never loads it, so the
//! other commands start in milliseconds. `pi3det` lists these commands in its help and hands
//! each over with its arguments verbatim (on Unix by `exec`, so the exit status, signals and
//! terminal are the child's own).
//!
//! `pi3det-torch` is looked for in `$PI3DET_TORCH` (a path), then beside this executable, then
//! on `PATH`.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

/// The executable's file name.
pub const EXE: &str = "pi3det-torch";

/// A command that runs in `pi3det-torch`: its arguments, unparsed (`pi3det <command> --help`
/// shows its options).
#[derive(clap::Args, Debug)]
#[command(disable_help_flag = true)]
pub struct Forwarded {
    /// Arguments for the command (see `pi3det <command> --help`).
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, num_args = 0.., value_name = "ARGS")]
    pub args: Vec<OsString>,
}

/// The first `n` words of `args` (without the program name) that are neither flags nor the
/// value of the global `--threads`: the command and its subcommands.
fn command_words(args: &[OsString], n: usize) -> Vec<&str> {
    let mut words = Vec::new();
    let mut it = args.iter().map(|a| a.to_str().unwrap_or(""));
    while let Some(a) = it.next() {
        if a == "--threads" {
            it.next();
        } else if !a.starts_with('-') {
            words.push(a);
        }
        if words.len() == n {
            break;
        }
    }
    words
}

/// The commands `pi3det-torch` runs, as the words that name them. The one list: dispatch, help
/// and the error for a missing `pi3det-torch` use it, and a test checks it against both
/// executables' help.
pub const FORWARDED: &[&str] = &[
    "train",
    "detect",
    "adapt",
    "autolabel",
    "run",
    "export",
    "demo",
    "bench suite",
    // The old name of `bench suite` (hidden).
    "benchmark",
    "bench nn",
    "bench live",
    "bench sparse",
    "bench real",
];

/// The forwarded command that `words` (a command line's command words) start with, if any.
fn forwarded_in(words: &[&str]) -> Option<&'static str> {
    FORWARDED.iter().copied().find(|c| words.starts_with(&c.split(' ').collect::<Vec<_>>()))
}

/// The forwarded command `args` (without the program name) run, if any.
pub fn forwarded(args: &[OsString]) -> Option<&'static str> {
    forwarded_in(&command_words(args, 2))
}

/// Whether `args` (without the program name) ask for `help` of a detector command, e.g.
/// `pi3det help train` or `pi3det --threads 2 help bench nn`: that help lives in pi3det-torch.
pub fn is_help_for_forwarded(args: &[OsString]) -> bool {
    match command_words(args, 3).as_slice() {
        ["help", rest @ ..] => forwarded_in(rest).is_some(),
        _ => false,
    }
}

/// Whether `args` run a command that trains a network (`train`, `adapt`, `demo`, `bench suite`,
/// `bench nn`). For these `pi3det` sets `OMP_WAIT_POLICY=ACTIVE` unless the user set it: a
/// backward pass is many short OpenMP regions, and workers that spin between them instead of
/// sleeping make a training step faster; inference gains nothing, and a live `run` would burn a
/// core while it waits for frames, so the others keep libgomp's default
/// (results/2026-12-05-omp-wait-policy.md). It has to be set before libtorch loads, hence here
/// and not in `pi3det-torch`.
pub fn trains(args: &[OsString]) -> bool {
    matches!(
        command_words(args, 2).as_slice(),
        ["train" | "adapt" | "demo" | "benchmark", ..] | ["bench", "nn" | "suite", ..]
    )
}

/// Whether `args` run the detector beside other work on a robot computer (`run`, `bench live`).
/// For these `pi3det` sets `OMP_WAIT_POLICY=PASSIVE` unless the user set it: a spinning wait
/// takes a core from the neighbours, and a thread a neighbour has preempted stalls every layer
/// its siblings spin at (results/2026-12-06-live-threads.md).
pub fn runs_live(args: &[OsString]) -> bool {
    matches!(forwarded(args), Some("run" | "bench live"))
}

fn is_file(p: &Path) -> bool {
    p.metadata().is_ok_and(|m| m.is_file())
}

/// Where `pi3det-torch` is: `$PI3DET_TORCH`, beside this executable, on `PATH`.
pub fn locate() -> anyhow::Result<PathBuf> {
    if let Some(p) = std::env::var_os("PI3DET_TORCH").filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        if !is_file(&p) {
            bail!("PI3DET_TORCH={} is not a file", p.display());
        }
        return Ok(p);
    }
    let exe = std::env::current_exe().ok();
    let beside = exe.as_deref().and_then(Path::parent).map(|d| d.join(EXE));
    if let Some(p) = beside.as_ref().filter(|p| is_file(p)) {
        return Ok(p.clone());
    }
    if let Some(path) = std::env::var_os("PATH") {
        if let Some(p) = std::env::split_paths(&path).map(|d| d.join(EXE)).find(|p| is_file(p)) {
            return Ok(p);
        }
    }
    bail!(
        "the detector commands ({}) run in the {EXE} executable, which is neither beside {} nor on PATH; \
         build it with `cargo build --release -p pi3det-cli-torch` (scripts/demo builds both binaries; it needs libtorch, see scripts/setup-torch), \
         or set PI3DET_TORCH to its path",
        FORWARDED.join(", "),
        exe.as_deref().map_or_else(|| "this executable".into(), |e| e.display().to_string())
    )
}

/// Runs `pi3det-torch` with `args` (this process's arguments without the program name) and
/// returns its exit status; on Unix the process is replaced and this returns only on failure.
pub fn run(args: &[OsString]) -> anyhow::Result<std::process::ExitCode> {
    let exe = locate()?;
    let mut cmd = std::process::Command::new(&exe);
    cmd.args(args);
    if std::env::var_os("OMP_WAIT_POLICY").is_none() {
        if trains(args) {
            cmd.env("OMP_WAIT_POLICY", "ACTIVE");
        } else if runs_live(args) {
            cmd.env("OMP_WAIT_POLICY", "PASSIVE");
        }
    }
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        // Its help and errors then name `pi3det`, the command the user typed.
        let err = cmd.arg0("pi3det").exec();
        Err(err).with_context(|| format!("running {}", exe.display()))
    }
    #[cfg(not(unix))]
    {
        let status = cmd.status().with_context(|| format!("running {}", exe.display()))?;
        Ok(std::process::ExitCode::from(status.code().map_or(1, |c| c.clamp(0, 255) as u8)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(args: &[&str]) -> Vec<OsString> {
        args.iter().map(OsString::from).collect()
    }

    #[test]
    fn help_for_forwarded_commands() {
        assert!(is_help_for_forwarded(&v(&["help", "train"])));
        assert!(is_help_for_forwarded(&v(&["--threads", "2", "help", "bench", "nn"])));
        assert!(!is_help_for_forwarded(&v(&["help", "bench", "sim"])));
        assert!(!is_help_for_forwarded(&v(&["help", "eval"])));
        assert!(!is_help_for_forwarded(&v(&["help"])));
        assert!(!is_help_for_forwarded(&v(&["train", "--help"])), "not `help`: clap dispatches that");
    }

    #[test]
    fn forwarded_commands() {
        assert_eq!(forwarded(&v(&["--threads", "2", "bench", "live", "--load", "1"])), Some("bench live"));
        assert_eq!(forwarded(&v(&["train", "--config", "c.toml"])), Some("train"));
        assert_eq!(forwarded(&v(&["bench", "sim"])), None);
        assert_eq!(forwarded(&v(&["bench"])), None);
        assert_eq!(forwarded(&v(&["info", "train"])), None, "only the leading words name the command");
        assert_eq!(forwarded(&v(&["--help"])), None);
        // Every training command is a forwarded one.
        for t in [&["train"][..], &["adapt"], &["demo"], &["benchmark"], &["bench", "suite"], &["bench", "nn"]] {
            assert!(trains(&v(t)) && forwarded(&v(t)).is_some(), "{t:?}");
        }
    }

    #[test]
    fn training_commands() {
        assert!(trains(&v(&["train", "--config", "c.toml"])));
        assert!(trains(&v(&["--threads", "2", "demo"])));
        assert!(trains(&v(&["bench", "nn", "--no-torch"])));
        assert!(!trains(&v(&["bench", "live"])));
        assert!(!trains(&v(&["run", "--ckpt", "m.safetensors"])));
        assert!(!trains(&v(&["detect"])));
        assert!(!trains(&v(&["help", "train"])));
        assert!(runs_live(&v(&["run", "--ckpt", "m.safetensors"])) && runs_live(&v(&["bench", "live"])));
        assert!(!runs_live(&v(&["detect"])) && !runs_live(&v(&["bench", "nn"])));
    }
}
