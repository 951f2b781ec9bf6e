//! Run-time library paths for libtorch.
//!
//! `tch`'s build links libtorch dynamically but leaves finding it at run time to the user. We add an
//! rpath (absolute, canonicalised: the real folders in `.venv`, see `scripts/setup-torch`) to this
//! crate's own test, bench and example binaries, and hand the same folders to crates that depend on
//! this one through the `links` metadata: a dependent's build script reads
//! `DEP_PI3DET_TORCH_RPATH` (folders joined like `PATH`) and emits
//! `cargo:rustc-link-arg=-Wl,-rpath,<folder>` for each, which is what `crates/cli/build.rs` does
//! for the `pi3det` binary.

use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    println!("cargo:rerun-if-changed=build.rs");
    let Ok(libtorch) = std::env::var("LIBTORCH") else {
        println!("cargo:warning=LIBTORCH is not set (run scripts/setup-torch); binaries will need LD_LIBRARY_PATH");
        return;
    };
    let libtorch = PathBuf::from(libtorch);
    // The CUDA runtime stubs from the nvidia-cuda-runtime wheel sit beside torch in site-packages;
    // .venv/cu13lib is the stable link scripts/setup-torch makes to them.
    let mut candidates = vec![libtorch.join("lib")];
    if let Some(venv) = libtorch.parent() {
        candidates.push(venv.join("cu13lib"));
    }
    if let Ok(real) = libtorch.canonicalize() {
        if let Some(site) = real.parent() {
            candidates.push(site.join("nvidia/cu13/lib"));
        }
    }
    let mut dirs: Vec<PathBuf> = Vec::new();
    for c in candidates {
        if let Ok(real) = c.canonicalize() {
            if !dirs.contains(&real) {
                dirs.push(real);
            }
        }
    }
    for d in &dirs {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", d.display());
    }
    if let Ok(joined) = std::env::join_paths(&dirs) {
        println!("cargo:rpath={}", joined.to_string_lossy());
    }
}
