//! One benchmark cell: a method with a detector on a task, trained and evaluated on the task's
//! target validation split. Artifacts several cells share — simulated data, a source model, a
//! Pi3DET-Net Pre-Adaptation — are made once per output folder under `data/` and `shared/`,
//! each keyed by the full text of what made it, so a changed config never reuses a stale one.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::open_subset;
use anyhow::{bail, Context, Result};
use pi3det_adapt::baselines::memory::MemoryConfig;
use pi3det_adapt::baselines::redb::{self, Candidate};
use pi3det_adapt::baselines::self_training::{SelfTraining, SelfTrainingConfig, SelfTrainingReport};
use pi3det_adapt::pipeline::{self as adapt, AdaptOptions};
use pi3det_adapt::pseudo_labels;
use pi3det_autolabel::fusion::FusionConfig;
use pi3det_autolabel::tracking::TrackingConfig;
use pi3det_data::{Dataset, FrameInfo, Object, Platform};
use pi3det_nn::augment::{AugmentConfig, RandomObjectScalingConfig, StatisticalNormalizationConfig};
use pi3det_nn::config::DetectorConfig;
use pi3det_nn::data_loader::Subset;
use pi3det_nn::detect::FrameDetections;
use pi3det_nn::eval::ApSummary;
use pi3det_nn::preprocess::vpp::median_sensor_height;
use pi3det_nn::preprocess::Preprocessor;
use pi3det_nn::roi_heads::ScoreFusion;
use pi3det_nn::{checkpoint, train, Detector};

use super::suite::{Cell, DatasetSpec, MethodKind, MethodSpec, Suite};
use crate::autolabel::{detect_in_view, ensemble, EnsembleOptions, View};

/// A cell's log: every line to `log.txt` and to stderr.
pub struct Log {
    file: std::fs::File,
    prefix: String,
}

impl Log {
    pub fn create(path: &Path, prefix: String) -> Result<Self> {
        let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        Ok(Self { file, prefix })
    }

    pub fn line(&mut self, s: impl AsRef<str>) {
        let s = s.as_ref();
        let _ = writeln!(self.file, "{s}");
        eprintln!("[{}] {s}", self.prefix);
    }
}

/// What a finished cell measured.
#[derive(Debug, Default)]
pub struct Outcome {
    pub ap: ApSummary,
    /// Pseudo-label rounds with their quality against the target's ground truth.
    pub pseudo_labels: Vec<serde_json::Value>,
}

pub struct Ctx<'a> {
    pub suite: &'a Suite,
    pub out: &'a Path,
    pub device: tch::Device,
}

/// FNV-1a, for folder names of shared artifacts (their full key is stored beside them).
pub fn fnv(s: &str) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in s.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x100000001b3);
    }
    format!("{h:016x}")
}

