//! TorchScript export of a detector's network, and running the exported files.
//!
//! `pi3det export --ckpt runs/pp/final.safetensors --format torchscript --out model.pt`
//!
//! What is traced is the network, not the pre/post-processing around it (those are data
//! dependent: pillarization, proposal NMS, box decoding and NMS stay in Rust and follow the
//! config saved beside the model):
//! - `model.pt`: `forward(features [P, 32, 10] f32, cells [P] i64) → flat` for one frame — the
//!   pillar VFE, scatter, 2-D backbone, neck and dense head; `P` is free. TorchScript methods
//!   saved from a trace return one value, so the outputs come concatenated, flattened, in the
//!   order and shapes `model.json` lists: the BEV map (two-stage models only), then the head's
//!   outputs (anchor head: `cls, boxes, dir`; center head: `heatmap, codes`);
//! - `model.roi.pt` (two-stage models): `forward(bev, rois [1, N, 7]) → flat` (`features,
//!   iou_logits, box_codes, rois`) with `N` the config's test-time proposal limit (pad with zero
//!   rows);
//! - `model.json`: the format, the output shapes, and the detector config (classes, grid,
//!   heads, thresholds) the caller needs for the inputs and the decoding;
//! - `model.example.npz`: the traced frame's `features`, `cells` and the first stage's `output`
//!   (`examples/torchscript/run_exported.py` checks PyTorch against it).
//!
//! `pi3det run --ckpt model.pt` runs the exported files through [`TorchScriptModel`].

use std::path::{Path, PathBuf};

use tch::{CModule, Device, IValue, Tensor};

use crate::detector::{Forward, Inputs};
use crate::error::{NnError, Result};
use crate::{Detector, DetectorConfig};

/// `model.pt` → `model.roi.pt`.
pub fn roi_path(model: &Path) -> PathBuf {
    model.with_extension("roi.pt")
}

/// `model.pt` → `model.example.npz` (the traced frame's inputs and the first stage's output,
/// for checking a runtime: examples/torchscript/run_exported.py).
pub fn example_path(model: &Path) -> PathBuf {
    model.with_extension("example.npz")
}

/// `model.pt` → `model.json`.
pub fn config_path(model: &Path) -> PathBuf {
    model.with_extension("json")
}

pub const FORMAT: &str = "pi3det-torchscript/1";

/// `model.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExportMeta {
    pub format: String,
    /// The detector config, TOML.
    pub config: String,
    /// Shapes of the dense module's outputs, in order.
    pub dense_shapes: Vec<Vec<i64>>,
    /// Whether the first dense output is the BEV map (two-stage models).
    pub dense_has_bev: bool,
    /// Shapes of the second stage's outputs.
    pub roi_shapes: Option<Vec<Vec<i64>>>,
}

/// One flat tensor of all `ts` (a traced method returns one value).
fn flatten(ts: &[Tensor]) -> Tensor {
    Tensor::cat(&ts.iter().map(|t| t.reshape([-1])).collect::<Vec<_>>(), 0)
}

/// [`flatten`] undone.
fn unflatten(flat: &Tensor, shapes: &[Vec<i64>], path: &Path) -> Result<Vec<Tensor>> {
    let sizes: Vec<i64> = shapes.iter().map(|s| s.iter().product()).collect();
    let total: i64 = sizes.iter().sum();
    if flat.dim() != 1 || flat.size()[0] != total {
        return Err(NnError::Input(format!(
            "{}: the module returned {:?} values, model.json's shapes need {total}",
            path.display(),
            flat.size()
        )));
    }
    Ok(flat.split_with_sizes(&sizes, 0).iter().zip(shapes).map(|(t, s)| t.reshape(s.as_slice())).collect())
}

/// The files of an export.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportedFiles {
    pub dense: PathBuf,
    pub roi: Option<PathBuf>,
    pub config: PathBuf,
    pub example: PathBuf,
}

fn tensor(v: IValue, path: &Path) -> Result<Tensor> {
    match v {
        IValue::Tensor(t) => Ok(t),
        _ => Err(NnError::Input(format!("{}: the TorchScript module did not return a tensor", path.display()))),
    }
}

