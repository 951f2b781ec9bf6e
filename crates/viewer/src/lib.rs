//! A browser viewer and label editor for LiDAR frames and 3D boxes, without a GPU toolkit on the
//! Rust side: the page draws with WebGL2.
//!
//! * [`scene`]: a dataset (any `pi3det-data` format) and optional detections → the [`Scene`]
//!   payload (points quantised to uint16 and base64-encoded).
//! * [`page::render`]: one self-contained HTML page (`pi3det view`).
//! * [`server`]: the same page in edit mode behind a loopback HTTP server (`pi3det annotate`),
//!   saving through [`labels`] as new numbered label sets beside the data.

pub mod error;
pub mod labels;
pub mod page;
pub mod scene;
pub mod server;

#[cfg(feature = "cli")]
pub mod cli;

pub use error::ViewerError;
pub use labels::{LabelSetWriter, SavedSet};
pub use page::render;
pub use scene::{build_scene, ColorBy, LabelBox, Scene, Source};
pub use server::{EditServer, Editor, Reply, Request};

/// Writes the static page for `src`; refuses to replace `out` unless `overwrite`.
pub fn write_page(
    src: &Source,
    max_points: usize,
    color: ColorBy,
    out: &std::path::Path,
    overwrite: bool,
) -> Result<Scene, ViewerError> {
    if !overwrite && out.exists() {
        return Err(ViewerError::Exists { path: out.to_path_buf() });
    }
    let scene = build_scene(src, max_points, color)?;
    pi3det_data::io::write_atomic(out, render(&scene).as_bytes(), overwrite).map_err(|e| match e {
        pi3det_data::DataError::Exists { path } => ViewerError::Exists { path },
        e => e.into(),
    })?;
    Ok(scene)
}
