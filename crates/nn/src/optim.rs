//! Adam / AdamW on tensors we own (so that the moments go into checkpoints and a run resumes
//! exactly), gradient-norm clipping, and the one-cycle schedule of OpenPCDet's `adam_onecycle`
//! (fastai's: cosine warm-up of the learning rate from `lr / div_factor` to `lr` over `pct_start`
//! of the steps while β1 goes from `moms[0]` to `moms[1]`, then cosine decay to
//! `lr / div_factor / final_div_factor` while β1 returns).

use std::collections::HashMap;

use tch::{Kind, Tensor};

use crate::config::{OptimizerKind, TrainConfig};
use crate::error::{NnError, Result};

pub struct Optimizer {
    kind: OptimizerKind,
    names: Vec<String>,
    params: Vec<Tensor>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    pub step: i64,
    beta2: f64,
    eps: f64,
    weight_decay: f64,
}

impl Optimizer {
    /// `params`: the trainable variables by name.
    pub fn new(params: Vec<(String, Tensor)>, cfg: &TrainConfig) -> Self {
        let mut params = params;
        params.sort_by(|a, b| a.0.cmp(&b.0));
        let (names, params): (Vec<String>, Vec<Tensor>) = params.into_iter().unzip();
        let m = params.iter().map(|p| p.zeros_like()).collect();
        let v = params.iter().map(|p| p.zeros_like()).collect();
        Self {
            kind: cfg.optimizer,
            names,
            params,
            m,
            v,
            step: 0,
            beta2: cfg.beta2,
            eps: 1e-8,
            weight_decay: cfg.weight_decay,
        }
    }

    pub fn zero_grad(&mut self) {
        for p in &mut self.params {
            let mut g = p.grad();
            if g.defined() {
                let _ = g.zero_();
            }
        }
    }

    /// Scales gradients so that their global L2 norm is at most `max`; returns the norm before
    /// clipping (`max ≤ 0`: no clipping).
    pub fn clip_grad_norm(&mut self, max: f64) -> f64 {
        let grads: Vec<Tensor> = self.params.iter().map(|p| p.grad()).filter(|g| g.defined()).collect();
        if grads.is_empty() {
            return 0.0;
        }
        let sq: Vec<Tensor> = grads.iter().map(|g| g.square().sum(Kind::Float)).collect();
        let norm = Tensor::stack(&sq, 0).sum(Kind::Float).sqrt().double_value(&[]);
        if max > 0.0 && norm > max {
            let scale = max / (norm + 1e-6);
            tch::no_grad(|| {
                for g in &grads {
                    let mut g = g.shallow_clone();
                    let _ = g.g_mul_scalar_(scale);
                }
            });
        }
        norm
    }

    /// One update with learning rate `lr` and β1 `beta1`.
    pub fn update(&mut self, lr: f64, beta1: f64) {
        self.step += 1;
        let t = self.step as f64;
        let bc1 = 1.0 - beta1.powf(t);
        let bc2 = 1.0 - self.beta2.powf(t);
        let b2 = self.beta2;
        tch::no_grad(|| {
            for ((p, m), v) in self.params.iter().zip(&mut self.m).zip(&mut self.v) {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let mut p = p.shallow_clone();
                let g = match self.kind {
                    OptimizerKind::AdamW => {
                        if self.weight_decay > 0.0 {
                            let _ = p.g_mul_scalar_(1.0 - lr * self.weight_decay);
                        }
                        g
                    }
                    OptimizerKind::Adam => {
                        if self.weight_decay > 0.0 {
                            &g + &p * self.weight_decay
                        } else {
                            g
                        }
                    }
                };
                let _ = m.g_mul_scalar_(beta1).g_add_(&(&g * (1.0 - beta1)));
                let _ = v.g_mul_scalar_(b2).g_add_(&(g.square() * (1.0 - b2)));
                let denom = (&*v / bc2).sqrt() + self.eps;
                let _ = p.g_sub_(&(&*m / &denom * (lr / bc1)));
            }
        });
    }

