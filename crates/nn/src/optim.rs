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
    /// The moments of all parameters, flat (in `params` order), so that an update is a dozen
    /// kernels whatever the number of tensors (a GPU step paid ~10 launches per parameter
    /// tensor); `m` and `v` are per-parameter views into them, for checkpoints and for steps
    /// where some gradient is undefined.
    m_flat: Tensor,
    v_flat: Tensor,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    /// Factor the next update applies to the gradients (gradient-norm clipping).
    grad_scale: f64,
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
        let total: i64 = params.iter().map(Tensor::numel).sum::<usize>() as i64;
        let options = params.first().map_or((Kind::Float, tch::Device::Cpu), |p| (p.kind(), p.device()));
        let m_flat = Tensor::zeros([total], options);
        let v_flat = Tensor::zeros([total], options);
        let views = |flat: &Tensor| -> Vec<Tensor> {
            let mut offset = 0;
            params
                .iter()
                .map(|p| {
                    let n = p.numel() as i64;
                    let view = flat.narrow(0, offset, n).view(p.size().as_slice());
                    offset += n;
                    view
                })
                .collect()
        };
        let (m, v) = (views(&m_flat), views(&v_flat));
        Self {
            kind: cfg.optimizer,
            names,
            params,
            m_flat,
            v_flat,
            m,
            v,
            grad_scale: 1.0,
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
        self.grad_scale = 1.0;
    }

    /// The global L2 norm of the gradients, returned before clipping; when it exceeds `max`
    /// (`max > 0`), the next [`Optimizer::update`] scales the gradients to norm `max` (the
    /// gradient tensors themselves are left as they are).
    pub fn clip_grad_norm(&mut self, max: f64) -> f64 {
        let grads: Vec<Tensor> =
            self.params.iter().map(|p| p.grad()).filter(|g| g.defined()).map(|g| g.reshape([-1])).collect();
        if grads.is_empty() {
            return 0.0;
        }
        let flat = Tensor::cat(&grads, 0);
        let norm = flat.square().sum(flat.kind()).sqrt().double_value(&[]);
        self.grad_scale = if max > 0.0 && norm > max { max / (norm + 1e-6) } else { 1.0 };
        norm
    }

    /// One update with learning rate `lr` and β1 `beta1`.
    pub fn update(&mut self, lr: f64, beta1: f64) {
        self.step += 1;
        let grads: Vec<Tensor> = self.params.iter().map(|p| p.grad()).collect();
        if grads.is_empty() {
            // Nothing to train (`cat` of no tensors would fail).
            return;
        }
        tch::no_grad(|| {
            if grads.iter().all(Tensor::defined) {
                self.update_flat(&grads, lr, beta1);
            } else {
                self.update_each(&grads, lr, beta1);
            }
        });
        self.grad_scale = 1.0;
    }

    fn bias_corrections(&self, beta1: f64) -> (f64, f64) {
        let t = self.step as f64;
        (1.0 - beta1.powf(t), 1.0 - self.beta2.powf(t))
    }

    /// Every parameter has a gradient: the arithmetic on flat tensors, then one copy per
    /// parameter.
    fn update_flat(&mut self, grads: &[Tensor], lr: f64, beta1: f64) {
        let (bc1, bc2) = self.bias_corrections(beta1);
        let flat = |ts: &[Tensor]| Tensor::cat(&ts.iter().map(|t| t.reshape([-1])).collect::<Vec<_>>(), 0);
        // `cat` copies: `g` and `p` are fresh tensors, safe to scale in place.
        let mut g = flat(grads);
        if self.grad_scale != 1.0 {
            g *= self.grad_scale;
        }
        let mut p = flat(&self.params);
        match self.kind {
            OptimizerKind::AdamW => {
                if self.weight_decay > 0.0 {
                    p *= 1.0 - lr * self.weight_decay;
                }
            }
            OptimizerKind::Adam => {
                if self.weight_decay > 0.0 {
                    g = &g + &p * self.weight_decay;
                }
            }
        }
        let b2 = self.beta2;
        let _ = self.m_flat.g_mul_scalar_(beta1).g_add_(&(&g * (1.0 - beta1)));
        let _ = self.v_flat.g_mul_scalar_(b2).g_add_(&(g.square() * (1.0 - b2)));
        let denom = (&self.v_flat / bc2).sqrt() + self.eps;
        let p = p - &self.m_flat / &denom * (lr / bc1);
        let mut offset = 0;
        for param in &self.params {
            let n = param.numel() as i64;
            let mut param = param.shallow_clone();
            param.copy_(&p.narrow(0, offset, n).view(param.size().as_slice()));
            offset += n;
        }
    }

    /// Some parameter took no part in the loss: update the others one by one (their moments
    /// are views into the flat ones).
    fn update_each(&mut self, grads: &[Tensor], lr: f64, beta1: f64) {
        let (bc1, bc2) = self.bias_corrections(beta1);
        let b2 = self.beta2;
        for (((p, g), m), v) in self.params.iter().zip(grads).zip(&mut self.m).zip(&mut self.v) {
            if !g.defined() {
                continue;
            }
            let mut p = p.shallow_clone();
            let mut g = if self.grad_scale != 1.0 { g * self.grad_scale } else { g.shallow_clone() };
            match self.kind {
                OptimizerKind::AdamW => {
                    if self.weight_decay > 0.0 {
                        let _ = p.g_mul_scalar_(1.0 - lr * self.weight_decay);
                    }
                }
                OptimizerKind::Adam => {
                    if self.weight_decay > 0.0 {
                        g = &g + &p * self.weight_decay;
                    }
                }
            }
            let _ = m.g_mul_scalar_(beta1).g_add_(&(&g * (1.0 - beta1)));
            let _ = v.g_mul_scalar_(b2).g_add_(&(g.square() * (1.0 - b2)));
            let denom = (&*v / bc2).sqrt() + self.eps;
            let _ = p.g_sub_(&(&*m / &denom * (lr / bc1)));
        }
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
        // State round trip.
        let state: HashMap<String, Tensor> = opt.state().into_iter().map(|(k, v)| (k, v.copy())).collect();
        let mut opt2 = Optimizer::new(vec![("x".into(), Tensor::zeros([2], (Kind::Float, Device::Cpu)))], &cfg);
        opt2.load_state(&state, opt.step).unwrap();
        assert_eq!(opt2.step, 300);
        assert!(opt2.load_state(&HashMap::new(), 0).is_err());
    }

    /// A model with nothing to train steps without failing.
    #[test]
    fn no_parameters_is_a_no_op() {
        let mut opt = Optimizer::new(Vec::new(), &TrainConfig::default());
        assert_eq!(opt.clip_grad_norm(1.0), 0.0);
        opt.update(0.1, 0.9);
        assert_eq!(opt.step, 1);
        assert!(opt.state().is_empty());
    }

    /// The textbook per-tensor Adam(W) with clipping, for comparison.
    struct Reference {
        m: Vec<Vec<f64>>,
        v: Vec<Vec<f64>>,
        step: i32,
    }

    impl Reference {
        #[allow(clippy::too_many_arguments)]
        fn step(
            &mut self,
            kind: OptimizerKind,
            p: &mut [Vec<f64>],
            g: &[Option<Vec<f64>>],
            lr: f64,
            b1: f64,
            wd: f64,
            clip: f64,
        ) {
            self.step += 1;
            let norm = g.iter().flatten().flatten().map(|x| x * x).sum::<f64>().sqrt();
            let scale = if norm > clip { clip / (norm + 1e-6) } else { 1.0 };
            let b2 = TrainConfig::default().beta2;
            let (bc1, bc2) = (1.0 - b1.powi(self.step), 1.0 - b2.powi(self.step));
            for (i, gi) in g.iter().enumerate() {
                let Some(gi) = gi else { continue };
                for j in 0..gi.len() {
                    let mut gj = gi[j] * scale;
                    match kind {
                        OptimizerKind::AdamW => p[i][j] *= 1.0 - lr * wd,
                        OptimizerKind::Adam => gj += p[i][j] * wd,
                    }
                    self.m[i][j] = b1 * self.m[i][j] + (1.0 - b1) * gj;
                    self.v[i][j] = b2 * self.v[i][j] + (1.0 - b2) * gj * gj;
                    p[i][j] -= lr / bc1 * self.m[i][j] / ((self.v[i][j] / bc2).sqrt() + 1e-8);
                }
            }
        }
    }

    /// The flat update (every gradient defined) and the per-tensor one (a parameter without a
    /// gradient) both equal the textbook algorithm, clipping and weight decay included, and a
    /// parameter without a gradient keeps its value.
    #[test]
    fn flat_and_per_tensor_updates_equal_the_textbook() {
        for (kind, uses_c) in [(OptimizerKind::AdamW, true), (OptimizerKind::Adam, true), (OptimizerKind::AdamW, false)]
        {
            let init = [vec![0.5, -1.0, 2.0, 0.25, 3.0, -0.75], vec![1.5, -0.5], vec![0.1, 0.2, 0.3]];
            let shapes: [&[i64]; 3] = [&[2, 3], &[2], &[3]];
            let xs: Vec<Tensor> =
                init.iter().zip(shapes).map(|(v, s)| Tensor::from_slice(v).view(s).set_requires_grad(true)).collect();
            let cfg = TrainConfig { optimizer: kind, weight_decay: 0.01, ..Default::default() };
            let named = ["a", "b", "c"].iter().map(|n| n.to_string()).zip(xs.iter().map(|x| x.shallow_clone()));
            let mut opt = Optimizer::new(named.collect(), &cfg);
            let zeros = || init.iter().map(|v| vec![0.0; v.len()]).collect();
            let mut reference = Reference { m: zeros(), v: zeros(), step: 0 };
            let mut p: Vec<Vec<f64>> = init.to_vec();
            for step in 0..6 {
                opt.zero_grad();
                let mut loss = (&xs[0] * &xs[0] * 40.0).sum(Kind::Double) + (&xs[1] * 3.0).sum(Kind::Double);
                if uses_c {
                    loss += (&xs[2] * &xs[2]).sum(Kind::Double);
                }
                loss.backward();
                let grads: Vec<Option<Vec<f64>>> = xs
                    .iter()
                    .map(|x| {
                        Some(x.grad()).filter(Tensor::defined).map(|g| Vec::<f64>::try_from(&g.reshape([-1])).unwrap())
                    })
                    .collect();
                assert_eq!(grads[2].is_some(), uses_c);
                let norm = opt.clip_grad_norm(5.0);
                let want = grads.iter().flatten().flatten().map(|x| x * x).sum::<f64>().sqrt();
                assert!((norm - want).abs() < 1e-9 * want, "{norm} vs {want}");
                opt.update(0.1, 0.9);
                reference.step(kind, &mut p, &grads, 0.1, 0.9, 0.01, 5.0);
                for (x, want) in xs.iter().zip(&p) {
                    let got = Vec::<f64>::try_from(&x.reshape([-1])).unwrap();
                    for (g, w) in got.iter().zip(want) {
                        assert!((g - w).abs() < 1e-12, "{kind:?} step {step}: {got:?} vs {want:?}");
                    }
                }
            }
            if !uses_c {
                assert_eq!(p[2], init[2]);
            }
        }
    }
}
