//! `pi3det fuse`: MS3D++ kernel-density box fusion of several detectors' label files.

use std::path::PathBuf;
use std::time::Instant;

use super::{config_or_print, refuse_existing};
use crate::fusion::{fuse, FusionConfig, FusionInput};
use crate::labels::LabelSet;
use crate::read_infos;
use crate::AutolabelError;

/// Fuse several detectors' boxes into one label set by kernel-density box fusion (MS3D++).
#[derive(clap::Args, Debug, Clone)]
pub struct FuseArgs {
    /// Detections of one detector (repeat for each): JSON lines, result.pkl or a KITTI result folder.
    #[arg(long = "det", required = true, value_name = "DETECTIONS")]
    pub det: Vec<PathBuf>,
    /// Class weights of each --det, in order: one number for all classes (`0.5`) or per class
    /// (`Car=1,Pedestrian=0`); missing ones are 1.
    #[arg(long = "weights", value_name = "W")]
    pub weights: Vec<String>,
    /// Fusion parameters (TOML; `--print-config` shows the defaults, MS3D++'s).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Members a cluster needs, for every class (overrides the config's `min_members`).
    #[arg(long)]
    pub min_members: Option<usize>,
    /// Check that every frame id is one of this dataset's.
    #[arg(long, value_name = "DATASET")]
    pub data: Option<PathBuf>,
    #[arg(long, required_unless_present = "print_config")]
    pub out: Option<PathBuf>,
    #[arg(long)]
    pub overwrite: bool,
    /// Print the configuration as TOML and exit.
    #[arg(long)]
    pub print_config: bool,
}

pub fn run(args: &FuseArgs) -> Result<(), AutolabelError> {
    let Some(mut cfg) = config_or_print(args.config.as_deref(), FusionConfig::from_file, args.print_config)? else {
        return Ok(());
    };
    if let Some(m) = args.min_members {
        cfg.classes.iter_mut().for_each(|c| c.min_members = m);
    }
    if let Some(c) = cfg.classes.iter().find(|c| c.min_members > args.det.len()) {
        tracing::warn!(
            "{} inputs but class {} needs {} cluster members: only inputs with several boxes per object (test-time \
             augmentation) can fill such clusters; --min-members sets a smaller size",
            args.det.len(),
            c.name,
            c.min_members
        );
    }
    let out = args.out.as_deref().ok_or_else(|| AutolabelError::Input("--out is required".into()))?;
    refuse_existing(out, args.overwrite)?;
    if args.weights.len() > args.det.len() {
        return Err(AutolabelError::Input(format!("{} --weights for {} --det", args.weights.len(), args.det.len())));
    }
    let known = args.data.as_deref().map(read_infos).transpose()?;
    let mut inputs = Vec::new();
    for (k, path) in args.det.iter().enumerate() {
        let labels = LabelSet::read(path)?;
        if let Some(infos) = &known {
            labels.check_frames(infos.iter().map(|i| i.id.as_str()))?;
        }
        let class_weights = parse_weights(args.weights.get(k).map(String::as_str), &cfg)?;
        inputs.push(FusionInput { labels, class_weights });
    }
    let t0 = Instant::now();
    let (fused, stats) = fuse(&inputs, &cfg)?;
    fused.write_jsonl(out, None, args.overwrite)?;
    println!(
        "fused {} detections of {} inputs over {} frames into {} boxes ({} candidates, {} clusters) in {:.2} s → {}",
        stats.detections,
        inputs.len(),
        stats.frames,
        stats.fused,
        stats.candidates,
        stats.clusters,
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

fn parse_weights(spec: Option<&str>, cfg: &FusionConfig) -> Result<Vec<f64>, AutolabelError> {
    let mut w = vec![1.0; cfg.classes.len()];
    let Some(spec) = spec else { return Ok(w) };
    let num = |s: &str| {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| AutolabelError::Input(format!("--weights {spec:?}: {s:?} is not a non-negative number")))
    };
    if !spec.contains('=') {
        let v = num(spec)?;
        w.iter_mut().for_each(|x| *x = v);
        return Ok(w);
    }
    for part in spec.split(',') {
        let (name, value) = part
            .split_once('=')
            .ok_or_else(|| AutolabelError::Input(format!("--weights {spec:?}: expected CLASS=W, got {part:?}")))?;
        let k = cfg.class_index(name.trim()).ok_or_else(|| {
            AutolabelError::Input(format!(
                "--weights {spec:?}: unknown class {name:?} (known: {:?})",
                cfg.known_names()
            ))
        })?;
        w[k] = num(value)?;
    }
    Ok(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_parse_or_say_why() {
        let cfg = FusionConfig::default();
        assert_eq!(parse_weights(None, &cfg).unwrap(), vec![1.0, 1.0, 1.0]);
        assert_eq!(parse_weights(Some("0.5"), &cfg).unwrap(), vec![0.5, 0.5, 0.5]);
        assert_eq!(parse_weights(Some("Vehicle=2,Pedestrian=0"), &cfg).unwrap(), vec![2.0, 0.0, 1.0]);
        let e = parse_weights(Some("Bus=1"), &cfg).unwrap_err().to_string();
        assert!(e.contains("unknown class"), "{e}");
        assert!(parse_weights(Some("Car=-1"), &cfg).is_err());
    }
}
