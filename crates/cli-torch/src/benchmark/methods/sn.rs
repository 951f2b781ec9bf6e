//! SN (Wang et al. 2020, "Train in Germany, Test in the USA"): the source's box sizes shifted to the
//! target's mean sizes per class while training on the source.

use super::*;

/// SN: the source model retrained with its boxes resized to the target's statistics.
pub(super) fn run(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, cell, base, target_infos, .. } = c;
    let device = c.device;
    let mut outcome = Outcome::default();
    let source = ctx.split(&task.source, true, log)?;
    let (s, t) = (mean_sizes(&source.infos()?, base), mean_sizes(target_infos, base));
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
        None,
        log,
    )?;
    outcome.ap = c.eval(&load(&ck, Some(&c.on_target(&cfg)), device)?, log)?;
    Ok(outcome)
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
