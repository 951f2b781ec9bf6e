//! The reference rows: the source model alone, a model trained on the target's labels, and one
//! trained on both domains' labels.

use super::*;

/// Source-only: the source model on the target, through the suite's height matching.
pub(super) fn source_only(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { base, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    let ck = c.source_model(base, log)?;
    outcome.ap = c.eval(&load(&ck, Some(&c.on_target(base)), device)?, log)?;
    Ok(outcome)
}

/// Target-only: trained with the target's labels (the upper reference).
pub(super) fn target_only(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, cell, base, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    let cfg = c.on_target(base);
    let ck = ctx.trained(&format!("target_{}_{}", task.target, cell.detector), &cfg, &[&task.target], None, log)?;
    outcome.ap = c.eval(&load(&ck, None, device)?, log)?;
    Ok(outcome)
}

/// Combined: trained on the labels of both domains.
pub(super) fn combined(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, cell, base, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    // One config for both domains' frames: the detector's own shift (no height matching).
    let name = format!("combined_{}_{}_{}", task.source, task.target, cell.detector);
    let ck = ctx.trained(&name, base, &[&task.source, &task.target], None, log)?;
    outcome.ap = c.eval(&load(&ck, None, device)?, log)?;
    Ok(outcome)
}
