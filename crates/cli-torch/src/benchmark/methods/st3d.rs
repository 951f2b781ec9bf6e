//! ST3D (Yang et al. 2021) and ST3D++ (Yang et al. 2022) self-training, and REDB (Chen et al. 2023),
//! which selects the same loop's pseudo-labels ([`super::redb`]).

use super::*;

/// ST3D, ST3D++ or REDB: self-training on the target with refreshed pseudo-labels.
pub(super) fn run(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, method, with_ros, target, target_infos, dir, .. } = c;
    let device = c.device;
    let adapt_epochs = c.adapt_epochs;
    let mut outcome = Outcome::default();
    let ck = c.source_model(with_ros, log)?;
    let pp = method.kind == MethodKind::St3dPp;
    // ST3D++ ranks pseudo-labels by its hybrid score (no weights involved: same checkpoint).
    let mut cfg = with_ros.clone();
    if pp {
        if let Some(r) = cfg.roi_head.as_mut() {
            r.score_fusion = ScoreFusion::Hybrid;
        }
    }
    let mut det = load(&ck, Some(&c.on_target(&cfg)), device)?;
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
        redb::redb_select(d, target_ref, labels, labels_cfg.positive_score, &redb_cfg)
    };
    let runner = SelfTraining { config: st, source, target: target.clone(), target_gt: Some(target_infos), device };
    let r = runner.run(&mut det, &mut labeller, &dir.join("self_training"), &mut |_| {})?;
    log_rounds(log, &r);
    outcome.pseudo_labels = rounds_json(&r);
    outcome.ap = c.eval(&det, log)?;
    Ok(outcome)
}
