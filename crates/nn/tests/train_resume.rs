//! The training loop end to end on a tiny simulated dataset: checkpoints are written atomically
//! with the config, a run resumed from an epoch checkpoint ends with exactly the weights of an
//! uninterrupted run (fixed seeds, per-frame augmentation seeds), the final checkpoint reloads to
//! identical detections, and detections are written in the formats the evaluator reads; the box
//! fits and test-time augmentation keep their promises on the trained model.

use std::path::Path;
use std::sync::Arc;

use pi3det_data::{DataError, FrameInfo, FrameMap, Mapped, Platform, PointCloud};
use pi3det_geometry::View;
use pi3det_nn::checkpoint;
use pi3det_nn::config::TrainConfig;
use pi3det_nn::data_loader::{open_split, Subset};
use pi3det_nn::detect;
use pi3det_nn::post_process::tta::TtaConfig;
use pi3det_nn::testing::tiny_detector;
use pi3det_nn::train::{train, TrainOptions};
use pi3det_nn::DetectorConfig;
use pi3det_sim::{ExportOptions, PlatformPlan, SimConfig};
use tch::{Device, Tensor};

fn config() -> DetectorConfig {
    let mut train =
        TrainConfig { epochs: 2, batch_size: 2, ckpt_every: 1, keep_checkpoints: 5, ..TrainConfig::default() };
    // Every augmentation, ground-truth sampling included, so resuming must reproduce their draws.
    train.augment.push(pi3det_nn::augment::AugmentConfig::RandomPlatformJitter(Default::default()));
    train.augment.push(pi3det_nn::augment::AugmentConfig::RandomObjectRotation(Default::default()));
    DetectorConfig { train, ..tiny_detector(12.8, 0.4) }
}

/// Frames mirrored left/right (y → −y), boxes with them.
struct Mirror;

impl FrameMap for Mirror {
    fn info(&self, _index: usize, mut info: FrameInfo) -> FrameInfo {
        let m = View { flip_y: true, yaw_rad: 0.0 };
        info.objects.iter_mut().for_each(|o| o.box3d = m.into_view(&o.box3d));
        info
    }
    fn points(&self, _index: usize, points: PointCloud) -> Result<PointCloud, DataError> {
        let (channels, stride) = (points.channels().to_vec(), points.stride());
        let mut data = points.into_vec();
        data.chunks_exact_mut(stride).for_each(|p| p[1] = -p[1]);
        PointCloud::from_vec(data, channels)
    }
}

/// Objects in a fixed order: by score, ties (many on a barely trained model) by box and class.
fn sorted(objects: &[pi3det_data::Object]) -> Vec<pi3det_data::Object> {
    let mut v = objects.to_vec();
    let key = |o: &pi3det_data::Object| (o.score.unwrap_or(0.0), o.box3d.to_array(), o.name.clone());
    v.sort_by(|a, b| {
        let (ka, kb) = (key(a), key(b));
        kb.0.total_cmp(&ka.0)
            .then_with(|| {
                ka.1.iter()
                    .zip(&kb.1)
                    .map(|(x, y)| x.total_cmp(y))
                    .find(|o| o.is_ne())
                    .unwrap_or(std::cmp::Ordering::Equal)
            })
            .then_with(|| ka.2.cmp(&kb.2))
    });
    v
}

