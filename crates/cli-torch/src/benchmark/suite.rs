//! A benchmark suite (`configs/benchmark/<suite>.toml`): datasets (simulator recipes or folders
//! on disk), tasks (source → target), methods and detectors. Every (task, method, detector) is a
//! [`Cell`]; the suite is checked whole — unknown methods, datasets, missing paths or configs —
//! before any cell runs.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use pi3det_adapt::baselines::redb::RedbConfig;
use pi3det_adapt::baselines::self_training::SelfTrainingConfig;
use pi3det_adapt::pipeline::AdaptConfig;
use pi3det_nn::config::DetectorConfig;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct SuiteFile {
    name: String,
    #[serde(default)]
    seed: u64,
    detectors: BTreeMap<String, DetectorFile>,
    datasets: BTreeMap<String, DatasetSpec>,
    tasks: Vec<TaskSpec>,
    methods: Vec<MethodSpec>,
    #[serde(default)]
    schedule: Schedule,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct DetectorFile {
    /// The baselines' detector config (relative to the suite file). Absent: the Pi3DET-Net
    /// config's detector without its components (RPJ, GTD, PFA), so every row runs one network
    /// and one post-processing and Pi3DET-Net adds only what the paper adds.
    config: Option<PathBuf>,
    /// The Pi3DET-Net config on this detector (`pi3det adapt`'s), for the `pi3det_net` method.
    pi3det_net: Option<PathBuf>,
    /// Accept a `config` whose post-processing (`[post]`, test-time augmentation, precision, RoI
    /// head) differs from the Pi3DET-Net detector's; the table then flags the comparison.
    #[serde(default)]
    mixed_post: bool,
}

/// Where a dataset's frames come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetSpec {
    /// Simulated with the embedded simulator.
    pub sim: Option<SimSpec>,
    /// A dataset on disk (any format the readers open; relative to the suite file).
    pub path: Option<PathBuf>,
    #[serde(default = "train_split")]
    pub train_split: String,
    #[serde(default = "val_split")]
    pub val_split: String,
}