    /// Moments for a checkpoint: `optim.m.<name>`, `optim.v.<name>`.
    pub fn state(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.names.len());
        for (n, (m, v)) in self.names.iter().zip(self.m.iter().zip(&self.v)) {
            out.push((format!("optim.m.{n}"), m.shallow_clone()));
            out.push((format!("optim.v.{n}"), v.shallow_clone()));
        }
        out
    }

    /// Restores moments saved by [`Optimizer::state`].
    pub fn load_state(&mut self, tensors: &HashMap<String, Tensor>, step: i64) -> Result<()> {
        tch::no_grad(|| -> Result<()> {
            for (n, (m, v)) in self.names.iter().zip(self.m.iter_mut().zip(self.v.iter_mut())) {
                for (prefix, dst) in [("optim.m.", m), ("optim.v.", v)] {
                    let key = format!("{prefix}{n}");
                    let src = tensors.get(&key).ok_or_else(|| NnError::Input(format!("checkpoint lacks {key}")))?;
                    if src.size() != dst.size() {
                        return Err(NnError::Input(format!(
                            "checkpoint {key} has shape {:?}, expected {:?}",
                            src.size(),
                            dst.size()
                        )));
                    }
                    dst.f_copy_(&src.to_device(dst.device()))?;
                }
            }
            Ok(())
        })?;
        self.step = step;
        Ok(())
    }
}

/// Learning rate and β1 at a step of the one-cycle schedule.
#[derive(Debug, Clone, Copy)]
pub struct OneCycle {
    pub total_steps: usize,
    pub lr_max: f64,
    pub div_factor: f64,
    pub final_div_factor: f64,
    pub pct_start: f64,
    pub moms: [f64; 2],
}

impl OneCycle {
    pub fn new(cfg: &TrainConfig, total_steps: usize) -> Self {
        Self {
            total_steps: total_steps.max(1),
            lr_max: cfg.lr,
            div_factor: cfg.div_factor,
            final_div_factor: cfg.final_div_factor,
            pct_start: cfg.pct_start,
            moms: cfg.moms,
        }
    }

    fn cos(start: f64, end: f64, pct: f64) -> f64 {
        end + (start - end) / 2.0 * ((std::f64::consts::PI * pct).cos() + 1.0)
    }

    /// `(lr, beta1)` at `step` (0-based).
    pub fn at(&self, step: usize) -> (f64, f64) {
        let low = self.lr_max / self.div_factor;
        let warm = (self.pct_start * self.total_steps as f64).max(1.0);
        let s = step as f64;
        if s < warm {
            let p = s / warm;
            (Self::cos(low, self.lr_max, p), Self::cos(self.moms[0], self.moms[1], p))
        } else {
            let rest = (self.total_steps as f64 - warm).max(1.0);
            let p = ((s - warm) / rest).min(1.0);
            (Self::cos(self.lr_max, low / self.final_div_factor, p), Self::cos(self.moms[1], self.moms[0], p))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn one_cycle_shape() {
        let cfg =
            TrainConfig { lr: 0.01, div_factor: 10.0, final_div_factor: 100.0, pct_start: 0.4, ..Default::default() };
        let s = OneCycle::new(&cfg, 100);
        let (lr0, m0) = s.at(0);
        assert!((lr0 - 0.001).abs() < 1e-12 && (m0 - 0.95).abs() < 1e-12);
        let (lr, m) = s.at(40);
        assert!((lr - 0.01).abs() < 1e-12 && (m - 0.85).abs() < 1e-12);
        let (lr, m) = s.at(100);
        assert!((lr - 1e-5).abs() < 1e-12 && (m - 0.95).abs() < 1e-12);
        assert!(s.at(20).0 > lr0 && s.at(70).0 < 0.01);
    }

    #[test]
    fn adam_minimises_a_quadratic_and_clips() {
        let x = Tensor::from_slice(&[3.0f32, -2.0]).set_requires_grad(true);
        let cfg = TrainConfig { weight_decay: 0.0, ..Default::default() };
        let mut opt = Optimizer::new(vec![("x".into(), x.shallow_clone())], &cfg);
        for _ in 0..300 {
            opt.zero_grad();
            (&x * &x).sum(Kind::Float).backward();
            opt.update(0.05, 0.9);
        }
        let v: Vec<f32> = Vec::try_from(&x).unwrap();
        assert!(v.iter().all(|a| a.abs() < 0.05), "{v:?}");
        opt.zero_grad();
        (&x * 1000.0).sum(Kind::Float).backward();
        let n = opt.clip_grad_norm(1.0);
        assert!((n - 1000.0 * 2f64.sqrt()).abs() < 1e-2);
        let g = x.grad();
        assert!((g.square().sum(Kind::Float).sqrt().double_value(&[]) - 1.0).abs() < 1e-4);
        // State round trip.
        let state: HashMap<String, Tensor> = opt.state().into_iter().map(|(k, v)| (k, v.copy())).collect();
        let mut opt2 = Optimizer::new(vec![("x".into(), Tensor::zeros([2], (Kind::Float, Device::Cpu)))], &cfg);
        opt2.load_state(&state, opt.step).unwrap();
        assert_eq!(opt2.step, 300);
        assert!(opt2.load_state(&HashMap::new(), 0).is_err());
    }
}
