//! MS3D++ (Tsai et al. 2023): the boxes of an ensemble of source-trained detectors (each in four
//! views) fused (KDE box fusion, a cluster kept with enough members) and tracked into fixed
//! pseudo-labels, then self-training on them, round after round, each round's model joining the
//! ensemble.

use super::*;

/// MS3D++: ensemble → fusion → tracking → fixed labels → self-training, per round.
pub(super) fn run(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { method, with_ros, target, target_infos, dir, .. } = c;
    let device = c.device;
    let target_shift = c.target_shift;
    let adapt_epochs = c.adapt_epochs;
    let mut outcome = Outcome::default();
    let ck = c.source_model(with_ros, log)?;
    let mut det = load(&ck, Some(&c.on_target(with_ros)), device)?;
    let st = self_training_config(method, adapt_epochs);
    let mut checkpoints = Vec::new();
    for m in method.members() {
        let p = match (&m.config, m.seed_offset) {
            (None, 0) => ck.clone(),
            (config, offset) => {
                let mut cfg = match config {
                    Some(p) => c.ctx.scheduled(&DetectorConfig::from_file(p)?),
                    None => with_ros.clone(),
                };
                cfg.train.seed = c.ctx.suite.seed + offset;
                let name = format!("ms3d_member_{}_{}_{}_s{offset}", c.task.source, c.cell.detector, cfg.name);
                c.ctx.trained(&name, &cfg, &[&c.task.source], None, None, log)?
            }
        };
        log.line(format!("MS3D++ member: {}", p.display()));
        checkpoints.push(p);
    }
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
                subset: target,
                infos: target_infos,
                checkpoints: &checkpoints,
                views: &views,
                level: Level::Off,
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
            target_gt: Some(target_infos),
            device,
        };
        let round_dir = dir.join(format!("round_{}", round + 1));
        let r = runner.run(&mut det, &mut labeller, &round_dir, &mut |_| {})?;
        log_rounds(log, &r);
        outcome.pseudo_labels.extend(rounds_json(&r));
        checkpoints.push(round_dir.join("final.safetensors"));
    }
    outcome.ap = c.eval(&det, log)?;
    Ok(outcome)
}