impl Ctx<'_> {
    /// `out/<kind>/<name>_<hash>`, made by `make` unless it was already made from `key`.
    /// Processes sharing `out` (Ray tasks on a shared filesystem) take turns through a file lock.
    fn shared(&self, kind: &str, name: &str, key: &str, make: impl FnOnce(&Path) -> Result<()>) -> Result<PathBuf> {
        let dir = self.out.join(kind).join(format!("{name}_{}", fnv(key)));
        std::fs::create_dir_all(self.out.join(kind))
            .with_context(|| format!("creating {}", self.out.join(kind).display()))?;
        let lock_path = self.out.join(kind).join(format!("{name}_{}.lock", fnv(key)));
        let lock = std::fs::File::create(&lock_path).with_context(|| format!("creating {}", lock_path.display()))?;
        lock.lock().with_context(|| format!("locking {}", lock_path.display()))?;
        let marker = dir.join(".complete");
        if std::fs::read_to_string(&marker).is_ok_and(|k| k == key) {
            return Ok(dir);
        }
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("clearing {}", dir.display()))?;
        }
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        make(&dir)?;
        pi3det_data::io::write_atomic(&marker, key.as_bytes(), true)?;
        Ok(dir)
    }

    /// The folder holding `dataset`'s `train` and `val` splits (simulated on first use).
    fn dataset_root(&self, name: &str, log: &mut Log) -> Result<(PathBuf, DatasetSpec)> {
        let spec = self.suite.datasets[name].clone();
        if let Some(p) = &spec.path {
            return Ok((p.clone(), spec));
        }
        let sim = spec.sim.clone().expect("a checked suite's dataset is sim or path");
        let seed = sim.seed.unwrap_or(self.suite.seed);
        let key = format!("{sim:?} seed {seed}");
        let platform = Platform::parse(&sim.platform);
        let dir = self.shared("data", name, &key, |dir| {
            log.line(format!(
                "simulating {name}: {} {} sequences × {} frames ({} val), {}",
                sim.sequences, platform, sim.frames, sim.val_sequences, sim.sensor
            ));
            let cfg = pi3det_sim::SimConfig {
                sensor: pi3det_sim::SensorPreset::parse(&sim.sensor)?.config(),
                ..Default::default()
            };
            let plan = pi3det_sim::PlatformPlan {
                platform,
                sequences: sim.sequences,
                frames: sim.frames,
                val_sequences: sim.val_sequences,
            };
            let opts = pi3det_sim::ExportOptions {
                out: dir.to_path_buf(),
                seed,
                overwrite: true,
                per_platform_folders: true,
                layout: None,
                stratify_layouts: false,
            };
            pi3det_sim::export(&cfg, &[plan], &opts, &mut |_, _| {}).context("simulation")?;
            Ok(())
        })?;
        Ok((dir.join(platform.as_str()), spec))
    }

    fn split(&self, dataset: &str, train: bool, log: &mut Log) -> Result<Subset> {
        let (root, spec) = self.dataset_root(dataset, log)?;
        let (split, max) = if train {
            (&spec.train_split, self.suite.schedule.max_train_frames)
        } else {
            (&spec.val_split, self.suite.schedule.max_val_frames)
        };
        let dir = if spec.sim.is_some() { root.join(split) } else { root };
        let s =
            open_subset(&dir, Some(split), None, max).with_context(|| format!("dataset {dataset}, split {split}"))?;
        if s.is_empty() {
            bail!("dataset {dataset}: the {split} split has no frames");
        }
        Ok(s)
    }

    /// A detector config with the suite's schedule and seed.
    fn scheduled(&self, cfg: &DetectorConfig) -> DetectorConfig {
        let mut c = cfg.clone();
        if let Some(e) = self.suite.schedule.epochs {
            c.train.epochs = e;
        }
        c.train.seed = self.suite.seed;
        c.train.max_train_frames = 0;
        c
    }

    /// Trains `cfg` on `dataset`'s training split (once per output folder); its final checkpoint.
    fn trained(
        &self,
        what: &str,
        cfg: &DetectorConfig,
        datasets: &[&str],
        stage: Option<&str>,
        log: &mut Log,
    ) -> Result<PathBuf> {
        let specs: Vec<String> = datasets.iter().map(|d| format!("{d}: {:?}", self.suite.datasets[*d])).collect();
        let key = format!("{}\n{stage:?}\n{}", specs.join("\n"), cfg.to_toml());
        let mut train_sets = Vec::new();
        for d in datasets {
            train_sets.push(self.split(d, true, log)?);
        }
        let device = self.device;
        let dir = self.shared("shared", what, &key, |dir| {
            let train = concat(&train_sets);
            log.line(format!("training {what} ({} frames, {} epochs)", train.len(), cfg.train.epochs));
            let t = std::time::Instant::now();
            train::train(
                train::TrainOptions {
                    config: cfg.clone(),
                    train,
                    val: None,
                    out_dir: dir.to_path_buf(),
                    device,
                    resume: None,
                    stage: stage.map(str::to_string),
                    frame_transform: None,
                },
                &mut |e| {
                    if let train::Event::EpochEnd { epoch, mean_loss, seconds, .. } = e {
                        log.line(format!("  {what} epoch {} loss {mean_loss:.3} ({seconds:.0} s)", epoch + 1));
                    }
                },
            )?;
            log.line(format!("trained {what} in {:.0} s", t.elapsed().as_secs_f64()));
            Ok(())
        })?;
        Ok(dir.join("final.safetensors"))
    }
}

/// Frames of several subsets as one (the `combined` method).
fn concat(sets: &[Subset]) -> Subset {
    if sets.len() == 1 {
        return sets[0].clone();
    }
    let parts: Vec<Subset> = sets.to_vec();
    let len = parts.iter().map(Subset::len).sum();
    Subset { dataset: Arc::new(Concat { parts, root: PathBuf::new() }), indices: (0..len).collect() }
}

