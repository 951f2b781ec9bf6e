//! Checkpoints: one safetensors file holding the weights (`model.*`, batch-norm statistics
//! included), optionally the optimiser moments (`optim.*`), and in its metadata the detector config
//! (TOML, key `pi3det.config`) and the training state (JSON, `pi3det.state`), so a checkpoint alone
//! is enough to run inference or resume. Written to a temporary file and renamed (atomic).

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::config::DetectorConfig;
use crate::detector::Detector;
use crate::error::{NnError, Result};

pub const FORMAT: &str = "pi3det-nn/1";

/// Where a training run is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct TrainState {
    /// Epochs completed.
    pub epoch: usize,
    /// Optimiser steps taken.
    pub step: i64,
    pub total_steps: usize,
    /// Wall-clock seconds of training so far.
    pub train_seconds: f64,
    /// Last training loss (mean over the last epoch).
    pub last_loss: Option<f64>,
    /// The adaptation stage the run is in (`pa`, `ka`); `None` for plain training.
    #[serde(default)]
    pub stage: Option<String>,
}

/// A loaded checkpoint.
pub struct Checkpoint {
    pub config: DetectorConfig,
    pub state: TrainState,
    pub tensors: HashMap<String, Tensor>,
}

/// A tensor's dtype, shape and little-endian bytes.
type RawTensor = (Dtype, Vec<usize>, Vec<u8>);

fn to_bytes(t: &Tensor) -> Result<RawTensor> {
    let t = t.to_device(Device::Cpu).contiguous();
    let shape: Vec<usize> = t.size().iter().map(|&d| d as usize).collect();
    let flat = t.view([-1]);
    match t.kind() {
        Kind::Int64 => {
            let v: Vec<i64> = Vec::try_from(&flat)?;
            Ok((Dtype::I64, shape, v.iter().flat_map(|x| x.to_le_bytes()).collect()))
        }
        _ => {
            let v: Vec<f32> = Vec::try_from(&flat.to_kind(Kind::Float))?;
            Ok((Dtype::F32, shape, v.iter().flat_map(|x| x.to_le_bytes()).collect()))
        }
    }
}

