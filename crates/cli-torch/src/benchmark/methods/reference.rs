//! The reference rows: the source model alone, a model trained on the target's labels, and one
//! trained on both domains' labels.

use super::*;
use crate::benchmark::suite::epochs_for_steps;

/// Source-only: the source model on the target, through the suite's height matching.
pub(super) fn source_only(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { base, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    let ck = c.source_model(base, log)?;
    outcome.ap = c.eval(&load(&ck, Some(&c.on_target(base)), device)?, log)?;
    Ok(outcome)
}

/// Target-only: trained with the target's labels (the upper reference), in the target's own
/// frames levelled to the detector's sensor height (every frame from its own ground, as VPP
/// does: a dataset-wide shift leaves a drone's cars outside the z window), and, under
/// `equal_steps`, for as many steps as the source model.
pub(super) fn target_only(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, cell, base, target, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    let mut cfg = base.clone();
    if ctx.suite.schedule.equal_steps {
        let source_steps = ctx.split(&task.source, true, log)?.len() * base.train.epochs;
        cfg.train.epochs = epochs_for_steps(source_steps, target.len());
        log.line(format!(
            "target-only: {} epochs over {} target frames for the source model's {source_steps} steps",
            cfg.train.epochs,
            target.len()
        ));
    }
    let level = Some(base.shift_z);
    let ck =
        ctx.trained(&format!("target_{}_{}", task.target, cell.detector), &cfg, &[&task.target], None, level, log)?;
    outcome.ap = c.eval_levelled(&load(&ck, None, device)?, level, log)?;
    Ok(outcome)
}

/// Combined: trained on the labels of both domains.
pub(super) fn combined(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, cell, base, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    // One config for both domains' frames: the detector's own shift (no height matching).
    let name = format!("combined_{}_{}_{}", task.source, task.target, cell.detector);
    let ck = ctx.trained(&name, base, &[&task.source, &task.target], None, None, log)?;
    outcome.ap = c.eval(&load(&ck, None, device)?, log)?;
    Ok(outcome)
}
