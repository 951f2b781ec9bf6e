//! Detection losses (OpenPCDet `loss_utils`): sigmoid focal loss (Lin et al. 2017), smooth-L1 with
//! the sin-difference heading trick (SECOND), direction cross-entropy, and CenterNet's focal loss
//! on Gaussian heatmaps (CornerNet) with its masked L1 regression loss.

pub mod target_negatives;

pub use target_negatives::TargetNegatives;

use std::collections::BTreeMap;
use tch::{Kind, Reduction, Tensor};

fn one_minus(t: &Tensor) -> Tensor {
    t.neg() + 1.0
}

/// Binary cross-entropy of `logits` against targets in [0, 1], per element, in the numerically
/// stable form `max(x, 0) − x·t + log(1 + e^(−|x|))`.
fn bce_with_logits(logits: &Tensor, targets: &Tensor) -> Tensor {
    logits.clamp_min(0.0) - logits * targets + logits.abs().neg().exp().log1p()
}

/// The training loss as a named sum. Every stage (dense head, RoI head, later alignment losses)
/// adds its terms, already weighted by its own config; `loss_weights` in the detector config
/// scales any term by name on top, so a new term needs no change to the training loop.
pub struct LossTerms {
    terms: Vec<(&'static str, Tensor)>,
    scale: BTreeMap<String, f64>,
}

impl LossTerms {
    pub fn new(scale: &BTreeMap<String, f64>) -> Self {
        Self { terms: Vec::new(), scale: scale.clone() }
    }

    /// Adds `value` (a scalar tensor) under `name`, times the configured scale of that name.
    pub fn add(&mut self, name: &'static str, value: Tensor) {
        let value = match self.scale.get(name) {
            Some(&w) => value * w,
            None => value,
        };
        self.terms.push((name, value));
    }

