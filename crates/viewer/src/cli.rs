//! `pi3det view` and `pi3det annotate`: arguments (clap) and runners, for the `pi3det` binary to
//! mount as subcommands.

use std::path::PathBuf;

use crate::error::ViewerError;
use crate::scene::{ColorBy, Source};
use crate::server::{EditServer, Editor};

/// Without `--frames`, a static page holds at most this many frames (each ~1 MB of text).
pub const DEFAULT_MAX_FRAMES: usize = 100;

/// Write one self-contained HTML page (WebGL2, no network) showing frames, their ground-truth
/// boxes and optional detections.
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct ViewArgs {
    /// A Pi3DET folder or info .pkl, a KITTI folder, or an mmdet3d nuScenes info .pkl.
    pub data: PathBuf,
    /// Detections to draw beside the ground truth: JSON lines (.jsonl) or an OpenPCDet result.pkl.
    #[arg(long, value_name = "DETECTIONS")]
    pub det: Option<PathBuf>,
    /// Frames (dataset indices): A..B (B excluded), A..=B, A.. or A [default: all, at most 100].
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<String>,
    /// At most this many points per frame (an even subsample).
    #[arg(long, value_name = "N", default_value_t = 200_000)]
    pub max_points: usize,
    /// Colour points by height or intensity (the page can switch).
    #[arg(long, value_enum, default_value_t = ColorBy::Height)]
    pub color: ColorBy,
    /// The HTML file to write.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Replace --out if it exists.
    #[arg(long)]
    pub overwrite: bool,
}

/// Serve the viewer with editing (move, rotate, resize, add, delete, relabel, copy to the next
/// frame, undo/redo); saving writes a new label set beside the data, never the original files.
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct AnnotateArgs {
    /// A Pi3DET folder or info .pkl, a KITTI folder, or an mmdet3d nuScenes info .pkl.
    pub data: PathBuf,
    /// Start from these detections instead of the ground truth (shown for reference).
    #[arg(long, value_name = "DETECTIONS")]
    pub det: Option<PathBuf>,
    /// Address to listen on.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:8080")]
    pub listen: String,
    /// Accept a non-loopback --listen address (the editor has no authentication).
    #[arg(long)]
    pub allow_remote: bool,
    /// Name of the label set saves write (files <...>.<NAME>-001, -002, …).
    #[arg(long, value_name = "NAME", default_value = "edit")]
    pub label_set: String,
    /// Frames to edit (dataset indices), as for `pi3det view` [default: all].
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<String>,
    /// At most this many points per frame sent to the page.
    #[arg(long, value_name = "N", default_value_t = 200_000)]
    pub max_points: usize,
    /// Colour points by height or intensity.
    #[arg(long, value_enum, default_value_t = ColorBy::Height)]
    pub color: ColorBy,
}

/// Runs `pi3det view`.
pub fn run_view(args: &ViewArgs) -> Result<(), ViewerError> {
    let mut src = Source::open(&args.data, args.det.as_deref(), args.frames.as_deref())?;
    if args.frames.is_none() && src.shown.len() > DEFAULT_MAX_FRAMES {
        tracing::warn!(
            "{}: showing frames 0..{DEFAULT_MAX_FRAMES} of {}; pass --frames to choose others",
            args.data.display(),
            src.shown.len()
        );
        src.shown = 0..DEFAULT_MAX_FRAMES;
    }
    let scene = crate::write_page(&src, args.max_points, args.color, &args.out, args.overwrite)?;
    let points: usize = scene.frames.iter().filter_map(|f| f.points.as_ref()).map(|p| p.n).sum();
    tracing::info!("wrote {} ({} frames, {points} points)", args.out.display(), scene.frames.len());
    Ok(())
}

/// Runs `pi3det annotate` until the process is stopped.
pub fn run_annotate(args: &AnnotateArgs) -> Result<(), ViewerError> {
    crate::labels::check_set_name(&args.label_set)?;
    crate::server::resolve_listen(&args.listen, args.allow_remote)?;
    let src = Source::open(&args.data, args.det.as_deref(), args.frames.as_deref())?;
    let editor = Editor::new(src, &args.label_set, args.max_points, args.color)?;
    let next = editor.writer().paths(editor.writer().next_version()?);
    let server = EditServer::bind(editor, &args.listen, args.allow_remote)?;
    eprintln!("pi3det annotate: open http://{}/ (Ctrl+C to stop)", server.addr());
    eprintln!("the next save writes: {}", next.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "));
    server.run();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    enum Cli {
        View(ViewArgs),
        Annotate(AnnotateArgs),
    }

    #[test]
    fn parses_both_commands() {
        let Cli::View(v) = Cli::try_parse_from(["x", "view", "d", "--out", "o.html", "--color", "intensity"]).unwrap()
        else {
            panic!()
        };
        assert_eq!((v.color, v.max_points, v.overwrite), (ColorBy::Intensity, 200_000, false));
        let Cli::Annotate(a) = Cli::try_parse_from(["x", "annotate", "d", "--listen", "0.0.0.0:9"]).unwrap() else {
            panic!()
        };
        assert_eq!(a.label_set, "edit");
        let e = run_annotate(&a).unwrap_err().to_string();
        assert!(e.contains("0.0.0.0:9") && e.contains("--allow-remote"), "{e}");
        assert!(Cli::try_parse_from(["x", "view", "d"]).is_err(), "--out is required");
    }
}