fn train_split() -> String {
    "train".into()
}
fn val_split() -> String {
    "val".into()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSpec {
    /// vehicle, drone or quadruped.
    pub platform: String,
    /// os1-64 (Pi3DET), nuscenes-32, hdl-64 (KITTI).
    #[serde(default = "os1")]
    pub sensor: String,
    pub sequences: u32,
    pub val_sequences: u32,
    pub frames: u32,
    /// Simulation seed (default: the suite's).
    pub seed: Option<u64>,
    /// Simulator settings (a TOML as `pi3det simulate --print-config` writes, only the keys that
    /// differ needed; relative to the suite file), e.g. another drone's flight heights.
    pub config: Option<PathBuf>,
    /// Simulate the validation split on its own from this seed, with stratified layouts (every
    /// scene layout in turn), so it is the same for every suite seed; absent: the last
    /// `val_sequences` of the training simulation.
    pub val_seed: Option<u64>,
}

impl SimSpec {
    /// What makes the `train` (or `val`) split of this dataset under suite seed `suite_seed`:
    /// a split simulated from a fixed `val_seed` does not depend on the suite's seed.
    pub fn split_key(&self, train: bool, suite_seed: u64) -> String {
        match (train, self.val_seed) {
            // The validation sequences are the last of `sequences` (a sequence depends on the
            // seed, the platform and its index), so the total is part of the key.
            (false, Some(v)) => format!(
                "{} {}: sequences {}..{} × {} frames, val seed {v} stratified",
                self.platform,
                self.sensor,
                self.sequences - self.val_sequences,
                self.sequences,
                self.frames
            ),
            _ => format!("{self:?} seed {}", self.seed.unwrap_or(suite_seed)),
        }
    }
}

fn os1() -> String {
    "os1-64".into()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskSpec {
    pub name: String,
    pub source: String,
    pub target: String,
}

/// The methods of the paper's tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MethodKind {
    SourceOnly,
    TargetOnly,
    Combined,
    St3d,
    St3dPp,
    Sn,
    Redb,
    Ms3dPp,
    Pi3detNet,
}

impl MethodKind {
    pub fn label(self) -> &'static str {
        match self {
            Self::SourceOnly => "Source Only",
            Self::TargetOnly => "Target Only",
            Self::Combined => "Combined",
            Self::St3d => "ST3D",
            Self::St3dPp => "ST3D++",
            Self::Sn => "SN",
            Self::Redb => "REDB",
            Self::Ms3dPp => "MS3D++",
            Self::Pi3detNet => "Pi3DET-Net",
        }
    }

    /// Methods that train with target labels (upper bounds; not ranked).
    pub fn uses_target_labels(self) -> bool {
        matches!(self, Self::TargetOnly | Self::Combined)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MethodSpec {
    pub kind: MethodKind,
    /// Row label (default: the method's name, "w/ ROS" added when `ros`).
    pub name: Option<String>,
    /// Random Object Scaling in the source training (ST3D, ST3D++).
    #[serde(default)]
    pub ros: bool,
    /// Self-training settings (ST3D, ST3D++, REDB, MS3D++); absent: the method's defaults.
    pub self_training: Option<SelfTrainingConfig>,
    pub redb: Option<RedbConfig>,
    /// Pi3DET-Net: the components this row keeps (`rpj`, `vpp`, `gtd`, `pfa`; absent: all of its
    /// config's), for the ablation (paper Table 5).
    pub components: Option<Vec<pi3det_adapt::pipeline::Component>>,
    /// MS3D++: label → self-train rounds.
    #[serde(default = "one")]
    pub rounds: usize,
    /// MS3D++: the source-trained detectors whose boxes are fused (each seen in 4 views). MS3D++
    /// fuses several different detectors; absent: the row's detector at the suite's seed and
    /// the next, two members of one architecture.
    #[serde(default)]
    pub ensemble: Vec<MemberSpec>,
    /// MS3D++: accept an ensemble of one detector (its views only), which is not MS3D++.
    #[serde(default)]
    pub allow_single_member: bool,
}

/// One member of an MS3D++ ensemble: a detector config trained on the source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MemberSpec {
    /// Its config (relative to the suite file); absent: the row's own detector.
    pub config: Option<PathBuf>,
    /// Added to the suite's seed for this member's training.
    #[serde(default)]
    pub seed_offset: u64,
}

impl MethodSpec {
    /// MS3D++'s members: the given ones, else the row's detector at two seeds.
    pub fn members(&self) -> Vec<MemberSpec> {
        if self.ensemble.is_empty() {
            vec![MemberSpec { config: None, seed_offset: 0 }, MemberSpec { config: None, seed_offset: 1 }]
        } else {
            self.ensemble.clone()
        }
    }
}

fn one() -> usize {
    1
}

impl MethodSpec {
    pub fn label(&self) -> String {
        match (&self.name, &self.components) {
            (Some(n), _) => n.clone(),
            (None, Some(c)) if c.is_empty() => format!("{} (KA alone)", self.kind.label()),
            (None, Some(c)) => {
                let names: Vec<String> = c.iter().map(|x| x.to_string()).collect();
                format!("{} ({})", self.kind.label(), names.join(" + "))
            }
            (None, None) if self.ros => format!("{} (w/ ROS)", self.kind.label()),
            (None, None) => self.kind.label().to_string(),
        }
    }

    /// The label as a folder name.
    pub fn slug(&self) -> String {
        slug(&self.label())
    }
}

pub fn slug(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if c == '+' {
            out.push('p');
        } else if !out.ends_with('_') && !out.is_empty() {
            out.push('_');
        }
    }
    out.trim_end_matches('_').to_string()
}

/// Training budgets that replace the detector configs' (so a suite sizes every method alike).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Schedule {
    /// Epochs of source (and target-only, combined, Pi3DET-Net PA) training.
    pub epochs: Option<usize>,
    /// Epochs of self-training and of Pi3DET-Net's KA.
    pub adapt_epochs: Option<usize>,
    /// At most this many training frames per split (0: all).
    pub max_train_frames: usize,
    /// At most this many validation frames (0: all).
    pub max_val_frames: usize,
    /// Methods without Virtual Platform Pose see the target's frames shifted in z by the
    /// difference of the two datasets' median sensor heights (ground-plane fits), so the target's
    /// ground lies where the source's did — the per-dataset `SHIFT_COOR` of ST3D's and OpenPCDet's
    /// cross-dataset configs. Off: every frame gets the detector config's `shift_z`.
    pub match_sensor_height: bool,
    /// Target-only trains as many steps as the source model (its epochs scaled by the ratio of
    /// the two training splits' sizes), not the same number of epochs over a smaller split.
    pub equal_steps: bool,
}