struct Concat {
    parts: Vec<Subset>,
    root: PathBuf,
}

impl Concat {
    /// The part holding frame `i` of the concatenation and the frame's index in its dataset.
    fn locate(&self, mut i: usize) -> std::result::Result<(&Subset, usize), pi3det_data::DataError> {
        for p in &self.parts {
            if i < p.len() {
                return Ok((p, p.indices[i]));
            }
            i -= p.len();
        }
        Err(pi3det_data::DataError::invalid(
            &self.root,
            format!("frame {i} past the end of a concatenation of {} frames", self.len()),
        ))
    }
}

impl Dataset for Concat {
    fn format(&self) -> pi3det_data::Format {
        self.parts[0].dataset.format()
    }
    fn root(&self) -> &Path {
        &self.root
    }
    fn len(&self) -> usize {
        self.parts.iter().map(Subset::len).sum()
    }
    fn info(&self, index: usize) -> std::result::Result<FrameInfo, pi3det_data::DataError> {
        let (p, i) = self.locate(index)?;
        p.dataset.info(i)
    }
    fn load(&self, index: usize) -> std::result::Result<pi3det_data::Frame, pi3det_data::DataError> {
        let (p, i) = self.locate(index)?;
        p.dataset.load(i)
    }
}

fn load(path: &Path, cfg: Option<&DetectorConfig>, device: tch::Device) -> Result<Detector> {
    let ck = checkpoint::load(path)?;
    let cfg = cfg.unwrap_or(&ck.config);
    let mut det = Detector::new(cfg, device)?;
    ck.load_into(&mut det, path)?;
    Ok(det)
}

/// The method's self-training settings: the suite's, else the method's published recipe.
fn self_training_config(m: &MethodSpec, epochs: Option<usize>) -> SelfTrainingConfig {
    let mut c = m.self_training.clone().unwrap_or_else(|| {
        let st3d = SelfTrainingConfig::default();
        match m.kind {
            MethodKind::St3dPp => SelfTrainingConfig {
                memory: Some(MemoryConfig { per_class: true, ..Default::default() }),
                source_assisted: true,
                ds_norm: true,
                ..st3d
            },
            MethodKind::Redb | MethodKind::Ms3dPp => SelfTrainingConfig {
                memory: None,
                curriculum: None,
                labels: pseudo_labels::PseudoLabelConfig { positive_score: 0.5, ignore_score: 0.2, refresh_every: 0 },
                ..st3d
            },
            _ => st3d,
        }
    });
    if m.self_training.is_none() {
        if let Some(e) = epochs {
            c.epochs = e;
        }
    }
    c
}

fn rounds_json(r: &SelfTrainingReport) -> Vec<serde_json::Value> {
    r.rounds.iter().map(|x| serde_json::to_value(x).unwrap_or_default()).collect()
}

fn log_rounds(log: &mut Log, r: &SelfTrainingReport) {
    for round in &r.rounds {
        let q: Vec<String> = round
            .quality
            .iter()
            .map(|q| format!("{}@{} P {:.1} R {:.1}", q.class, q.iou, q.precision, q.recall))
            .collect();
        log.line(format!(
            "  labels at epoch {}: {} positive, {} ignored; {}",
            round.epoch,
            round.positives,
            round.ignored,
            q.join(", ")
        ));
    }
    log.line(format!("  self-training: {} steps, {:.0} s", r.steps, r.seconds));
}

/// Mean box size per class of a split's labels.
fn mean_sizes(infos: &[FrameInfo], cfg: &DetectorConfig) -> BTreeMap<String, ([f64; 3], usize)> {
    let mut m: BTreeMap<String, ([f64; 3], usize)> = BTreeMap::new();
    for o in infos.iter().flat_map(|i| &i.objects) {
        if let Some(k) = cfg.class_index(&o.name) {
            let e = m.entry(cfg.classes[k].clone()).or_insert(([0.0; 3], 0));
            e.0[0] += o.box3d.dx;
            e.0[1] += o.box3d.dy;
            e.0[2] += o.box3d.dz;
            e.1 += 1;
        }
    }
    for (s, n) in m.values_mut() {
        s.iter_mut().for_each(|v| *v /= (*n).max(1) as f64);
    }
    m
}

