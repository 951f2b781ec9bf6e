//! Frames → batches: reading, class mapping and z shift, augmentation, pillarization and target
//! assignment, in parallel over a batch's frames (rayon) on a background thread that keeps
//! `prefetch` batches ready while the network trains.

use std::path::Path;
use std::sync::mpsc::{sync_channel, Receiver};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

use pi3det_data::{Dataset, Frame, FrameInfo, Platform};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::augment::Augment;
use crate::dense_heads::{BatchTargets, FrameTargets};
use crate::error::{NnError, Result};
use crate::pillarize::{Grid, Pillarizer, Pillars};
use crate::post_process::ground_fit::{PointIndex, INDEX_CELL_M};
use crate::preprocess::{Inputs, Preprocessor};
use pi3det_geometry::{Box3d, Pose, View};

/// A dataset restricted to some of its frames.
#[derive(Clone)]
pub struct Subset {
    pub dataset: Arc<dyn Dataset>,
    pub indices: Vec<usize>,
}

impl Subset {
    pub fn all(dataset: Arc<dyn Dataset>) -> Self {
        let indices = (0..dataset.len()).collect();
        Self { dataset, indices }
    }

    pub fn len(&self) -> usize {
        self.indices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// Keeps the frames of one platform.
    pub fn platform(self, platform: Platform) -> Result<Self> {
        let mut keep = Vec::new();
        for &i in &self.indices {
            if self.dataset.info(i)?.platform == platform {
                keep.push(i);
            }
        }
        Ok(Self { indices: keep, ..self })
    }

    /// Keeps at most `n` frames spread evenly over the subset (0: all).
    pub fn take_spread(self, n: usize) -> Self {
        if n == 0 || n >= self.indices.len() {
            return self;
        }
        let len = self.indices.len();
        let indices = (0..n).map(|k| self.indices[k * len / n]).collect();
        Self { indices, ..self }
    }

    pub fn infos(&self) -> Result<Vec<FrameInfo>> {
        self.indices.par_iter().map(|&i| self.dataset.info(i).map_err(NnError::from)).collect()
    }
}

/// Opens a dataset for a split: a folder holding `pi3det_infos_<split>.pkl` opens that file only;
/// anything else is opened as `pi3det_data::open` does.
pub fn open_split(path: &Path, split: Option<&str>) -> Result<Arc<dyn Dataset>> {
    if let Some(split) = split {
        let file = path.join(format!("pi3det_infos_{split}.pkl"));
        if path.is_dir() && file.is_file() {
            return Ok(Arc::from(pi3det_data::open(&file)?));
        }
    }
    Ok(Arc::from(pi3det_data::open(path)?))
}

/// Per-frame RNG seed from the run seed, epoch and frame index (splitmix64).
pub fn frame_seed(seed: u64, epoch: u64, index: u64) -> u64 {
    let mut z = seed ^ epoch.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A prepared batch.
pub struct Batch {
    pub inputs: Inputs,
    /// Present when training.
    pub targets: Option<BatchTargets>,
    /// Per frame: the transform into the detector's frame (detections go back through its
    /// inverse).
    pub detector_from_lidar: Vec<Pose>,
    /// Per frame, when training: the (augmented) ground truth in the detector's frame, for
    /// stages that build targets from the network's own proposals.
    pub gt: Vec<FrameGt>,
    /// The frames' infos (for writing detections).
    pub infos: Vec<FrameInfo>,
    /// Per frame at inference, when the config fits boxes to the points: the points' index.
    pub point_index: Vec<Option<PointIndex>>,
    /// Seconds spent reading and preparing the batch on the loader thread.
    pub prep_seconds: f64,
    pub num_pillars: usize,
    pub dropped_points: usize,
    /// Network inputs per frame: 1, or with test-time views ([`LoaderOptions::views`]) 1 + their
    /// number; a frame's inputs are neighbours in `inputs` (the frame as it is first).
    pub views_per_frame: usize,
}

/// Ground-truth boxes of a frame and their class indices, and the ignored boxes (with theirs)
/// that no stage may treat as background ([`crate::augment::Sample::ignored`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameGt {
    pub boxes: Vec<Box3d>,
    pub classes: Vec<usize>,
    /// Roll and pitch (rad) Random Platform Jitter applied to the frame (the target of the GTD
    /// rotation loss), when it did.
    pub platform_jitter: Option<[f64; 2]>,
    pub ignored: Vec<Box3d>,
    pub ignored_classes: Vec<usize>,
}

/// A frame prepared for the network.
pub struct PreparedFrame {
    pub pillars: Pillars,
    /// At inference: the frame seen through each of [`LoaderOptions::views`].
    pub view_pillars: Vec<Pillars>,
    /// At inference: the frame's points (detector frame) indexed for the vertical box fit
    /// ([`crate::post_process::ground_fit`]).
    pub point_index: Option<PointIndex>,
    pub targets: Option<FrameTargets>,
    pub detector_from_lidar: Pose,
    pub gt: FrameGt,
}

/// How to load.
#[derive(Clone)]
pub struct LoaderOptions {
    pub batch_size: usize,
    /// Training: shuffle, augment, build targets.
    pub train: bool,
    pub seed: u64,
    pub epoch: u64,
    pub prefetch: usize,
    pub drop_last: bool,
    /// At inference: test-time views (besides the frame as it is) each frame is also prepared
    /// in ([`crate::post_process::tta`]); empty: none.
    pub views: Vec<View>,
}

/// Prepares one frame. The augmentation list is empty at inference.
pub fn prepare_frame(
    prep: &Preprocessor,
    augments: &[Box<dyn Augment>],
    frame: &Frame,
    train: bool,
    rng_seed: u64,
) -> Result<PreparedFrame> {
    with_pillarizer(prep, |pillarizer| prepare_with(prep, pillarizer, augments, frame, train, rng_seed, &[]))?
}

thread_local! {
    // One pillarizer per thread, kept between frames: a fresh one allocates and zeroes its
    // nx·ny cell table (≈ 0.9 MB for the CPU preset) for every frame.
    static PILLARIZER: std::cell::RefCell<Option<Pillarizer>> = const { std::cell::RefCell::new(None) };
}

/// Runs `f` with this thread's pillarizer, made anew when `prep`'s grid or pillar size differs.
fn with_pillarizer<T>(prep: &Preprocessor, f: impl FnOnce(&mut Pillarizer) -> T) -> Result<T> {
    PILLARIZER.with(|cell| {
        let mut slot = cell.borrow_mut();
        let fits = slot.as_ref().is_some_and(|p| p.fits(&prep.cfg.pillars));
        if !fits {
            *slot = Some(prep.pillarizer()?);
        }
        Ok(f(slot.as_mut().expect("just set")))
    })
}

fn prepare_with(
    prep: &Preprocessor,
    pillarizer: &mut Pillarizer,
    augments: &[Box<dyn Augment>],
    frame: &Frame,
    train: bool,
    rng_seed: u64,
    views: &[View],
) -> Result<PreparedFrame> {
    let cfg = &prep.cfg;
    let mut s = prep.sample(frame, if train { cfg.train.min_points_in_gt } else { 0 });
    if train {
        let mut rng = ChaCha8Rng::seed_from_u64(rng_seed);
        for a in augments {
            a.apply(&mut s, &mut rng);
        }
        // Boxes whose centre left the grid cannot be learnt (nor ignored); headings back to
        // [−π, π).
        keep_in_grid(&prep.grid, &mut s.boxes, &mut s.classes);
        keep_in_grid(&prep.grid, &mut s.ignored, &mut s.ignored_classes);
        s.points.shuffle(&mut rng);
        let pillars = pillarizer.run(&s.points, cfg.pillars.max_pillars_train);
        if pillars.dropped_points > 0 {
            tracing::debug!("{}: {} points dropped by the pillar limits", frame.info.id, pillars.dropped_points);
        }
        let targets = Some(prep.targets(&s));
        let gt = FrameGt {
            boxes: s.boxes,
            classes: s.classes,
            platform_jitter: s.platform_jitter,
            ignored: s.ignored,
            ignored_classes: s.ignored_classes,
        };
        Ok(PreparedFrame {
            pillars,
            view_pillars: Vec::new(),
            targets,
            point_index: None,
            detector_from_lidar: s.detector_from_lidar,
            gt,
        })
    } else {
        let pillars = pillarizer.run(&s.points, cfg.pillars.max_pillars_test);
        let point_index = cfg.post.fits_to_points().then(|| PointIndex::new(&s.points, INDEX_CELL_M));
        let mut moved = Vec::new();
        let view_pillars = views
            .iter()
            .map(|v| {
                moved.clear();
                moved.extend(s.points.iter().map(|p| {
                    let (x, y) = v.apply_xy(f64::from(p[0]), f64::from(p[1]));
                    [x as f32, y as f32, p[2], p[3]]
                }));
                pillarizer.run(&moved, cfg.pillars.max_pillars_test)
            })
            .collect();
        Ok(PreparedFrame {
            pillars,
            view_pillars,
            targets: None,
            point_index,
            detector_from_lidar: s.detector_from_lidar,
            gt: FrameGt::default(),
        })
    }
}

/// Keeps the boxes (and their classes) whose centre is on the grid, headings wrapped.
fn keep_in_grid(grid: &Grid, boxes: &mut Vec<Box3d>, classes: &mut Vec<usize>) {
    let (kept, kept_classes): (Vec<Box3d>, Vec<usize>) = boxes
        .iter()
        .zip(classes.iter())
        .filter(|(b, _)| grid.contains_xy(b.x, b.y))
        .map(|(b, &c)| (b.with_wrapped_heading(), c))
        .unzip();
    *boxes = kept;
    *classes = kept_classes;
}

/// Prepares a batch of frames (rayon over the frames).
pub fn prepare_batch(
    prep: &Preprocessor,
    augments: &[Box<dyn Augment>],
    subset: &Subset,
    positions: &[usize],
    opts: &LoaderOptions,
) -> Result<Batch> {
    let t = Instant::now();
    let items: Vec<(FrameInfo, PreparedFrame)> = positions
        .par_iter()
        .map(|&pos| {
            let index = subset.indices[pos];
            let frame = subset.dataset.load(index)?;
            let seed = frame_seed(opts.seed, opts.epoch, index as u64);
            let views = if opts.train { &[][..] } else { &opts.views };
            let p = with_pillarizer(prep, |px| prepare_with(prep, px, augments, &frame, opts.train, seed, views))??;
            Ok((frame.info, p))
        })
        .collect::<Result<_>>()?;
    let pillars: Vec<&Pillars> =
        items.iter().flat_map(|x| std::iter::once(&x.1.pillars).chain(&x.1.view_pillars)).collect();
    let inputs = prep.collate_inputs(&pillars);
    let targets = if opts.train {
        let t: Vec<&FrameTargets> = items.iter().filter_map(|x| x.1.targets.as_ref()).collect();
        Some(prep.collate_targets(&t)?)
    } else {
        None
    };
    let num_pillars = pillars.iter().map(|p| p.len()).sum();
    let dropped_points = pillars.iter().map(|p| p.dropped_points).sum();
    let (infos, prepared): (Vec<FrameInfo>, Vec<PreparedFrame>) = items.into_iter().unzip();
    let (mut detector_from_lidar, mut gt, mut point_index) = (Vec::new(), Vec::new(), Vec::new());
    for p in prepared {
        detector_from_lidar.push(p.detector_from_lidar);
        gt.push(p.gt);
        point_index.push(p.point_index);
    }
    Ok(Batch {
        inputs,
        targets,
        detector_from_lidar,
        gt,
        infos,
        point_index,
        prep_seconds: t.elapsed().as_secs_f64(),
        num_pillars,
        dropped_points,
        views_per_frame: if opts.train { 1 } else { 1 + opts.views.len() },
    })
}

/// The batches of one pass over a subset, prepared on a background thread.
pub struct Loader {
    rx: Option<Receiver<Result<Batch>>>,
    handle: Option<JoinHandle<()>>,
    spawn_error: Option<String>,
    pub num_batches: usize,
}

impl Loader {
    pub fn new(
        prep: Arc<Preprocessor>,
        augments: Arc<Vec<Box<dyn Augment>>>,
        subset: Subset,
        opts: LoaderOptions,
    ) -> Self {
        let mut order: Vec<usize> = (0..subset.len()).collect();
        if opts.train {
            order.shuffle(&mut ChaCha8Rng::seed_from_u64(frame_seed(opts.seed, opts.epoch, u64::MAX)));
        }
        let bs = opts.batch_size.max(1);
        let mut batches: Vec<Vec<usize>> = order.chunks(bs).map(|c| c.to_vec()).collect();
        if opts.drop_last && batches.len() > 1 && batches.last().is_some_and(|b| b.len() < bs) {
            batches.pop();
        }
        let num_batches = batches.len();
        let (tx, rx) = sync_channel(opts.prefetch.max(1));
        let handle = std::thread::Builder::new().name("pi3det-loader".into()).spawn(move || {
            for b in batches {
                let r = prepare_batch(&prep, &augments, &subset, &b, &opts);
                let failed = r.is_err();
                if tx.send(r).is_err() || failed {
                    return;
                }
            }
        });
        match handle {
            Ok(h) => Self { rx: Some(rx), handle: Some(h), spawn_error: None, num_batches },
            Err(e) => Self { rx: None, handle: None, spawn_error: Some(e.to_string()), num_batches },
        }
    }
}

impl Iterator for Loader {
    type Item = Result<Batch>;
    fn next(&mut self) -> Option<Self::Item> {
        if let Some(e) = self.spawn_error.take() {
            return Some(Err(NnError::Loader(format!("cannot start the loader thread: {e}"))));
        }
        match self.rx.as_ref()?.recv() {
            Ok(b) => Some(b),
            Err(_) => {
                self.rx = None;
                None
            }
        }
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        // Dropping the receiver makes the thread's next send fail, so it stops.
        self.rx = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::augment::{WorldFlip, WorldFlipConfig};
    use crate::config::DetectorConfig;
    use crate::dense_heads::anchor_head::AnchorBatchTargets;
    use pi3det_data::{Object, PointCloud};

    /// Ignored boxes go through augmentation like boxes, off-grid ones are dropped, and they
    /// reach both the dense targets (−1 anchors) and the frame's GT for the second stage.
    #[test]
    fn ignored_boxes_reach_the_targets_and_the_gt() {
        let car = Box3d::new(10.0, 5.0, 0.8, 4.2, 1.9, 1.6, 0.3);
        let obj = |b: Box3d, score: Option<f64>, points: u32| Object {
            score,
            num_points: Some(points),
            ..Object::new(if b.dx > 1.0 { "Car" } else { "Pedestrian" }, b)
        };
        let mut info = FrameInfo::new("0", "x.bin".into());
        info.objects = vec![
            obj(car, None, 20),
            obj(Box3d { x: -10.0, y: -5.0, heading: 3.0, ..car }, Some(0.3), 0),
            obj(Box3d::new(45.0, 0.0, 0.8, 0.7, 0.6, 1.7, 0.0), Some(0.2), 5), // off the grid
        ];
        let pts: Vec<[f32; 4]> = (0..20).map(|k| [9.0 + 0.1 * k as f32, 5.0, 0.8, 0.5]).collect();
        let frame = Frame { info, points: PointCloud::from_xyzi(&pts) };
        let cfg = DetectorConfig::default();
        let flip: Vec<Box<dyn Augment>> =
            vec![Box::new(WorldFlip(WorldFlipConfig { along_x: true, along_y: false, probability: 1.0 }))];
        let prep = Preprocessor::new(&cfg).unwrap().with_ignore_score_below(0.5);
        let p = prepare_frame(&prep, &flip, &frame, true, 3).unwrap();
        let flipped = |b: Box3d| Box3d { y: -b.y, heading: -b.heading, ..b }.with_wrapped_heading();
        assert_eq!(p.gt.boxes, vec![flipped(car)]);
        assert_eq!(p.gt.ignored, vec![flipped(Box3d { x: -10.0, y: -5.0, heading: 3.0, ..car })]);
        assert_eq!(p.gt.ignored_classes, vec![0]);
        let ignored_anchors = |prep: &Preprocessor, p: PreparedFrame| {
            let t = prep.collate_targets(&[p.targets.as_ref().unwrap()]).unwrap();
            let t = t.downcast_ref::<AnchorBatchTargets>().unwrap();
            t.labels.eq(-1).sum(tch::Kind::Int64).int64_value(&[])
        };
        let plain = Preprocessor::new(&cfg).unwrap();
        let q = prepare_frame(&plain, &flip, &frame, true, 3).unwrap();
        assert!(q.gt.ignored.is_empty() && q.gt.boxes == p.gt.boxes, "no threshold: the 0-point guess is dropped");
        assert!(ignored_anchors(&prep, p) > ignored_anchors(&plain, q));
    }
}