/// Writes a checkpoint.
pub fn save(path: &Path, detector: &Detector, optim: Option<Vec<(String, Tensor)>>, state: &TrainState) -> Result<()> {
    let mut named: Vec<(String, Tensor)> =
        detector.vs.variables().into_iter().map(|(k, v)| (format!("model.{k}"), v)).collect();
    if let Some(o) = optim {
        named.extend(o);
    }
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let raw: Vec<(String, RawTensor)> =
        named.iter().map(|(k, t)| Ok((k.clone(), to_bytes(t)?))).collect::<Result<_>>()?;
    let views: Vec<(String, TensorView<'_>)> = raw
        .iter()
        .map(|(k, (d, s, b))| {
            TensorView::new(*d, s.clone(), b)
                .map(|v| (k.clone(), v))
                .map_err(|e| NnError::Checkpoint { path: path.to_path_buf(), message: format!("{k}: {e:?}") })
        })
        .collect::<Result<_>>()?;
    let meta: HashMap<String, String> = [
        ("format".to_string(), FORMAT.to_string()),
        ("pi3det.config".to_string(), detector.cfg().to_toml()),
        ("pi3det.state".to_string(), serde_json::to_string(state).unwrap_or_default()),
    ]
    .into_iter()
    .collect();
    let bytes = safetensors::tensor::serialize(views, &Some(meta))
        .map_err(|e| NnError::Checkpoint { path: path.to_path_buf(), message: format!("{e:?}") })?;
    pi3det_data::io::write_atomic(path, &bytes, true)?;
    Ok(())
}

/// Reads a checkpoint (tensors on the CPU).
pub fn load(path: &Path) -> Result<Checkpoint> {
    let bytes = std::fs::read(path).map_err(|e| NnError::io(path, e))?;
    let bad = |message: String| NnError::Checkpoint { path: path.to_path_buf(), message };
    let (_, meta) = SafeTensors::read_metadata(&bytes).map_err(|e| bad(format!("{e:?}")))?;
    let meta = meta.metadata().clone().unwrap_or_default();
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err(bad(format!("missing or unknown format tag (expected {FORMAT})")));
    }
    let config_text = meta.get("pi3det.config").ok_or_else(|| bad("no config in the metadata".into()))?;
    let config = DetectorConfig::from_toml_str(config_text).map_err(|e| bad(format!("its config: {e}")))?;
    let state: TrainState = meta
        .get("pi3det.state")
        .map(|s| serde_json::from_str(s))
        .transpose()
        .map_err(|e| bad(format!("its state: {e}")))?
        .unwrap_or_default();
    let st = SafeTensors::deserialize(&bytes).map_err(|e| bad(format!("{e:?}")))?;
    let mut tensors = HashMap::new();
    for (name, view) in st.tensors() {
        let shape: Vec<i64> = view.shape().iter().map(|&d| d as i64).collect();
        let data = view.data();
        let t = match view.dtype() {
            Dtype::F32 => {
                let v: Vec<f32> = data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
                Tensor::from_slice(&v)
            }
            Dtype::I64 => {
                let v: Vec<i64> = data
                    .chunks_exact(8)
                    .map(|c| i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                    .collect();
                Tensor::from_slice(&v)
            }
            d => return Err(bad(format!("tensor {name} has unsupported dtype {d:?}"))),
        };
        tensors.insert(name, t.view(shape.as_slice()));
    }
    Ok(Checkpoint { config, state, tensors })
}

impl Checkpoint {
    /// Copies `model.*` tensors into the detector's variables; every variable must be present
    /// with its shape.
    pub fn load_into(&self, detector: &mut Detector, path: &Path) -> Result<()> {
        self.blend_into(detector, path, 1.0)
    }

    /// Moves the detector's floating-point variables (weights and batch-norm statistics) the
    /// share `weight` of the way to this checkpoint's: `var ← (1 − weight)·var + weight·ckpt`
    /// (integer buffers are copied). `weight` 1 is [`load_into`](Self::load_into); between 0 and
    /// 1 it is a weight-space ensemble of two fine-tunings of one network (WiSE-FT, Wortsman et
    /// al. 2022), which Knowledge-Adaptation uses to keep part of the pre-adapted model.
    pub fn blend_into(&self, detector: &mut Detector, path: &Path, weight: f64) -> Result<()> {
        let vars = detector.vs.variables();
        tch::no_grad(|| -> Result<()> {
            for (name, mut var) in vars {
                let key = format!("model.{name}");
                let src = self.tensors.get(&key).ok_or_else(|| NnError::Checkpoint {
                    path: path.to_path_buf(),
                    message: format!("no tensor {key} (was it written for another config?)"),
                })?;
                if src.size() != var.size() {
                    return Err(NnError::Checkpoint {
                        path: path.to_path_buf(),
                        message: format!("{key} has shape {:?}, the model {:?}", src.size(), var.size()),
                    });
                }
                let src = src.to_device(var.device()).to_kind(var.kind());
                if weight >= 1.0 || !var.is_floating_point() {
                    var.f_copy_(&src)?;
                } else {
                    let mixed = &var * (1.0 - weight) + src * weight;
                    var.f_copy_(&mixed)?;
                }
            }
            Ok(())
        })
    }
}

/// Builds a detector from a checkpoint on `device`.
pub fn load_detector(path: &Path, device: Device) -> Result<(Detector, Checkpoint)> {
    load_detector_with_post(path, None, device)
}

/// [`load_detector`] with the checkpoint's `[post]` replaced by `post` (post-processing does not
/// touch the weights, so a model trained before a post-processing change runs with the new one).
pub fn load_detector_with_post(
    path: &Path,
    post: Option<&crate::config::PostConfig>,
    device: Device,
) -> Result<(Detector, Checkpoint)> {
    let mut ck = load(path)?;
    if let Some(p) = post {
        ck.config.post = p.clone();
        ck.config.validate()?;
    }
    let mut det = Detector::new(&ck.config, device)?;
    ck.load_into(&mut det, path)?;
    Ok((det, ck))
}