    pub fn terms(&self) -> &[(&'static str, Tensor)] {
        &self.terms
    }

    /// The sum of the terms (a zero scalar when there are none).
    pub fn total(&self) -> Tensor {
        self.total_scaled(&BTreeMap::new())
    }

    /// The sum of the terms, each further scaled by `extra[name]` where given (KA's target
    /// batches weigh their terms apart from the source's).
    pub fn total_scaled(&self, extra: &BTreeMap<String, f64>) -> Tensor {
        self.terms
            .iter()
            .map(|(n, t)| match extra.get(*n) {
                Some(&w) => t * w,
                None => t.shallow_clone(),
            })
            .reduce(|acc, t| acc + t)
            .unwrap_or_else(|| Tensor::zeros([], (Kind::Float, tch::Device::Cpu)))
    }

    /// Configured scales whose name no stage used (a typo would otherwise be silently ignored).
    pub fn unused_scales(&self) -> Vec<String> {
        self.scale.keys().filter(|k| !self.terms.iter().any(|(n, _)| n == k)).cloned().collect()
    }
}

/// Sigmoid focal loss, summed: `logits` `[..., C]`, one-hot `targets` `[..., C]`, `weights`
/// `[...]` (per anchor).
pub fn sigmoid_focal_loss(logits: &Tensor, targets: &Tensor, weights: &Tensor, alpha: f64, gamma: f64) -> Tensor {
    let p = logits.sigmoid();
    let alpha_w = targets * alpha + one_minus(targets) * (1.0 - alpha);
    let pt = targets * one_minus(&p) + one_minus(targets) * &p;
    let focal_w = alpha_w * pt.pow_tensor_scalar(gamma);
    let bce = bce_with_logits(logits, targets);
    let l: Tensor = focal_w * bce * weights.unsqueeze(-1);
    l.sum(l.kind())
}

/// Quality focal loss (Li et al., "Generalized Focal Loss", 2020) against soft targets in
/// [0, 1]: `α_t · |σ(x) − t|^γ · BCE(x, t)` per element, times per-row weights `[...]`, summed.
/// Unlike [`sigmoid_focal_loss`] with a soft target, its minimum is at `σ(x) = t`, so an output
/// taught a teacher's score of 0.15 settles at 0.15 rather than below it.
pub fn quality_focal_loss(logits: &Tensor, targets: &Tensor, weights: &Tensor, alpha: f64, gamma: f64) -> Tensor {
    let p = logits.sigmoid();
    let alpha_w = targets * alpha + one_minus(targets) * (1.0 - alpha);
    let scale = (p - targets).abs().pow_tensor_scalar(gamma);
    let bce = bce_with_logits(logits, targets);
    let l: Tensor = alpha_w * scale * bce * weights.unsqueeze(-1);
    l.sum(l.kind())
}

/// `sin(a − b) = sin a cos b − cos a sin b`: replaces the heading channel of predictions and
/// targets by the two terms so that a smooth-L1 between them penalises `sin(Δθ)`.
pub fn add_sin_difference(preds: &Tensor, targets: &Tensor, dim: i64) -> (Tensor, Tensor) {
    let n = preds.size()[preds.dim() - 1];
    let (pr, tr) = (preds.narrow(-1, dim, 1), targets.narrow(-1, dim, 1));
    let p_enc = pr.sin() * tr.cos();
    let t_enc = pr.cos() * tr.sin();
    let p = Tensor::cat(&[preds.narrow(-1, 0, dim), p_enc, preds.narrow(-1, dim + 1, n - dim - 1)], -1);
    let t = Tensor::cat(&[targets.narrow(-1, 0, dim), t_enc, targets.narrow(-1, dim + 1, n - dim - 1)], -1);
    (p, t)
}

/// Smooth-L1 (`beta`) per element, times per-code weights `[C]` and per-row weights `[...]`,
/// summed.
pub fn weighted_smooth_l1(
    preds: &Tensor,
    targets: &Tensor,
    code_weights: &Tensor,
    weights: &Tensor,
    beta: f64,
) -> Tensor {
    let diff = (preds - targets).abs();
    let l = if beta < 1e-5 {
        diff
    } else {
        let quad = diff.lt(beta).to_kind(Kind::Float);
        &quad * 0.5 * diff.square() / beta + (1.0 - &quad) * (&diff - 0.5 * beta)
    };
    let l = l * code_weights * weights.unsqueeze(-1);
    l.sum(l.kind())
}

/// Cross-entropy of `logits` `[N, K]` against class indices `targets` `[N]`, weighted per row,
/// summed.
pub fn weighted_cross_entropy(logits: &Tensor, targets: &Tensor, weights: &Tensor) -> Tensor {
    let nll = logits.log_softmax(-1, logits.kind()).gather(1, &targets.unsqueeze(1), false).squeeze_dim(1).neg();
    let l = nll * weights;
    l.sum(l.kind())
}

/// CenterNet focal loss on a heatmap: `logits` and Gaussian `targets` of the same shape, positives
/// where the target is 1; normalised by the number of positives.
pub fn center_focal_loss(logits: &Tensor, targets: &Tensor) -> Tensor {
    center_focal(logits, targets, None)
}

/// [`center_focal_loss`] over the cells where `mask` (same shape, 1 / 0) is 1: masked cells
/// (ignored boxes) add nothing and get no gradient. Still normalised by all the peaks of
/// `targets` (the real positives), so the loss scale does not depend on what is ignored.
pub fn center_focal_loss_masked(logits: &Tensor, targets: &Tensor, mask: &Tensor) -> Tensor {
    center_focal(logits, targets, Some(mask))
}

fn center_focal(logits: &Tensor, targets: &Tensor, mask: Option<&Tensor>) -> Tensor {
    let p = logits.sigmoid().clamp(1e-4, 1.0 - 1e-4);
    let k = logits.kind();
    let pos = targets.eq(1.0).to_kind(k);
    let num_pos = pos.sum(k).clamp_min(1.0);
    let (pos, neg) = match mask {
        Some(m) => {
            let m = m.to_kind(k);
            (&pos * &m, one_minus(&pos) * m)
        }
        None => {
            let neg = one_minus(&pos);
            (pos, neg)
        }
    };
    let neg_w = one_minus(targets).pow_tensor_scalar(4.0);
    let pos_loss = (p.log() * one_minus(&p).square() * &pos).sum(k);
    let neg_loss = (one_minus(&p).log() * p.square() * neg_w * neg).sum(k);
    -(pos_loss + neg_loss) / num_pos
}

/// Masked L1 of gathered predictions `[K, C]` against targets `[K, C]`, per-code weights `[C]`,
/// normalised by the number of objects.
pub fn reg_l1_loss(preds: &Tensor, targets: &Tensor, code_weights: &Tensor, num_objects: f64) -> Tensor {
    let l = preds.l1_loss(targets, Reduction::None) * code_weights;
    l.sum(l.kind()) / (num_objects + 1e-4)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    fn f(v: &[f32]) -> Tensor {
        Tensor::from_slice(v)
    }

    fn close(t: &Tensor, v: f64) {
        let x = t.double_value(&[]);
        assert!((x - v).abs() < 1e-5, "{x} vs {v}");
    }

    #[test]
    fn focal_loss_values() {
        // One anchor, two classes: logit 0 for both, target class 0.
        let l = sigmoid_focal_loss(&f(&[0.0, 0.0]).view([1, 2]), &f(&[1.0, 0.0]).view([1, 2]), &f(&[1.0]), 0.25, 2.0);
        // Each term: bce = ln 2, pt = 0.5 → 0.25·0.25·ln2 + 0.75·0.25·ln2.
        close(&l, 0.25 * 2f64.ln());
        // Zero weight → zero loss.
        let l = sigmoid_focal_loss(&f(&[3.0, -1.0]).view([1, 2]), &f(&[1.0, 0.0]).view([1, 2]), &f(&[0.0]), 0.25, 2.0);
        close(&l, 0.0);
    }

    #[test]
    fn sin_difference_is_periodic() {
        let p = f(&[0.0, 0.0, 0.1]).view([1, 3]);
        let t = f(&[0.0, 0.0, 0.1 + std::f32::consts::PI]).view([1, 3]);
        let (pe, te) = add_sin_difference(&p, &t, 2);
        let l = weighted_smooth_l1(&pe, &te, &f(&[1.0, 1.0, 1.0]), &f(&[1.0]), 1.0 / 9.0);
        assert!(l.double_value(&[]) < 1e-6, "a heading off by π costs nothing (the direction classifier handles it)");
    }

    #[test]
    fn smooth_l1_and_cross_entropy() {
        let l = weighted_smooth_l1(
            &f(&[0.0, 2.0]).view([1, 2]),
            &f(&[0.05, 0.0]).view([1, 2]),
            &f(&[1.0, 0.5]),
            &f(&[2.0]),
            0.1,
        );
        // 0.5·0.05²/0.1 + 0.5·(2 − 0.05), times row weight 2.
        close(&l, 2.0 * (0.5 * 0.0025 / 0.1 + 0.5 * 1.95));
        let ce = weighted_cross_entropy(&f(&[0.0, 0.0]).view([1, 2]), &Tensor::from_slice(&[1i64]), &f(&[1.0]));
        close(&ce, 2f64.ln());
    }

    #[test]
    fn center_focal_loss_gradients_point_the_right_way() {
        let targets = f(&[1.0, 0.5, 0.0, 0.0]).view([1, 4]);
        let logits = Tensor::zeros([1, 4], (Kind::Float, Device::Cpu)).set_requires_grad(true);
        center_focal_loss(&logits, &targets).backward();
        let g: Vec<f32> = logits.grad().view([-1]).try_into().unwrap();
        assert!(g[0] < 0.0, "raise the peak");
        assert!(g[2] > 0.0 && g[3] > 0.0, "lower the background");
        assert!(g[1] > 0.0 && g[1] < g[2], "near-peak cells are pushed down less");
        let l1 = reg_l1_loss(&f(&[1.0, 2.0]).view([1, 2]), &f(&[0.0, 0.0]).view([1, 2]), &f(&[1.0, 1.0]), 1.0);
        assert!((l1.double_value(&[]) - 3.0).abs() < 1e-3);
    }

    /// A soft target's loss is minimal where the score equals it: zero gradient there, pushed
    /// up below it and down above it; with hard targets it is the focal loss without its
    /// `pt`-weight's asymmetry (same sign of gradient as [`sigmoid_focal_loss`]).
    #[test]
    fn quality_focal_loss_settles_on_the_soft_target() {
        let t = 0.15f64;
        let at = (t / (1.0 - t)).ln();
        let logits = f(&[at as f32, (at - 2.0) as f32, (at + 2.0) as f32]).view([1, 3]).set_requires_grad(true);
        let targets = f(&[t as f32; 3]).view([1, 3]);
        quality_focal_loss(&logits, &targets, &f(&[1.0]), 0.25, 2.0).backward();
        let g: Vec<f32> = logits.grad().view([-1]).try_into().unwrap();
        assert!(g[0].abs() < 1e-6, "minimum at the target: {g:?}");
        assert!(g[1] < 0.0 && g[2] > 0.0, "{g:?}");
        // The focal loss with the same soft target is still falling at σ = t: it would settle
        // below the teacher's score.
        let l2 = f(&[at as f32]).view([1, 1]).set_requires_grad(true);
        sigmoid_focal_loss(&l2, &f(&[t as f32]).view([1, 1]), &f(&[1.0]), 0.25, 2.0).backward();
        assert!(l2.grad().double_value(&[0, 0]) > 0.0);
    }

    #[test]
    fn total_scaled_weighs_terms_by_name() {
        let mut scale = BTreeMap::new();
        scale.insert("loc".to_string(), 2.0);
        let mut l = LossTerms::new(&scale);
        l.add("cls", f(&[1.0]).sum(Kind::Float));
        l.add("loc", f(&[3.0]).sum(Kind::Float));
        close(&l.total(), 7.0);
        close(&l.total_scaled(&BTreeMap::new()), 7.0);
        let extra: BTreeMap<String, f64> = [("loc".to_string(), 0.0), ("dir".to_string(), 5.0)].into();
        close(&l.total_scaled(&extra), 1.0);
    }
}
