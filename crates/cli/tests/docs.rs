//! The documentation that is generated or mirrors the code stays current:
//! - `docs/cli.md` is `pi3det --help` and every command's `--help` (the detector commands from
//!   `pi3det-torch`, when it is built beside `pi3det` as `cargo test --workspace` does).
//!   Regenerate with `PI3DET_UPDATE_DOCS=1 cargo test --workspace --test docs`.
//! - ARCHITECTURE.md's crate map names exactly the workspace's packages (`cargo metadata`).

mod common;

use common::commands;
use std::path::{Path, PathBuf};
use std::process::Command;

const PI3DET: &str = env!("CARGO_BIN_EXE_pi3det");

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn help(words: &[&str]) -> String {
    let out = Command::new(PI3DET).args(words).arg("--help").env_remove("PI3DET_TORCH").output().unwrap();
    assert!(out.status.success(), "pi3det {words:?} --help: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn cli_markdown() -> String {
    let mut md = String::from(
        "# Command-line reference\n\n\
         Generated from the commands' own `--help` by `crates/cli/tests/docs.rs` (a test fails when it\n\
         is stale; `PI3DET_UPDATE_DOCS=1 cargo test --workspace --test docs` rewrites it).\n",
    );
    let section = |words: &[&str], md: &mut String| {
        let title = if words.is_empty() { "pi3det".to_string() } else { format!("pi3det {}", words.join(" ")) };
        md.push_str(&format!("\n## `{title}`\n\n```text\n{}```\n", help(words)));
    };
    section(&[], &mut md);
    for c in commands(&help(&[])) {
        section(&[&c], &mut md);
        for s in commands(&help(&[&c])) {
            section(&[&c, &s], &mut md);
        }
    }
    md
}

#[test]
fn cli_reference_is_current() {
    let torch = Path::new(PI3DET).with_file_name("pi3det-torch");
    if !torch.is_file() {
        eprintln!(
            "note: {} is not built, so the detector commands' help cannot be listed; not checked",
            torch.display()
        );
        return;
    }
    let path = repo().join("docs/cli.md");
    let want = cli_markdown();
    if std::env::var_os("PI3DET_UPDATE_DOCS").is_some() {
        std::fs::write(&path, &want).unwrap();
        return;
    }
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        have == want,
        "{} is stale; regenerate it with PI3DET_UPDATE_DOCS=1 cargo test --workspace --test docs",
        path.display()
    );
}

#[test]
fn architecture_crate_map_matches_cargo_metadata() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(["metadata", "--no-deps", "--offline", "--format-version", "1"])
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(out.status.success(), "cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let mut packages: Vec<String> =
        meta["packages"].as_array().unwrap().iter().map(|p| p["name"].as_str().unwrap().to_string()).collect();
    packages.sort();
    let arch = std::fs::read_to_string(repo().join("ARCHITECTURE.md")).unwrap();
    let mut mapped: Vec<String> = arch
        .lines()
        .skip_while(|l| !l.starts_with("## Crate map"))
        .skip_while(|l| !l.starts_with("| `"))
        .take_while(|l| l.starts_with("| `"))
        .filter_map(|l| l.split('`').nth(1).map(String::from))
        .collect();
    mapped.sort();
    assert_eq!(mapped, packages, "ARCHITECTURE.md's crate map / the workspace's packages");
}