/// Epochs over `frames` frames that take at least `steps` steps (one frame per step).
pub fn epochs_for_steps(steps: usize, frames: usize) -> usize {
    if frames == 0 {
        return 0;
    }
    steps.div_ceil(frames).max(1)
}

/// A checked suite.
#[derive(Debug, Clone)]
pub struct Suite {
    pub name: String,
    pub seed: u64,
    pub path: PathBuf,
    pub detectors: BTreeMap<String, DetectorEntry>,
    pub datasets: BTreeMap<String, DatasetSpec>,
    pub tasks: Vec<TaskSpec>,
    pub methods: Vec<MethodSpec>,
    pub schedule: Schedule,
}

#[derive(Debug, Clone)]
pub struct DetectorEntry {
    pub config: DetectorConfig,
    pub pi3det_net: Option<AdaptConfig>,
    /// The baselines' post-processing differs from Pi3DET-Net's (`mixed_post`): flagged.
    pub mixed_post: bool,
}

/// What decides a detector's boxes after training besides its weights: `[post]` (test-time
/// augmentation included), the inference precision and the RoI head.
fn post_processing(c: &DetectorConfig) -> String {
    let mut out = toml::to_string(&c.post).unwrap_or_default();
    out.push_str(&format!("\nprecision {:?}\n", c.precision));
    out.push_str(&toml::to_string(&c.roi_head).unwrap_or_default());
    out
}

/// The Pi3DET-Net config's detector without RPJ, GTD and PFA: the base every other row runs.
pub fn base_detector(a: &AdaptConfig) -> DetectorConfig {
    use pi3det_adapt::pipeline::Component;
    let mut d = a.without(&[Component::Rpj, Component::Vpp, Component::Gtd, Component::Pfa]).detector;
    d.name = format!("{}_base", d.name);
    d
}

/// One job: a method with a detector on a task.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Cell {
    pub task: String,
    pub method: usize,
    pub detector: String,
}