fn weights(path: &Path) -> Vec<(String, Tensor)> {
    let ck = checkpoint::load(path).unwrap();
    let mut v: Vec<(String, Tensor)> = ck.tensors.into_iter().filter(|(k, _)| k.starts_with("model.")).collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn resume_reproduces_an_uninterrupted_run() {
    tch::set_num_threads(1);
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let plans = [PlatformPlan { platform: Platform::Vehicle, sequences: 2, frames: 3, val_sequences: 1 }];
    let opts = ExportOptions {
        out: data.clone(),
        seed: 1,
        overwrite: false,
        per_platform_folders: false,
        layout: None,
        stratify_layouts: false,
    };
    pi3det_sim::export(&SimConfig::default(), &plans, &opts, &mut |_, _| {}).unwrap();
    let train_set = Subset::all(open_split(&data.join("train"), Some("train")).unwrap());
    let val_set = Subset::all(open_split(&data.join("val"), Some("val")).unwrap());
    assert_eq!((train_set.len(), val_set.len()), (3, 3));
    let cfg = config();
    let run = |out: &Path, resume: Option<&Path>| {
        let opts = TrainOptions {
            config: cfg.clone(),
            train: train_set.clone(),
            val: Some(val_set.clone()),
            out_dir: out.to_path_buf(),
            device: Device::Cpu,
            resume: resume.map(Path::to_path_buf),
            stage: None,
            frame_transform: None,
        };
        train(opts, &mut |_| {}).unwrap()
    };
    let a = dir.path().join("a");
    let report = run(&a, None);
    assert_eq!(report.epochs.len(), 2);
    assert!(report.final_eval.is_some(), "the last epoch is evaluated");
    assert!(a.join("checkpoint_epoch_1.safetensors").is_file());
    assert!(a.join("config.toml").is_file() && a.join("eval_epoch_2.json").is_file());
    assert!(!std::fs::read_dir(&a).unwrap().any(|e| e.unwrap().file_name().to_string_lossy().contains(".tmp")));

    // Resume the second epoch from the first epoch's checkpoint, in another folder.
    let b = dir.path().join("b");
    let r = run(&b, Some(&a.join("checkpoint_epoch_1.safetensors")));
    assert_eq!(r.epochs.len(), 1, "only the remaining epoch ran");
    let (wa, wb) = (weights(&a.join("final.safetensors")), weights(&b.join("final.safetensors")));
    assert_eq!(wa.len(), wb.len());
    for ((ka, ta), (kb, tb)) in wa.iter().zip(&wb) {
        assert_eq!(ka, kb);
        assert!(ta.equal(tb), "{ka} differs after resuming");
    }

    // A checkpoint of another config is refused for resuming.
    let mut other = cfg.clone();
    other.train.lr *= 2.0;
    let opts = TrainOptions {
        config: other,
        train: train_set.clone(),
        val: None,
        out_dir: dir.path().join("c"),
        device: Device::Cpu,
        resume: Some(a.join("checkpoint_epoch_1.safetensors")),
        stage: None,
        frame_transform: None,
    };
    assert!(train(opts, &mut |_| {}).is_err());

    // The final checkpoint reloads to the same detections; files for the evaluator.
    let (det, ck) = checkpoint::load_detector(&a.join("final.safetensors"), Device::Cpu).unwrap();
    // The config as given, plus what training recorded about its frames.
    assert_eq!(ck.config.settings_toml(), cfg.settings_toml());
    let recorded = ck.config.trained_on.expect("training records its frames");
    assert!(recorded.sensor_height_m.is_some_and(|h| (1.5..2.2).contains(&h)), "{recorded:?}");
    assert!(recorded.intensity_mean.is_some_and(|i| (0.0..1.0).contains(&i)), "{recorded:?}");
    assert_eq!(ck.state.epoch, 2);
    let (frames, lat) = detect::detect(&det, &val_set, 2, &mut |_, _| {}).unwrap();
    assert_eq!(frames.len(), 3);
    assert!(lat.network_ms > 0.0);
    let (det2, _) = checkpoint::load_detector(&a.join("final.safetensors"), Device::Cpu).unwrap();
    let (frames2, _) = detect::detect(&det2, &val_set, 1, &mut |_, _| {}).unwrap();
    for (f, g) in frames.iter().zip(&frames2) {
        assert_eq!(f.objects.len(), g.objects.len());
        for (o, p) in f.objects.iter().zip(&g.objects) {
            assert_eq!(o.name, p.name);
            assert!((o.score.unwrap() - p.score.unwrap()).abs() < 1e-5);
        }
    }
    // `[post.ground_fit]` moves boxes only vertically, after NMS: same boxes in BEV, same
    // scores, some z and heights changed (score threshold 0 so that there are many boxes).
    let with_fit = |ground: bool, bev: bool| {
        let mut c = ck.config.clone();
        c.post.score_threshold = 0.0;
        c.post.ground_fit = ground.then(pi3det_nn::post_process::ground_fit::GroundFitConfig::default);
        let few = pi3det_nn::post_process::bev_fit::BevFitConfig { min_points: 5, ..Default::default() };
        c.post.bev_fit = bev.then_some(few);
        let mut d = pi3det_nn::Detector::new(&c, Device::Cpu).unwrap();
        ck.load_into(&mut d, &a.join("final.safetensors")).unwrap();
        detect::detect(&d, &val_set, 2, &mut |_, _| {}).unwrap().0
    };
    let (plain, fitted) = (with_fit(false, false), with_fit(true, false));
    let (mut boxes, mut moved) = (0, 0);
    for (f, g) in plain.iter().zip(&fitted) {
        assert_eq!(f.objects.len(), g.objects.len());
        for (o, p) in f.objects.iter().zip(&g.objects) {
            let (b, c) = (o.box3d, p.box3d);
            assert_eq!((o.score, b.x, b.y, b.dx, b.dy, b.heading), (p.score, c.x, c.y, c.dx, c.dy, c.heading));
            boxes += 1;
            moved += usize::from((b.z - c.z).abs() > 1e-6 || (b.dz - c.dz).abs() > 1e-6);
        }
    }
    assert!(boxes > 0 && moved > 0, "{moved} of {boxes} boxes fitted");
    // `[post.bev_fit]` moves long boxes only in the plane: same scores, z and heights; sizes
    // may grow, never shrink.
    let (mut long, mut moved) = (0, 0);
    for (f, g) in plain.iter().zip(&with_fit(false, true)) {
        assert_eq!(f.objects.len(), g.objects.len());
        for (o, p) in f.objects.iter().zip(&g.objects) {
            let (b, c) = (o.box3d, p.box3d);
            assert_eq!((o.score, b.z, b.dz), (p.score, c.z, c.dz));
            assert!(c.dx >= b.dx && c.dy >= b.dy, "{b:?} → {c:?}");
            long += usize::from(b.dx.max(b.dy) >= 2.5);
            moved += usize::from((b.x - c.x).abs() > 1e-6 || (b.y - c.y).abs() > 1e-6 || b.heading != c.heading);
        }
    }
    assert!(moved > 0, "{moved} of {long} long boxes fitted");
    // Test-time augmentation: with the frame as its only view it is plain detection; with the
    // mirror as a second view, a mirrored frame gives the mirror of the frame's detections (the
    // two runs see the same two network inputs).
    let with_tta = |tta: Option<TtaConfig>, data: &Subset| {
        let mut c = ck.config.clone();
        c.post.score_threshold = 0.0;
        c.post.tta = tta;
        let mut d = pi3det_nn::Detector::new(&c, Device::Cpu).unwrap();
        ck.load_into(&mut d, &a.join("final.safetensors")).unwrap();
        detect::detect(&d, data, 1, &mut |_, _| {}).unwrap().0
    };
    let only_frame = TtaConfig { flip: false, yaw_deg: vec![], ..Default::default() };
    for (f, g) in with_tta(None, &val_set).iter().zip(&with_tta(Some(only_frame), &val_set)) {
        assert!(!f.objects.is_empty());
        assert_eq!(sorted(&f.objects), sorted(&g.objects));
    }
    let flip = TtaConfig { flip: true, yaw_deg: vec![], ..Default::default() };
    let mirrored = Subset {
        dataset: Arc::new(Mapped { inner: val_set.dataset.clone(), map: Mirror }),
        indices: val_set.indices.clone(),
    };
    let (seen, seen_mirrored) = (with_tta(Some(flip.clone()), &val_set), with_tta(Some(flip), &mirrored));
    let mirror = View { flip_y: true, yaw_rad: 0.0 };
    for (f, g) in seen.iter().zip(&seen_mirrored) {
        assert!(!f.objects.is_empty());
        assert_eq!(f.objects.len(), g.objects.len());
        let mirrored_back: Vec<_> =
            f.objects.iter().map(|o| pi3det_data::Object { box3d: mirror.into_view(&o.box3d), ..o.clone() }).collect();
        for (o, p) in sorted(&mirrored_back).iter().zip(&sorted(&g.objects)) {
            let (b, c) = (o.box3d.to_array(), p.box3d.to_array());
            assert!((o.score.unwrap() - p.score.unwrap()).abs() < 1e-6, "{o:?} vs {p:?}");
            assert!(b.iter().zip(c).all(|(u, v)| (u - v).abs() < 1e-4), "{b:?} vs {c:?}");
        }
    }
    let out = dir.path().join("det");
    std::fs::create_dir_all(&out).unwrap();
    detect::write_jsonl(&out.join("d.jsonl"), &frames).unwrap();
    detect::write_result_pkl(&out.join("result.pkl"), &frames, &cfg.classes).unwrap();
    let n: usize = frames.iter().map(|f| f.objects.len()).sum();
    for file in ["d.jsonl", "result.pkl"] {
        let d = pi3det_eval::Detections::read(&out.join(file)).unwrap();
        assert_eq!(d.num_detections(), n, "{file}");
    }
    // A corrupt checkpoint is an error, not a panic.
    std::fs::write(out.join("bad.safetensors"), b"not a checkpoint").unwrap();
    assert!(checkpoint::load(&out.join("bad.safetensors")).is_err());
}
