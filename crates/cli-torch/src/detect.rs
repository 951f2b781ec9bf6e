//! `pi3det detect`: a trained detector over a dataset; detections as JSON lines and OpenPCDet's
//! `result.pkl`, per-frame latency, optionally the evaluation.

use std::path::PathBuf;

use indicatif::ProgressBar;

use crate::args::{on_off, DataArgs, DeviceArgs};
use crate::common::{progress_style, refuse_existing};
use pi3det_nn::checkpoint;
use pi3det_nn::detect::{self, Latency};
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::eval;

/// Run a trained detector over a dataset and write its detections (JSON lines and OpenPCDet's
/// result.pkl), with per-frame latency.
#[derive(clap::Args, Debug, Clone)]
pub struct DetectArgs {
    /// Checkpoint (.safetensors) written by `pi3det train`.
    #[arg(long)]
    pub ckpt: PathBuf,
    #[command(flatten)]
    pub data: DataArgs,
    /// Output folder: detections.jsonl, result.pkl, latency.json (and eval.json with --eval).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub batch_size: usize,
    /// Override the checkpoint's score threshold.
    #[arg(long)]
    pub score_threshold: Option<f64>,
    /// Override the checkpoint's NMS IoU threshold.
    #[arg(long)]
    pub nms_iou: Option<f64>,
    /// Override the checkpoint's NMS mode: per class (`--per-class-nms`) or over all classes at
    /// once (`--no-per-class-nms`).
    #[arg(long, overrides_with = "no_per_class_nms")]
    pub per_class_nms: bool,
    #[arg(long, overrides_with = "per_class_nms")]
    pub no_per_class_nms: bool,
    /// Fit each box's bottom to the local ground and its top to the highest point inside it after
    /// NMS (`[post.ground_fit]` with its defaults; `--no-ground-fit` turns the checkpoint's off).
    #[arg(long, overrides_with = "no_ground_fit")]
    pub ground_fit: bool,
    #[arg(long, overrides_with = "ground_fit")]
    pub no_ground_fit: bool,
    /// Fit each long box's heading and BEV centre to the points on its faces after NMS
    /// (`[post.bev_fit]` with its defaults; `--no-bev-fit` turns the checkpoint's off).
    #[arg(long, overrides_with = "no_bev_fit")]
    pub bev_fit: bool,
    #[arg(long, overrides_with = "bev_fit")]
    pub no_bev_fit: bool,
    /// Lower the scores of pedestrian detections that do not stand up to a person's height or
    /// have points right above them, after the fits (`[post.upright_check]` with its defaults;
    /// `--no-upright-check` turns the checkpoint's check off).
    #[arg(long, overrides_with = "no_upright_check")]
    pub upright_check: bool,
    #[arg(long, overrides_with = "upright_check")]
    pub no_upright_check: bool,
    /// Test-time augmentation: the frame also mirrored and turned, the views fused
    /// (`[post.tta]` with its defaults; `--no-tta` turns the checkpoint's off, for a sixth of
    /// the network time per frame).
    #[arg(long, overrides_with = "no_tta")]
    pub tta: bool,
    #[arg(long, overrides_with = "tta")]
    pub no_tta: bool,
    /// A TOML file whose `[post]` table (a detector config's, or a Pi3DET-Net preset's
    /// `[detector.post]`) replaces the checkpoint's post-processing (thresholds, NMS, fits, TTA);
    /// the flags above apply on top of it.
    #[arg(long, value_name = "TOML")]
    pub post: Option<PathBuf>,
    /// Override the z shift applied to the points (e.g. to move a drone's ground to z ≈ 0).
    #[arg(long, allow_negative_numbers = true)]
    pub shift_z: Option<f64>,
    #[command(flatten)]
    pub level: crate::args::LevelArgs,
    /// Also evaluate against the data's ground truth (within the detector's range) and print it
    /// with the error breakdown (eval.json, breakdown.json).
    #[arg(long)]
    pub eval: bool,
    /// Replace detections an earlier run left in OUT.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Virtual Platform Pose putting frames at `height_m` above the ground (`--vpp-height`).
pub fn vpp(
    cfg: &pi3det_nn::DetectorConfig,
    height_m: f64,
) -> Result<std::sync::Arc<dyn pi3det_nn::preprocess::FrameTransform>> {
    let v: std::sync::Arc<dyn pi3det_nn::preprocess::FrameTransform> = vpp_at(cfg, height_m)?;
    Ok(v)
}

/// [`vpp`], keeping the concrete type (its counts say how many frames had no ground).
pub fn vpp_at(
    cfg: &pi3det_nn::DetectorConfig,
    height_m: f64,
) -> Result<std::sync::Arc<pi3det_nn::preprocess::vpp::VirtualPlatformPose>> {
    let level = pi3det_nn::preprocess::Level::Height(height_m);
    level.transform(cfg)?.ok_or_else(|| NnError::Input(format!("cannot level frames to {height_m} m")))
}

pub fn run_detect(args: &DetectArgs) -> Result<()> {
    if !args.overwrite {
        refuse_existing(&args.out, |name| ["detections.jsonl", "result.pkl", "latency.json"].contains(&name))?;
    }
    let device = args.device.setup(0)?;
    let mut ck = checkpoint::load(&args.ckpt)?;
    if let Some(path) = &args.post {
        ck.config.post = read_post(path)?;
    }
    if let Some(t) = args.score_threshold {
        ck.config.post.score_threshold = t;
    }
    if let Some(t) = args.nms_iou {
        ck.config.post.nms_iou = t;
    }
    if let Some(z) = args.shift_z {
        ck.config.shift_z = z;
    }
    if let Some(b) = on_off(args.per_class_nms, args.no_per_class_nms) {
        ck.config.post.per_class_nms = b;
    }
    switch(&mut ck.config.post.ground_fit, on_off(args.ground_fit, args.no_ground_fit));
    switch(&mut ck.config.post.bev_fit, on_off(args.bev_fit, args.no_bev_fit));
    switch(&mut ck.config.post.upright_check, on_off(args.upright_check, args.no_upright_check));
    switch(&mut ck.config.post.tta, on_off(args.tta, args.no_tta));
    args.device.apply_precision(&mut ck.config);
    ck.config.validate()?;
    let mut det = pi3det_nn::Detector::new(&ck.config, device)?;
    ck.load_into(&mut det, &args.ckpt)?;
    let level = args.level.level();
    eprintln!("{}", level.describe(&ck.config));
    let levelling = level.transform(&ck.config)?;
    if let Some(v) = &levelling {
        det.prep =
            std::sync::Arc::new(pi3det_nn::preprocess::Preprocessor::new(&ck.config)?.with_frame_transform(v.clone()));
    }
    let subset = args.data.subset("val", 0)?;
    let bar = ProgressBar::new(subset.len() as u64)
        .with_style(progress_style("detect [{bar:30}] {pos}/{len} {elapsed}<{eta}"));
    let (frames, lat) = detect::detect(&det, &subset, args.batch_size, &mut |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    if let Some(c) = levelling.map(|v| v.counts()).filter(|c| c.no_ground > 0) {
        eprintln!(
            "warning: no ground found in {} of {} frames: those kept the plain z shift ({} m)",
            c.no_ground, c.frames, ck.config.shift_z
        );
    }
    std::fs::create_dir_all(&args.out).map_err(|e| NnError::io(&args.out, e))?;
    detect::write_jsonl(&args.out.join("detections.jsonl"), &frames)?;
    detect::write_result_pkl(&args.out.join("result.pkl"), &frames, &det.cfg().classes)?;
    let lat_json = serde_json::to_vec_pretty(&serde_json::json!({
        "device": format!("{device:?}"), "batch_size": args.batch_size, "latency_ms": lat, "total_ms": lat.total_ms(),
    }))
    .unwrap_or_default();
    pi3det_data::io::write_atomic(&args.out.join("latency.json"), &lat_json, true)?;
    let n: usize = frames.iter().map(|f| f.objects.len()).sum();
    println!("{} frames, {n} detections → {}", frames.len(), args.out.display());
    println!("{}", format_latency(&lat));
    if args.eval {
        let mut frames = frames;
        let outside = eval::keep_camera_view(&mut frames);
        if outside > 0 {
            eprintln!("evaluating without {outside} detections outside KITTI's camera view (nobody labels there)");
        }
        let r = det.cfg().pillars.point_cloud_range;
        let opts = eval::options(&det.cfg().classes, Some([r[0], r[1], r[3], r[4]]), None);
        let (report, _) = eval::evaluate(&frames, &opts)?;
        let json = serde_json::to_vec_pretty(&report).unwrap_or_default();
        pi3det_data::io::write_atomic(&args.out.join("eval.json"), &json, true)?;
        print!("{}", pi3det_eval::format_report(&report));
        let b = eval::breakdown(&frames, &opts)?;
        pi3det_data::io::write_atomic(
            &args.out.join("breakdown.json"),
            &serde_json::to_vec_pretty(&b).unwrap_or_default(),
            true,
        )?;
        print!("{}", pi3det_eval::format_breakdown(&b));
    }
    Ok(())
}

/// `--ground-fit` / `--bev-fit` / `--upright-check`: off drops the fit, on adds it with its defaults unless the
/// checkpoint (or `--post`) already has one, absent leaves it.
fn switch<T: Default>(fit: &mut Option<T>, on: Option<bool>) {
    match on {
        Some(false) => *fit = None,
        Some(true) if fit.is_none() => *fit = Some(T::default()),
        _ => {}
    }
}

/// The post-processing of a TOML file (`--post`): its `[post]` table — a file holding just that
/// table, or a detector config — or a Pi3DET-Net preset's `[detector.post]`, so a preset's box
/// fits and test-time augmentation apply to any checkpoint.
fn read_post(path: &std::path::Path) -> Result<pi3det_nn::config::PostConfig> {
    let text = std::fs::read_to_string(path).map_err(|e| NnError::io(path, e))?;
    parse_post(&text).map_err(|message| NnError::ConfigFile { path: path.to_path_buf(), message })
}

fn parse_post(text: &str) -> std::result::Result<pi3det_nn::config::PostConfig, String> {
    let mut table: toml::Table = toml::from_str(text).map_err(|e| e.to_string())?;
    let nested = table.get_mut("detector").and_then(|d| d.as_table_mut()).and_then(|d| d.remove("post"));
    let post = match (table.remove("post"), nested) {
        (Some(p), None) | (None, Some(p)) => p,
        (Some(_), Some(_)) => return Err("both [post] and [detector.post]: which one is meant?".into()),
        (None, None) => return Err("no [post] or [detector.post] table".into()),
    };
    post.try_into().map_err(|e: toml::de::Error| format!("[post]: {e}"))
}

pub fn format_latency(l: &Latency) -> String {
    format!(
        "latency per frame: {:.1} ms (read + pillarize {:.1}, network {:.1}, decode + NMS {:.1})",
        l.total_ms(),
        l.prep_ms,
        l.network_ms,
        l.post_ms
    )
}

#[cfg(test)]
mod tests {
    use super::parse_post;

    #[test]
    fn post_comes_from_a_post_table_a_detector_config_or_a_preset() {
        let plain = parse_post("[post]\nscore_threshold = 0.2\n[post.bev_fit]\n").unwrap();
        assert_eq!(plain.score_threshold, 0.2);
        assert!(plain.bev_fit.is_some());
        let detector = parse_post("name = \"d\"\n[post]\nnms_iou = 0.3\n").unwrap();
        assert_eq!(detector.nms_iou, 0.3);
        let preset = parse_post(include_str!("../../../configs/pi3det_net_cpu.toml")).unwrap();
        let tta = preset.tta.expect("the Pi3DET-Net preset has test-time augmentation");
        assert_eq!(tta.class_fusion_iou.get("Pedestrian"), Some(&0.4));
        assert!(preset.ground_fit.is_some() && preset.upright_check.is_some());
        let e = parse_post("[post]\nscore_treshold = 0.2\n").unwrap_err();
        assert!(e.contains("score_treshold"), "{e}");
        let e = parse_post("[post]\n[detector.post]\n").unwrap_err();
        assert!(e.contains("both"), "{e}");
        let e = parse_post("[train]\nepochs = 1\n").unwrap_err();
        assert!(e.contains("[post]"), "{e}");
    }
}
