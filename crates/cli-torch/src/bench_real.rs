//! `pi3det bench real`: one checkpoint on every real labelled set in `../shared/data/` (KITTI's
//! HDL-64E, Argoverse 1's two VLP-32C in the vehicle frame, nuScenes' 32 beams), with no
//! per-dataset settings — exactly what `pi3det detect --ckpt M --data D --eval` does by default
//! (each reader's intensity scale, levelling to the training sensor height) — and one table:
//! per set and pooled, Car AP_R40 BEV / 3D at 0.7 and 0.5, Pedestrian at 0.5, recall at the
//! strict threshold, detections per frame and frames without ground. On KITTI's full scans only
//! the detections in the camera's view are scored, as the field does (OpenPCDet detects on the
//! points in that view).
//!
//! Each set's labels are also checked against its points: the median height of the Car boxes'
//! bottoms above the ground around them ([`LabelGroundCheck`]). Where they float
//! (a converter that wrote box centres as KITTI's bottom centres), 3D AP measures the labels, not
//! the detector; the table says so and adds a pooled row with those sets' labels set on the
//! ground (read as centres where that is the mistake, else each car on its local ground), beside
//! the row on the labels as they are.
//!
//! `pi3det bench real --ckpt runs/demo/pointpillars_vehicle/final.safetensors [--root ../shared/data] [--out runs/bench_real]`

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::args::{DeviceArgs, LevelArgs};
use anyhow::{Context, Result};
use pi3det_data::{Dataset, FrameInfo};
use pi3det_ground::{LabelGroundCheck, LocalGround};
use pi3det_nn::data_loader::Subset;
use pi3det_nn::detect::{self, FrameDetections};
use pi3det_nn::preprocess::Preprocessor;
use pi3det_nn::{checkpoint, eval, Detector};
use serde::Serialize;

/// The real sets the table covers, as `(name, path under the root)`. `pi3det_sample` is left out:
/// it holds the same six frames as `kitti`.
pub const REAL_SETS: [(&str, &str); 4] = [
    ("argoverse1", "argoverse1/training"),
    ("kitti", "kitti/training"),
    ("kitti_extra", "kitti_extra/training"),
    ("nuscenes_demo", "nuscenes_demo"),
];

/// A checkpoint on every real labelled set, one table.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchRealArgs {
    #[arg(long)]
    pub ckpt: PathBuf,
    /// The folder holding the real sets (`../shared/data` beside the repository).
    #[arg(long, default_value = "../shared/data")]
    pub root: PathBuf,
    /// Also write the table (table.md), the numbers (bench_real.json) and each set's detections here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub level: LevelArgs,
    #[arg(long, default_value_t = 1)]
    pub batch_size: usize,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct RealRow {
    pub set: String,
    pub frames: usize,
    pub cars: usize,
    pub pedestrians: usize,
    /// Car BEV / 3D AP_R40 (moderate) at 0.7 and at 0.5.
    pub car_07: [f64; 2],
    pub car_05: [f64; 2],
    /// Pedestrian BEV / 3D AP_R40 at 0.5.
    pub ped_05: [f64; 2],
    /// Share of ground truths matched at the strict BEV threshold by any detection (Car, Pedestrian).
    pub recall: [Option<f64>; 2],
    pub detections_per_frame: f64,
    pub frames_without_ground: usize,
    /// Median height (m) of the labelled cars' bottoms above the ground around them; `None`
    /// where too few boxes had ground near them (and for the pooled rows).
    pub label_above_ground_m: Option<f64>,
}

