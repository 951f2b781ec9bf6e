//! Lets `pi3det-torch` and this crate's test binaries find libtorch at run time without
//! LD_LIBRARY_PATH: an rpath to the folders `pi3det-nn`'s build script found
//! (`DEP_PI3DET_TORCH_RPATH`, see crates/nn/build.rs; cargo hands it only to direct dependents of
//! pi3det-nn, as this crate is).

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_PI3DET_TORCH_RPATH");
    if let Some(dirs) = std::env::var_os("DEP_PI3DET_TORCH_RPATH") {
        for d in std::env::split_paths(&dirs) {
            println!("cargo:rustc-link-arg=-Wl,-rpath,{}", d.display());
        }
    }
}