/// Runs one cell in `dir` (its folder, empty).
pub fn run_cell(ctx: &Ctx<'_>, cell: &Cell, dir: &Path, log: &mut Log) -> Result<Outcome> {
    let suite = ctx.suite;
    let task = suite.task(&cell.task);
    let method = &suite.methods[cell.method];
    let entry = &suite.detectors[&cell.detector];
    let base = ctx.scheduled(&entry.config);
    let val = ctx.split(&task.target, false, log)?;
    let target = ctx.split(&task.target, true, log)?;
    let device = ctx.device;
    let adapt_epochs = suite.schedule.adapt_epochs;
    let eval = |det: &Detector, log: &mut Log| -> Result<ApSummary> {
        let prep = Arc::new(Preprocessor::new(det.cfg())?);
        let ap = adapt::evaluate(det, prep, &val, &dir.join("val_detections.jsonl"))?;
        log.line(format!("target val ({} frames): {}", val.len(), ap.one_line()));
        Ok(ap)
    };
    let mut with_ros = base.clone();
    if method.ros {
        with_ros.train.augment.insert(0, AugmentConfig::RandomObjectScaling(RandomObjectScalingConfig::default()));
    }
    let source_model = |cfg: &DetectorConfig, log: &mut Log| -> Result<PathBuf> {
        let what = if method.ros { "source_ros" } else { "source" };
        ctx.trained(&format!("{what}_{}_{}", task.source, cell.detector), cfg, &[&task.source], None, log)
    };
    let target_infos = target.infos()?;
    let target_shift = if suite.schedule.match_sensor_height {
        let source = ctx.split(&task.source, true, log)?;
        let (hs, _) = median_sensor_height(&source, 64)?;
        let (ht, _) = median_sensor_height(&target, 64)?;
        let z = base.shift_z + (ht - hs);
        log.line(format!("target frames: shift_z {z:.2} m (median sensor height: source {hs:.2} m, target {ht:.2} m)"));
        z
    } else {
        base.shift_z
    };
    // A config whose frames are the target's.
    let on_target = |cfg: &DetectorConfig| DetectorConfig { shift_z: target_shift, ..cfg.clone() };
    let mut outcome = Outcome::default();
    match method.kind {
        MethodKind::SourceOnly => {
            let ck = source_model(&base, log)?;
            outcome.ap = eval(&load(&ck, Some(&on_target(&base)), device)?, log)?;
        }
        MethodKind::TargetOnly => {
            let cfg = on_target(&base);
            let ck =
                ctx.trained(&format!("target_{}_{}", task.target, cell.detector), &cfg, &[&task.target], None, log)?;
            outcome.ap = eval(&load(&ck, None, device)?, log)?;
        }
        MethodKind::Combined => {
            // One config for both domains' frames: the detector's own shift (no height matching).
            let name = format!("combined_{}_{}_{}", task.source, task.target, cell.detector);
            let ck = ctx.trained(&name, &base, &[&task.source, &task.target], None, log)?;
            outcome.ap = eval(&load(&ck, None, device)?, log)?;
        }
        MethodKind::Sn => {
            let source = ctx.split(&task.source, true, log)?;
            let (s, t) = (mean_sizes(&source.infos()?, &base), mean_sizes(&target_infos, &base));
            let mut sn = StatisticalNormalizationConfig::default();
            for (class, (ts, _)) in &t {
                if let Some((ss, _)) = s.get(class) {
                    sn.size_delta_m.insert(class.clone(), [ts[0] - ss[0], ts[1] - ss[1], ts[2] - ss[2]]);
                }
            }
            log.line(format!("SN: size shift target − source per class {:?}", sn.size_delta_m));
            let mut cfg = base.clone();
            cfg.train.augment.insert(0, AugmentConfig::StatisticalNormalization(sn));
            let ck = ctx.trained(
                &format!("sn_{}_{}_{}", task.source, task.target, cell.detector),
                &cfg,
                &[&task.source],
                None,
                log,
            )?;
            outcome.ap = eval(&load(&ck, Some(&on_target(&cfg)), device)?, log)?;
        }
        MethodKind::St3d | MethodKind::St3dPp | MethodKind::Redb => {
            let ck = source_model(&with_ros, log)?;
            let pp = method.kind == MethodKind::St3dPp;
            // ST3D++ ranks pseudo-labels by its hybrid score (no weights involved: same checkpoint).
            let mut cfg = with_ros.clone();
            if pp {
                if let Some(r) = cfg.roi_head.as_mut() {
                    r.score_fusion = ScoreFusion::Hybrid;
                }
            }
            let mut det = load(&ck, Some(&on_target(&cfg)), device)?;
            let st = self_training_config(method, adapt_epochs);
            let source = if st.source_assisted {
                let s = ctx.split(&task.source, true, log)?;
                let prep = Arc::new(Preprocessor::new(&cfg)?);
                let (augments, _) = train::build_augments(&prep, &s)?;
                Some(pi3det_adapt::ka::DomainData { subset: s, prep, augments: Arc::new(augments) })
            } else {
                None
            };
            let labels_cfg = st.labels.clone();
            let redb_cfg = method.redb.clone().unwrap_or_default();
            let kind = method.kind;
            let target_ref = &target;
            let mut labeller = |d: &Detector| -> pi3det_nn::Result<Vec<FrameDetections>> {
                let prep = Arc::new(Preprocessor::new(d.cfg())?);
                let labels = pseudo_labels::generate(d, prep, target_ref, &labels_cfg, &mut |_, _| {})?;
                if kind != MethodKind::Redb {
                    return Ok(labels);
                }
                redb_select(d, target_ref, labels, labels_cfg.positive_score, &redb_cfg)
            };
            let runner =
                SelfTraining { config: st, source, target: target.clone(), target_gt: Some(&target_infos), device };
            let r = runner.run(&mut det, &mut labeller, &dir.join("self_training"), &mut |_| {})?;
            log_rounds(log, &r);
            outcome.pseudo_labels = rounds_json(&r);
            outcome.ap = eval(&det, log)?;
        }
        MethodKind::Ms3dPp => {
            let ck = source_model(&with_ros, log)?;
            let mut det = load(&ck, Some(&on_target(&with_ros)), device)?;
            let st = self_training_config(method, adapt_epochs);
            let mut checkpoints = vec![ck.clone()];
            for round in 0..method.rounds.max(1) {
                let views = [
                    View { flip_y: false, yaw_rad: 0.0 },
                    View { flip_y: true, yaw_rad: 0.0 },
                    View { flip_y: false, yaw_rad: 15f64.to_radians() },
                    View { flip_y: false, yaw_rad: -15f64.to_radians() },
                ];
                let fusion = FusionConfig::default();
                let tracking = TrackingConfig::default();
                let e = ensemble(
                    &EnsembleOptions {
                        subset: &target,
                        infos: &target_infos,
                        checkpoints: &checkpoints,
                        views: &views,
                        level: pi3det_nn::preprocess::Level::Off,
                        shift_z: Some(target_shift),
                        fusion,
                        min_members: None,
                        tracking: &tracking,
                        frame_rate: Some(10.0),
                        min_score: st.labels.ignore_score,
                        batch_size: 4,
                        device,
                        // The checkpoints' own: they were trained by this benchmark.
                        precision: None,
                    },
                    &mut |_, _| Ok(()),
                )?;
                log.line(format!(
                    "MS3D++ round {}: {} inputs → {} fused → {} tracked → {} labels",
                    round + 1,
                    e.inputs.len(),
                    e.fused.num_boxes(),
                    e.tracked.labels.num_boxes(),
                    e.final_labels.num_boxes()
                ));
                let fixed: Vec<FrameDetections> = target_infos
                    .iter()
                    .map(|info| FrameDetections {
                        info: info.clone(),
                        objects: e.final_labels.frames.get(&info.id).cloned().unwrap_or_default(),
                    })
                    .collect();
                let mut labeller = |_: &Detector| -> pi3det_nn::Result<Vec<FrameDetections>> { Ok(fixed.clone()) };
                let runner = SelfTraining {
                    config: st.clone(),
                    source: None,
                    target: target.clone(),
                    target_gt: Some(&target_infos),
                    device,
                };
                let round_dir = dir.join(format!("round_{}", round + 1));
                let r = runner.run(&mut det, &mut labeller, &round_dir, &mut |_| {})?;
                log_rounds(log, &r);
                outcome.pseudo_labels.extend(rounds_json(&r));
                checkpoints.push(round_dir.join("final.safetensors"));
            }
            outcome.ap = eval(&det, log)?;
        }
        MethodKind::Pi3detNet => {
            let mut cfg = entry.pi3det_net.clone().expect("a checked suite has the pi3det_net config");
            cfg.detector = ctx.scheduled(&cfg.detector);
            if let Some(e) = adapt_epochs {
                cfg.ka.epochs = e;
            }
            let pa = ctx.trained(
                &format!("pa_{}_{}", task.source, cell.detector),
                &cfg.detector,
                &[&task.source],
                Some("pa"),
                log,
            )?;
            let source = ctx.split(&task.source, true, log)?;
            let mut msgs = Vec::new();
            let report = adapt::run(
                AdaptOptions {
                    config: cfg,
                    source,
                    target: target.clone(),
                    val: Some(val.clone()),
                    out_dir: dir.join("adapt"),
                    device,
                    pa_ckpt: Some(pa),
                    resume: false,
                    stop_after: None,
                    source_only: None,
                    vpp_diagnostics: true,
                },
                &mut |e| match e {
                    adapt::AdaptEvent::Message(m) => msgs.push(m),
                    adapt::AdaptEvent::Stage(s) => msgs.push(format!("stage: {s}")),
                    adapt::AdaptEvent::KaEpoch(k) => {
                        msgs.push(format!("  KA epoch {} loss {:.3} ({:.0} s)", k.epoch + 1, k.mean_loss, k.seconds))
                    }
                    _ => {}
                },
            )?;
            for m in msgs {
                log.line(m);
            }
            if let Some(s) = &report.source_only {
                log.line(format!("PA model on target val: {}", s.one_line()));
            }
            outcome.pseudo_labels =
                report.pseudo_label_quality.iter().map(|q| serde_json::to_value(q).unwrap_or_default()).collect();
            outcome.ap = report.adapted.clone().context("the adaptation run gave no evaluation")?;
            log.line(format!("target val ({} frames): {}", val.len(), outcome.ap.one_line()));
        }
    }
    Ok(outcome)
}