impl Suite {
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading the suite {}", path.display()))?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and checks a suite; relative paths are relative to `path`'s folder.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self> {
        let f: SuiteFile = toml::from_str(text).with_context(|| format!("suite {}", path.display()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let rel = |p: &Path| if p.is_absolute() { p.to_path_buf() } else { dir.join(p) };
        let ctx = |what: String| format!("suite {}: {what}", path.display());
        if f.tasks.is_empty() || f.methods.is_empty() || f.detectors.is_empty() {
            bail!(ctx("needs at least one task, method and detector".into()));
        }
        let mut datasets = BTreeMap::new();
        for (name, d) in &f.datasets {
            let mut d = d.clone();
            match (d.sim.as_mut(), &d.path) {
                (Some(s), None) => {
                    if pi3det_data::Platform::parse(&s.platform) == pi3det_data::Platform::Unknown {
                        bail!(ctx(format!(
                            "dataset {name}: unknown platform {:?} (vehicle, drone, quadruped)",
                            s.platform
                        )));
                    }
                    pi3det_sim::SensorPreset::parse(&s.sensor)
                        .map_err(|e| anyhow::anyhow!(ctx(format!("dataset {name}: {e}"))))?;
                    if let Some(p) = &s.config {
                        let p = rel(p);
                        pi3det_sim::SimConfig::load(&p)
                            .map_err(|e| anyhow::anyhow!(ctx(format!("dataset {name}: {e}"))))?;
                        s.config = Some(p);
                    }
                    if s.sequences <= s.val_sequences || s.val_sequences == 0 || s.frames == 0 {
                        bail!(ctx(format!("dataset {name}: needs 0 < val_sequences < sequences and frames > 0")));
                    }
                }
                (None, Some(p)) => {
                    let p = rel(p);
                    if !p.exists() {
                        bail!(ctx(format!("dataset {name}: {} does not exist", p.display())));
                    }
                    d.path = Some(p);
                }
                _ => bail!(ctx(format!("dataset {name}: give exactly one of `sim` and `path`"))),
            }
            datasets.insert(name.clone(), d);
        }
        let mut names = BTreeSet::new();
        for t in &f.tasks {
            if !names.insert(&t.name) || slug(&t.name) != t.name {
                bail!(ctx(format!("task {:?}: names must be unique and lowercase [a-z0-9_]", t.name)));
            }
            for d in [&t.source, &t.target] {
                if !datasets.contains_key(d) {
                    bail!(ctx(format!(
                        "task {}: unknown dataset {d:?} (the suite defines {:?})",
                        t.name,
                        datasets.keys().collect::<Vec<_>>()
                    )));
                }
            }
        }
        let mut labels = BTreeSet::new();
        for m in &f.methods {
            if !labels.insert(m.slug()) {
                bail!(ctx(format!("method {:?} appears twice (give one a `name`)", m.label())));
            }
            if let Some(st) = &m.self_training {
                st.validate().map_err(|e| anyhow::anyhow!(ctx(format!("method {}: {e}", m.label()))))?;
            }
        }
        for m in &f.methods {
            if m.components.is_some() && m.kind != MethodKind::Pi3detNet {
                bail!(ctx(format!("method {}: `components` are Pi3DET-Net's", m.label())));
            }
        }
        let mut methods = f.methods.clone();
        for m in &mut methods {
            if m.kind != MethodKind::Ms3dPp {
                if !m.ensemble.is_empty() {
                    bail!(ctx(format!("method {}: `ensemble` is MS3D++'s", m.label())));
                }
                continue;
            }
            let distinct: BTreeSet<String> = m.members().iter().map(|x| format!("{x:?}")).collect();
            if distinct.len() < 2 && !m.allow_single_member {
                bail!(ctx(format!(
                    "method {}: an MS3D++ ensemble needs at least two different members (MS3D++ fuses several \
                     detectors); list them in `ensemble` or set `allow_single_member = true`",
                    m.label()
                )));
            }
            for x in &mut m.ensemble {
                x.config = x.config.as_deref().map(rel);
            }
        }
        let mut detectors = BTreeMap::new();
        for (name, d) in &f.detectors {
            if slug(name) != *name {
                bail!(ctx(format!("detector {name:?}: names must be lowercase [a-z0-9_]")));
            }
            let pi3det_net = match &d.pi3det_net {
                Some(p) => Some(
                    AdaptConfig::from_file(&rel(p))
                        .with_context(|| ctx(format!("detector {name}: pi3det_net {}", rel(p).display())))?,
                ),
                None => None,
            };
            if pi3det_net.is_none() && f.methods.iter().any(|m| m.kind == MethodKind::Pi3detNet) {
                bail!(ctx(format!("detector {name}: the pi3det_net method needs a `pi3det_net` config for it")));
            }
            let config = match (&d.config, &pi3det_net) {
                (Some(p), _) => DetectorConfig::from_file(&rel(p))
                    .with_context(|| ctx(format!("detector {name}: config {}", rel(p).display())))?,
                (None, Some(a)) => base_detector(a),
                (None, None) => bail!(ctx(format!("detector {name}: give a `config`, a `pi3det_net` or both"))),
            };
            let mixed = pi3det_net.as_ref().is_some_and(|a| post_processing(&a.detector) != post_processing(&config));
            if mixed && !d.mixed_post {
                bail!(ctx(format!(
                    "detector {name}: its `config` post-processes otherwise than the `pi3det_net` detector \
                     (`[post]`, test-time augmentation, precision or RoI head differ), so rows would differ by more \
                     than the method; leave `config` out (the Pi3DET-Net detector without its components) or \
                     set `mixed_post = true` to compare anyway"
                )));
            }
            detectors.insert(name.clone(), DetectorEntry { config, pi3det_net, mixed_post: mixed });
        }
        for m in &methods {
            for x in m.ensemble.iter().filter_map(|x| x.config.as_ref()) {
                let c = DetectorConfig::from_file(x)
                    .with_context(|| ctx(format!("method {}: ensemble member {}", m.label(), x.display())))?;
                for (name, d) in &detectors {
                    if c.classes != d.config.classes || c.shift_z != d.config.shift_z {
                        bail!(ctx(format!(
                            "method {}: ensemble member {} detects {:?} at shift_z {} but detector {name} {:?} at {}",
                            m.label(),
                            x.display(),
                            c.classes,
                            c.shift_z,
                            d.config.classes,
                            d.config.shift_z
                        )));
                    }
                }
            }
        }
        Ok(Self {
            name: f.name,
            seed: f.seed,
            path: path.to_path_buf(),
            detectors,
            datasets,
            tasks: f.tasks,
            methods,
            schedule: f.schedule,
        })
    }

    /// Every cell, in table order (task, method, detector).
    pub fn cells(&self) -> Vec<Cell> {
        let mut out = Vec::new();
        for t in &self.tasks {
            for m in 0..self.methods.len() {
                for d in self.detectors.keys() {
                    out.push(Cell { task: t.name.clone(), method: m, detector: d.clone() });
                }
            }
        }
        out
    }

    /// `task/method/detector`.
    pub fn cell_id(&self, c: &Cell) -> String {
        format!("{}/{}/{}", c.task, self.methods[c.method].slug(), c.detector)
    }

    pub fn task(&self, name: &str) -> &TaskSpec {
        self.tasks.iter().find(|t| t.name == name).expect("a checked suite's task")
    }
}

/// `i/N` (1-based): the cells whose position in table order is `i − 1` modulo `N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let (i, n) = s.split_once('/').ok_or_else(|| format!("--shard {s:?}: expected i/N, e.g. 1/4"))?;
        let (i, n): (usize, usize) = (
            i.trim().parse().map_err(|_| format!("--shard {s:?}: i is not a number"))?,
            n.trim().parse().map_err(|_| format!("--shard {s:?}: N is not a number"))?,
        );
        if n == 0 || i == 0 || i > n {
            return Err(format!("--shard {s:?}: need 1 ≤ i ≤ N"));
        }
        Ok(Self { index: i - 1, count: n })
    }
}