pub fn run(args: &BenchRealArgs) -> Result<()> {
    let device = args.device.setup(0)?;
    let mut ck = checkpoint::load(&args.ckpt)?;
    args.device.apply_precision(&mut ck.config);
    let cfg = ck.config.clone();
    let mut det = Detector::new(&cfg, device)?;
    ck.load_into(&mut det, &args.ckpt)?;
    let level = args.level.level();
    eprintln!("{}", level.describe(&cfg));
    let r = cfg.pillars.point_cloud_range;
    let opts = eval::options(&cfg.classes, Some([r[0], r[1], r[3], r[4]]), None);
    let mut rows = Vec::new();
    let mut pooled: Vec<FrameDetections> = Vec::new();
    let mut pooled_no_ground = 0;
    let mut grounded: Vec<FrameDetections> = Vec::new();
    let mut floating = Vec::new();
    for (name, rel) in REAL_SETS {
        let path = args.root.join(rel);
        if !path.exists() {
            eprintln!("{name}: {} not found, left out", path.display());
            continue;
        }
        let ds: Arc<dyn Dataset> =
            Arc::from(pi3det_data::open(&path).with_context(|| format!("opening {}", path.display()))?);
        // One levelling per set, so its frames without ground are counted apart.
        let levelling = level.transform(&cfg)?;
        det.prep = Arc::new(match &levelling {
            Some(v) => Preprocessor::new(&cfg)?.with_frame_transform(v.clone()),
            None => Preprocessor::new(&cfg)?,
        });
        let (mut frames, _) = detect::detect(&det, &Subset::all(ds.clone()), args.batch_size, &mut |_, _| {})?;
        eval::keep_camera_view(&mut frames);
        let no_ground = levelling.map_or(0, |v| v.counts().no_ground);
        if let Some(out) = &args.out {
            let dir = out.join(name);
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            detect::write_jsonl(&dir.join("detections.jsonl"), &frames)?;
        }
        let (check, ground_z) = label_ground(ds.as_ref())?;
        let mut r = row(name, &frames, no_ground, &opts)?;
        r.label_above_ground_m = check.median_m();
        rows.push(r);
        pooled_no_ground += no_ground;
        let fix = LabelFix::of(&check);
        if let Some(fix) = fix {
            floating.push(fix.describe(name, &check));
        }
        // Frame ids repeat across sets (KITTI's and Argoverse's both start at 000000).
        for f in frames {
            let mut on_ground = f.info.clone();
            match fix {
                Some(LabelFix::AsCentres) => lower_by_half_height(&mut on_ground),
                Some(LabelFix::OnLocalGround) => set_on_ground(&mut on_ground, ground_z.get(&f.info.id)),
                None => {}
            }
            let id = format!("{name}/{}", f.info.id);
            grounded
                .push(FrameDetections { info: FrameInfo { id: id.clone(), ..on_ground }, objects: f.objects.clone() });
            pooled.push(FrameDetections { info: FrameInfo { id, ..f.info }, objects: f.objects });
        }
    }
    if rows.is_empty() {
        anyhow::bail!("none of the real sets was found under {}", args.root.display());
    }
    rows.push(row("pooled", &pooled, pooled_no_ground, &opts)?);
    if !floating.is_empty() {
        rows.push(row("pooled, floating labels set on the ground", &grounded, pooled_no_ground, &opts)?);
    }
    let mut table = format_table(&rows);
    if !floating.is_empty() {
        table.push_str(&format!(
            "\nLabels that float (median car bottom − ground beyond ±{} m): 3D AP on those sets measures the \
             labels' offset, not the detector. The last row evaluates them set on the ground: {}.\n",
            LabelGroundCheck::FLOATING_M,
            floating.join("; ")
        ));
    }
    print!("{table}");
    if let Some(out) = &args.out {
        write(out, "table.md", table.as_bytes())?;
        let json = serde_json::json!({ "ckpt": args.ckpt, "level": level.describe(&cfg), "rows": rows });
        write(out, "bench_real.json", &serde_json::to_vec_pretty(&json)?)?;
    }
    Ok(())
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> Result<()> {
    pi3det_data::io::write_atomic(&dir.join(name), bytes, true).with_context(|| format!("writing {name}"))
}

/// Each labelled box's local ground height (`None`: not checked or none found), by frame id.
type GroundByFrame = HashMap<String, Vec<Option<f64>>>;

/// The labelled cars of every frame against the ground around them, and each car's local ground
/// height by frame id (`None` for other classes and where no ground was found). Cars only: the
/// ground around a pedestrian is often hidden by the crowd or the parked cars beside it, so its
/// estimate is not to be trusted.
fn label_ground(ds: &dyn Dataset) -> Result<(LabelGroundCheck, GroundByFrame)> {
    let ground = LocalGround::default();
    let mut check = LabelGroundCheck::default();
    let mut per_frame = HashMap::new();
    for i in 0..ds.len() {
        let frame = ds.load(i)?;
        let points: Vec<[f32; 4]> =
            frame.points.to_xyzi().as_slice().chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect();
        // Case-insensitive, as the evaluator matches classes.
        let car = |o: &&pi3det_data::Object| o.name.eq_ignore_ascii_case("Car");
        check.add_frame(&points, frame.info.objects.iter().filter(car).map(|o| &o.box3d), &ground);
        let zs = frame.info.objects.iter().map(|o| car(&o).then(|| ground.z(&points, &o.box3d)).flatten()).collect();
        per_frame.insert(frame.info.id, zs);
    }
    Ok((check, per_frame))
}

/// How the last row sets a floating set's labels on the ground.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LabelFix {
    /// Every label's location read as its box's centre (every class): the converter's mistake,
    /// when that reading brings the cars onto the ground.
    AsCentres,
    /// Each car set on its local ground, other classes as labelled: floating for a reason the
    /// check cannot name.
    OnLocalGround,
}