/// Traces `det` on one frame's `example` inputs and writes the files next to `out`
/// (`model.pt`, `model.roi.pt`, `model.json`, `model.example.npz`). The detector's variables stop requiring
/// gradients (traced weights are constants).
pub fn export(det: &mut Detector, example: &Inputs, out: &Path) -> Result<ExportedFiles> {
    if example.batch_size != 1 {
        return Err(NnError::Input("the export traces one frame (batch size 1)".into()));
    }
    if det.has_backbone_3d() {
        // A trace records tensor operations only; the rulebooks are built in Rust per frame.
        return Err(NnError::Model(
            "TorchScript export covers pillar detectors: a sparse 3-D backbone builds its rulebooks in Rust on every frame, which a trace cannot record".into(),
        ));
    }
    det.vs.freeze();
    let _guard = tch::no_grad_guard();
    let x = example.to_device(det.device());
    let det: &Detector = det;
    let two_stage = det.fixed_roi_count().is_some();
    // Single-stage models need no BEV map after the head: leave it out of the output.
    let outputs = |x: &Inputs| -> Result<Vec<Tensor>> {
        let mut t = det.dense_tensors(x)?;
        if !two_stage {
            drop(t.remove(0));
        }
        Ok(t)
    };
    let example_out = outputs(&x)?;
    let dense_shapes: Vec<Vec<i64>> = example_out.iter().map(Tensor::size).collect();
    let inputs = [x.features.shallow_clone(), x.cells.shallow_clone()];
    let dense = CModule::create_by_tracing("Pi3detDense", "forward", &inputs, &mut |inp| {
        let x = Inputs { features: inp[0].shallow_clone(), cells: inp[1].shallow_clone(), batch_size: 1 };
        // The same computation succeeded on these inputs just above.
        vec![flatten(&outputs(&x).unwrap_or_default())]
    })?;
    dense.save(out)?;
    let example = example_path(out);
    let flat = flatten(&example_out);
    Tensor::write_npz(&[("features", &x.features), ("cells", &x.cells), ("output", &flat)], &example)?;
    let mut files = ExportedFiles { dense: out.to_path_buf(), roi: None, config: config_path(out), example };
    let mut roi_shapes = None;
    if two_stage {
        // Trace the second stage on the example's own proposals, padded to the fixed count.
        let mut seen = None;
        det.forward_from_tensors(det.dense_tensors(&x)?, &mut |bev, rois| {
            let t = det.roi_tensors(bev, rois)?.ok_or_else(|| NnError::Model("no second stage".into()))?;
            seen = Some((bev.shallow_clone(), rois.shallow_clone(), t.iter().map(Tensor::size).collect::<Vec<_>>()));
            Ok(t)
        })?;
        let (bev, rois, shapes) = seen.ok_or_else(|| NnError::Model("the second stage was not run".into()))?;
        let roi = CModule::create_by_tracing("Pi3detRoi", "forward", &[bev, rois], &mut |inp| {
            vec![flatten(&det.roi_tensors(&inp[0], &inp[1]).ok().flatten().unwrap_or_default())]
        })?;
        let p = roi_path(out);
        roi.save(&p)?;
        files.roi = Some(p);
        roi_shapes = Some(shapes);
    }
    let meta = ExportMeta {
        format: FORMAT.into(),
        config: det.cfg().to_toml(),
        dense_shapes,
        dense_has_bev: two_stage,
        roi_shapes,
    };
    let json = serde_json::to_vec_pretty(&meta).map_err(|e| NnError::Input(e.to_string()))?;
    pi3det_data::io::write_atomic(&files.config, &json, true)?;
    Ok(files)
}

/// An exported model: the TorchScript modules plus a detector built from the saved config for
/// the pre/post-processing (its own weights are not used).
pub struct TorchScriptModel {
    pub det: Detector,
    meta: ExportMeta,
    path: PathBuf,
    dense: CModule,
    roi: Option<CModule>,
}

impl TorchScriptModel {
    /// Loads `model.pt` (and `model.roi.pt`, `model.json` beside it); `adjust` may change the
    /// config's post-processing (thresholds) first.
    pub fn load(path: &Path, device: Device, adjust: impl FnOnce(&mut DetectorConfig)) -> Result<Self> {
        let cfg_path = config_path(path);
        if !cfg_path.is_file() {
            return Err(NnError::Input(format!(
                "{}: the exported model's config {} is missing (pi3det export writes both)",
                path.display(),
                cfg_path.display()
            )));
        }
        let text = std::fs::read(&cfg_path).map_err(|e| NnError::io(&cfg_path, e))?;
        let meta: ExportMeta = serde_json::from_slice(&text)
            .map_err(|e| NnError::Input(format!("{}: not an export description: {e}", cfg_path.display())))?;
        if meta.format != FORMAT {
            return Err(NnError::Input(format!(
                "{}: format {:?}, expected {FORMAT:?}",
                cfg_path.display(),
                meta.format
            )));
        }
        let mut cfg = DetectorConfig::from_toml_str(&meta.config)?;
        adjust(&mut cfg);
        let det = Detector::new(&cfg, device)?;
        let load = |p: &Path| {
            CModule::load_on_device(p, device)
                .map_err(|e| NnError::Input(format!("{}: not a TorchScript module: {e}", p.display())))
        };
        let dense = load(path)?;
        let roi = match det.fixed_roi_count() {
            Some(_) => Some(load(&roi_path(path))?),
            None => None,
        };
        if det.fixed_roi_count().is_some() != meta.roi_shapes.is_some() {
            return Err(NnError::Input(format!("{}: the config and the exported stages disagree", cfg_path.display())));
        }
        Ok(Self { det, meta, path: path.to_path_buf(), dense, roi })
    }

    /// The network on one frame's inputs, ready for `self.det.post_process`.
    pub fn forward(&self, x: &Inputs) -> Result<Forward> {
        let x = x.to_device(self.det.device());
        let out = self.dense.forward_is(&[IValue::Tensor(x.features), IValue::Tensor(x.cells)])?;
        let mut dense = unflatten(&tensor(out, &self.path)?, &self.meta.dense_shapes, &self.path)?;
        if !self.meta.dense_has_bev {
            // Only the second stage reads the BEV map.
            dense.insert(0, Tensor::zeros([0], (tch::Kind::Float, self.det.device())));
        }
        let roi_path = roi_path(&self.path);
        self.det.forward_from_tensors(dense, &mut |bev, rois| {
            let m = self.roi.as_ref().ok_or_else(|| NnError::Model("no second-stage module loaded".into()))?;
            let shapes = self.meta.roi_shapes.as_deref().unwrap_or_default();
            let out = m.forward_is(&[IValue::Tensor(bev.shallow_clone()), IValue::Tensor(rois.shallow_clone())])?;
            unflatten(&tensor(out, &roi_path)?, shapes, &roi_path)
        })
    }
}