impl Shard {
    pub fn take<T: Clone>(&self, items: &[T]) -> Vec<T> {
        items.iter().enumerate().filter(|(k, _)| k % self.count == self.index).map(|(_, c)| c.clone()).collect()
    }
}

/// Whether `id` matches one of `patterns` (`*` matches any run of characters, also `/`).
pub fn matches_any(id: &str, patterns: &[String]) -> bool {
    patterns.iter().any(|p| glob(p.as_bytes(), id.as_bytes()))
}

fn glob(p: &[u8], s: &[u8]) -> bool {
    match p.split_first() {
        None => s.is_empty(),
        Some((b'*', rest)) => (0..=s.len()).any(|k| glob(rest, &s[k..])),
        Some((c, rest)) => s.split_first().is_some_and(|(d, srest)| c == d && glob(rest, srest)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_every_cell_once() {
        let cells: Vec<usize> = (0..23).collect();
        for n in 1..6 {
            let mut seen: Vec<usize> =
                (1..=n).flat_map(|i| format!("{i}/{n}").parse::<Shard>().unwrap().take(&cells)).collect();
            seen.sort_unstable();
            assert_eq!(seen, cells, "N = {n}");
        }
        for bad in ["0/2", "3/2", "1", "a/b", "1/0"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn target_only_gets_the_source_models_steps() {
        // The mini suite: 20 vehicle sequences × 30 frames for 3 epochs against 8 × 30 target frames.
        let source_steps = 600 * 3;
        let e = epochs_for_steps(source_steps, 240);
        assert_eq!(e, 8);
        assert!(e * 240 >= source_steps && (e - 1) * 240 < source_steps);
        assert_eq!(epochs_for_steps(10, 20), 1);
        assert_eq!(epochs_for_steps(10, 0), 0);
    }

    #[test]
    fn a_validation_split_with_its_own_seed_is_the_same_for_every_suite_seed() {
        let sim = SimSpec {
            platform: "drone".into(),
            sensor: "os1-64".into(),
            sequences: 20,
            val_sequences: 12,
            frames: 30,
            seed: None,
            val_seed: Some(1000),
            config: None,
        };
        assert_eq!(sim.split_key(false, 0), sim.split_key(false, 1));
        assert_ne!(sim.split_key(true, 0), sim.split_key(true, 1));
        let joint = SimSpec { val_seed: None, ..sim };
        assert_ne!(joint.split_key(false, 0), joint.split_key(false, 1));
    }

    #[test]
    fn globs_and_slugs() {
        assert!(matches_any("v2d/st3d/pp", &["v2d/*".into()]));
        assert!(matches_any("v2d/st3d/pp", &["*/st3d/*".into()]));
        assert!(!matches_any("v2d/st3d_w_ros/pp", &["*/st3d/*".into()]));
        assert!(matches_any("v2d/st3d/pp", &["v2d/st3d/pp".into()]));
        assert_eq!(slug("ST3D++ (w/ ROS)"), "st3dpp_w_ros");
        assert_eq!(slug("Pi3DET-Net"), "pi3det_net");
    }
}
