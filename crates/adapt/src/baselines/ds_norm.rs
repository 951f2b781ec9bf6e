//! Domain-specific normalisation (ST3D++ §3.3, after Chang et al.'s DSBN): source and target
//! batches share every batch norm's affine γ/β but keep their own running mean and variance, so
//! the statistics of one domain do not blur the other's; pseudo-labelling and evaluation on the
//! target use the target's. The network keeps one set of buffers; [`DomainNorms`] holds a
//! separate, deep copy per domain and swaps them in and out (`copy_` under `no_grad`), which on
//! CPU guarantees the two never alias one storage.

use tch::nn::VarStore;
use tch::Tensor;

use pi3det_nn::detector::Domain;

/// Per-domain running statistics of every batch norm in a [`VarStore`].
pub struct DomainNorms {
    names: Vec<String>,
    /// The network's own buffers (shallow handles: writing them writes the network).
    live: Vec<Tensor>,
    source: Vec<Tensor>,
    target: Vec<Tensor>,
    current: Domain,
}

fn deep(ts: &[Tensor]) -> Vec<Tensor> {
    ts.iter().map(|t| t.detach().copy()).collect()
}

impl DomainNorms {
    /// Both domains start from the statistics the network has now; the network is in `Source`.
    pub fn new(vs: &VarStore) -> Self {
        let mut vars: Vec<(String, Tensor)> = vs
            .variables()
            .into_iter()
            .filter(|(n, _)| n.ends_with("running_mean") || n.ends_with("running_var"))
            .collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        let (names, live): (Vec<String>, Vec<Tensor>) = vars.into_iter().unzip();
        let (source, target) = (deep(&live), deep(&live));
        Self { names, live, source, target, current: Domain::Source }
    }

    /// Buffers held per domain (two per batch norm).
    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    pub fn current(&self) -> Domain {
        self.current
    }

    /// Puts `domain`'s statistics into the network (saving the current domain's first).
    pub fn enter(&mut self, domain: Domain) {
        if domain == self.current {
            return;
        }
        tch::no_grad(|| {
            let (save, load) = match self.current {
                Domain::Source => (&mut self.source, &self.target),
                Domain::Target => (&mut self.target, &self.source),
            };
            for ((live, s), l) in self.live.iter_mut().zip(save.iter_mut()).zip(load) {
                s.copy_(live);
                live.copy_(l);
            }
        });
        self.current = domain;
    }

    /// `domain`'s statistics as they are now (for tests and reports): the network's own buffers
    /// for the current domain, the stored copy for the other.
    pub fn stats(&self, domain: Domain) -> Vec<(String, Tensor)> {
        let ts = match (domain == self.current, domain) {
            (true, _) => &self.live,
            (false, Domain::Source) => &self.source,
            (false, Domain::Target) => &self.target,
        };
        self.names.iter().cloned().zip(deep(ts)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::{self, ModuleT};
    use tch::{Device, Kind};

    #[test]
    fn statistics_are_kept_apart_and_affine_shared() {
        tch::manual_seed(0);
        let vs = VarStore::new(Device::Cpu);
        let bn = nn::batch_norm1d(vs.root() / "bn", 3, nn::BatchNormConfig { momentum: 0.5, ..Default::default() });
        let mut norms = DomainNorms::new(&vs);
        assert_eq!(norms.len(), 2);
        let batch = |mean: f64| Tensor::randn([256, 3], (Kind::Float, Device::Cpu)) * 0.1 + mean;
        // 16 updates at momentum 0.5 leave 0.5^16 of the initial statistics (mean 0, var 1).
        for _ in 0..16 {
            norms.enter(Domain::Source);
            let _ = bn.forward_t(&batch(5.0), true);
            norms.enter(Domain::Target);
            let _ = bn.forward_t(&batch(-3.0), true);
        }
        let mean_of = |norms: &DomainNorms, d: Domain| {
            let s = norms.stats(d);
            let m = &s.iter().find(|(n, _)| n.ends_with("running_mean")).unwrap().1;
            m.mean(Kind::Float).double_value(&[])
        };
        let (ms, mt) = (mean_of(&norms, Domain::Source), mean_of(&norms, Domain::Target));
        assert!((ms - 5.0).abs() < 0.05, "source mean {ms}");
        assert!((mt + 3.0).abs() < 0.05, "target mean {mt}");
        // The network holds the current (target) domain's; the stored copies are separate storages.
        assert!((bn.running_mean.mean(Kind::Float).double_value(&[]) + 3.0).abs() < 0.05);
        assert_ne!(norms.source[0].data_ptr(), norms.target[0].data_ptr());
        assert_ne!(norms.source[0].data_ptr(), norms.live[0].data_ptr());
        // γ/β are the network's one set: evaluation in either domain uses the same affine.
        norms.enter(Domain::Source);
        let y = bn.forward_t(&batch(5.0), false);
        let ym = y.mean(Kind::Float).double_value(&[]);
        assert!(ym.abs() < 0.1, "source statistics normalise source data: mean {ym}");
        assert_eq!(vs.trainable_variables().len(), 2);
    }
}
