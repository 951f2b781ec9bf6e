//! Pi3DET-Net (the paper's §4): Pre-Adaptation on the source, then `pi3det_adapt::pipeline`
//! (pseudo-labels through VPP, Knowledge-Adaptation, the guard).

use super::*;

/// Pi3DET-Net: PA (shared between cells), then the adaptation stages on the target.
pub(super) fn run(c: &CellRun<'_>, log: &mut Log) -> Result<Outcome> {
    let CellRun { ctx, task, cell, entry, val, target, dir, .. } = c;
    let device = c.device;
    let adapt_epochs = c.adapt_epochs;
    let mut outcome = Outcome::default();
    let mut cfg = entry.pi3det_net.clone().expect("a checked suite has the pi3det_net config");
    // An ablation row: exactly the components it keeps (its PA trains with just those). One the
    // config lacks comes with the paper's defaults, so an ablation can measure a component its
    // preset leaves out.
    if let Some(keep) = &c.method.components {
        let had = cfg.components();
        cfg = cfg.exactly(keep);
        let added: Vec<String> = keep.iter().filter(|x| !had.contains(x)).map(|x| x.to_string()).collect();
        if !added.is_empty() {
            log.line(format!("Pi3DET-Net: {} not in the config, added with the defaults", added.join(", ")));
        }
        log.line(format!("Pi3DET-Net components: {}", pi3det_adapt::pipeline::component_names(&cfg.components())));
    }
    cfg.detector = ctx.scheduled(&cfg.detector);
    // A row without VPP sees the target as the baselines do: through the suite's one shift.
    if cfg.vpp.is_none() {
        cfg.target_shift_z = Some(c.target_shift);
    }
    if let Some(e) = adapt_epochs {
        cfg.ka.epochs = e;
    }
    // Without RPJ, PFA and GTD, PA trains what source-only trains: the same model, trained once.
    let same_as_base = DetectorConfig { name: c.base.name.clone(), ..cfg.detector.clone() } == c.base;
    let pa = if same_as_base {
        log.line("PA without RPJ, PFA and GTD: the source-only model");
        c.source_model(&c.base, log)?
    } else {
        ctx.trained(
            &format!("pa_{}_{}", task.source, cell.detector),
            &cfg.detector,
            &[&task.source],
            Some("pa"),
            None,
            log,
        )?
    };
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
    Ok(outcome)
}
