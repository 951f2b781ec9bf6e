//! `pi3det project`: draw boxes into the camera images and flag the ones no camera sees.

use std::path::PathBuf;

use crate::error::AutolabelError;
use crate::project::{self, FrameRange, ImageKind, ProjectOptions, ProjectionReport};

/// Project ground-truth boxes (and detections) into the dataset's cameras through its
/// calibration, draw them, and flag boxes outside every image or behind every camera.
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct ProjectArgs {
    /// The dataset: a Pi3DET folder or info .pkl, a KITTI folder, or an mmdet3d nuScenes info .pkl.
    #[arg(long, value_name = "DATASET")]
    pub data: PathBuf,
    /// Detections to draw too: pi3det JSON lines (.jsonl), an OpenPCDet result.pkl or a KITTI
    /// result folder.
    #[arg(long, value_name = "DETECTIONS")]
    pub det: Option<PathBuf>,
    /// Frame indices: A..B (B excluded), A.., ..B or N [default: all].
    #[arg(long, value_name = "A..B")]
    pub frames: Option<FrameRange>,
    /// Output folder: one image per frame and camera, and projection_report.json.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Write into an existing non-empty --out.
    #[arg(long)]
    pub overwrite: bool,
    /// Only these cameras (comma-separated, e.g. CAM_FRONT) [default: all of the calibration].
    #[arg(long, value_delimiter = ',', value_name = "NAME")]
    pub camera: Vec<String>,
    /// Leave out detections scoring below this.
    #[arg(long, value_name = "SCORE")]
    pub score_threshold: Option<f64>,
    /// Class check per box: run `sh -c CMD` with {crop} (a PNG of the box's image region) and
    /// {class}; the first stdout line is recorded as "verify" in the report.
    #[arg(long, value_name = "CMD")]
    pub verify_cmd: Option<String>,
    /// Write PNG instead of JPEG.
    #[arg(long)]
    pub png: bool,
}

impl ProjectArgs {
    pub fn options(&self) -> ProjectOptions {
        ProjectOptions {
            data: self.data.clone(),
            det: self.det.clone(),
            frames: self.frames,
            out: self.out.clone(),
            overwrite: self.overwrite,
            cameras: self.camera.clone(),
            score_threshold: self.score_threshold,
            verify_cmd: self.verify_cmd.clone(),
            image_kind: if self.png { ImageKind::Png } else { ImageKind::Jpeg },
        }
    }
}

/// Runs the check and prints the summary line.
pub fn run(args: &ProjectArgs) -> Result<ProjectionReport, AutolabelError> {
    let start = std::time::Instant::now();
    let report = project::project(&args.options())?;
    tracing::info!(
        "wrote {} images and projection_report.json to {} in {:.1} s",
        report.summary.images_written,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    println!("{}", report.summary);
    Ok(report)
}