/// REDB's selection over `labels` (positives only; the rest stay in the ignored band):
/// examination by the mirrored view, points per box from the frames, then [`redb::select`].
fn redb_select(
    det: &Detector,
    target: &Subset,
    mut labels: Vec<FrameDetections>,
    positive: f64,
    cfg: &redb::RedbConfig,
) -> pi3det_nn::Result<Vec<FrameDetections>> {
    let prep = Preprocessor::new(det.cfg())?;
    let mirrored = detect_in_view(det, prep, target, View { flip_y: true, yaw_rad: 0.0 }, 4)
        .map_err(|e| pi3det_nn::NnError::Input(format!("REDB examination: {e:#}")))?;
    let mut cands = Vec::new();
    let mut slots = Vec::new();
    for (fi, (f, m)) in labels.iter().zip(&mirrored).enumerate() {
        let positives: Vec<usize> =
            (0..f.objects.len()).filter(|&k| f.objects[k].score.unwrap_or(1.0) >= positive).collect();
        if positives.is_empty() {
            continue;
        }
        let frame = target.dataset.load(target.indices[fi]).map_err(pi3det_nn::NnError::from)?;
        let pts: Vec<[f64; 3]> = frame.points.xyz_f64().collect();
        for k in positives {
            let o: &Object = &f.objects[k];
            let examination_iou = m
                .objects
                .iter()
                .filter(|x| x.name == o.name)
                .map(|x| pi3det_geometry::iou_3d(&x.box3d, &o.box3d))
                .fold(0.0, f64::max);
            let points = pts.iter().filter(|p| o.box3d.contains(**p)).count();
            cands.push(Candidate {
                class: det.cfg().class_index(&o.name).unwrap_or(0),
                score: o.score.unwrap_or(1.0),
                examination_iou,
                range_m: o.box3d.x.hypot(o.box3d.y),
                points,
            });
            slots.push((fi, k));
        }
    }
    let keep = redb::select(&cands, cfg);
    for ((fi, k), kept) in slots.into_iter().zip(keep) {
        if !kept {
            labels[fi].objects[k].score = Some(0.0);
        }
    }
    Ok(labels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv_is_stable() {
        assert_eq!(fnv(""), "cbf29ce484222325");
        assert_eq!(fnv("a"), "af63dc4c8601ec8c");
    }
}