impl LabelFix {
    fn of(check: &LabelGroundCheck) -> Option<Self> {
        if check.reads_as_centres() {
            Some(Self::AsCentres)
        } else if check.floating() {
            Some(Self::OnLocalGround)
        } else {
            None
        }
    }

    fn describe(self, set: &str, check: &LabelGroundCheck) -> String {
        let m = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:+.2} m"));
        match self {
            Self::AsCentres => format!(
                "{set}'s cars sit {} above the ground and {} read as box centres (its converter wrote centres \
                 where KITTI expects bottom centres), so every label of it is lowered by half its height",
                m(check.median_m()),
                m(check.median_as_centres_m())
            ),
            Self::OnLocalGround => format!(
                "{set}'s cars sit {} above the ground, {} read as box centres: each car is set on its local \
                 ground, other classes stay as labelled",
                m(check.median_m()),
                m(check.median_as_centres_m())
            ),
        }
    }
}

/// Reads every label's location as its box's centre: each box half its height lower.
fn lower_by_half_height(info: &mut FrameInfo) {
    for o in &mut info.objects {
        o.box3d.z -= 0.5 * o.box3d.dz;
    }
}

/// Sets each box whose local ground was found on it (bottom at the ground).
fn set_on_ground(info: &mut FrameInfo, ground_z: Option<&Vec<Option<f64>>>) {
    let Some(zs) = ground_z else { return };
    for (o, z) in info.objects.iter_mut().zip(zs) {
        if let Some(z) = z {
            o.box3d.z = z + 0.5 * o.box3d.dz;
        }
    }
}

fn row(set: &str, frames: &[FrameDetections], no_ground: usize, opts: &pi3det_eval::EvalOptions) -> Result<RealRow> {
    let (_, summary) = eval::evaluate(frames, opts)?;
    let breakdown = eval::breakdown(frames, opts)?;
    let class = |name: &str| summary.get(name);
    let recall = |name: &str| breakdown.classes.iter().find(|c| c.class == name).and_then(|c| c.all.recall_bev);
    let car = class("Car");
    let ped = class("Pedestrian");
    let detections: usize = frames.iter().map(|f| f.objects.len()).sum();
    Ok(RealRow {
        set: set.into(),
        frames: frames.len(),
        cars: car.map_or(0, |c| c.num_gt),
        pedestrians: ped.map_or(0, |c| c.num_gt),
        car_07: car.map_or([0.0; 2], |c| [c.bev_r40, c.d3_r40]),
        car_05: car.and_then(|c| c.loose).map_or([0.0; 2], |l| [l.bev_r40, l.d3_r40]),
        ped_05: ped.map_or([0.0; 2], |c| [c.bev_r40, c.d3_r40]),
        recall: [recall("Car"), recall("Pedestrian")],
        detections_per_frame: detections as f64 / frames.len().max(1) as f64,
        frames_without_ground: no_ground,
        label_above_ground_m: None,
    })
}

/// The markdown table `bench real` prints.
pub fn format_table(rows: &[RealRow]) -> String {
    let pct = |r: Option<f64>| r.map_or("–".to_string(), |v| format!("{:.0} %", 100.0 * v));
    let mut s = String::from(
        "| set | frames | cars / peds | Car BEV / 3D @0.7 | Car BEV / 3D @0.5 | Ped BEV / 3D @0.5 | recall Car / Ped | dets / frame | no ground | Car labels above ground |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} / {} | {:.1} / {:.1} | {:.1} / {:.1} | {:.1} / {:.1} | {} / {} | {:.1} | {} | {} |\n",
            r.set,
            r.frames,
            r.cars,
            r.pedestrians,
            r.car_07[0],
            r.car_07[1],
            r.car_05[0],
            r.car_05[1],
            r.ped_05[0],
            r.ped_05[1],
            pct(r.recall[0]),
            pct(r.recall[1]),
            r.detections_per_frame,
            r.frames_without_ground,
            r.label_above_ground_m.map_or("–".to_string(), |m| format!("{m:+.2} m")),
        ));
    }
    s.push_str("\nAP_R40, moderate, within the detector's BEV range; pooled: every set's frames evaluated together.\n");
    s
}
