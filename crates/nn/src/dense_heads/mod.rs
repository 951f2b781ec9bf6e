//! Dense (single-stage) detection heads on the BEV feature map, and the contract every head
//! keeps: [`DenseHead`] (the network part: forward, loss, candidate boxes) and
//! [`TargetAssigner`] (its training targets, built from boxes on the loader thread, without the
//! network). A new head implements both and gets a variant in [`crate::config::HeadConfig`];
//! the detector, the loader and the training loop see only the type-erased
//! [`AnyDenseHead`] / [`AnyAssigner`] and need no change.

pub mod anchor_head;
pub mod center_head;

use std::any::Any;

use pi3det_geometry::Box3d;
use tch::{Device, Tensor};

pub use anchor_head::{AnchorHead, AnchorHeadConfig};
pub use center_head::{CenterHead, CenterHeadConfig};

use crate::error::{NnError, Result};
use crate::losses::target_negatives::TargetNegatives;
use crate::losses::LossTerms;

/// Candidate boxes of one frame before NMS, on the CPU, in the detector frame.
pub struct Candidates {
    /// `[K, 7]`.
    pub boxes: Tensor,
    /// `[K]` in `[0, 1]`.
    pub scores: Tensor,
    /// `[K]` int64 class indices.
    pub labels: Tensor,
}

/// Batched targets move to the training device with the inputs.
pub trait ToDevice {
    fn to_device(&self, device: Device) -> Self;
}

/// The network part of a dense head.
pub trait DenseHead {
    type Output: 'static;
    type Targets: 'static;
    /// `bev`: `[B, C, H, W]` BEV features → the head's raw outputs.
    fn forward_t(&self, bev: &Tensor, train: bool) -> Self::Output;
    /// Adds the head's named, weighted loss terms.
    fn loss(&self, out: &Self::Output, targets: &Self::Targets, losses: &mut LossTerms);
    /// The loss of a Knowledge-Adaptation target batch under its background rules
    /// ([`crate::losses::target_negatives`]), with `teacher` the pre-adapted model's outputs on
    /// the same batch when the rules learn its scores; a head without the rules trains the
    /// target as any batch.
    fn loss_target(
        &self,
        out: &Self::Output,
        targets: &Self::Targets,
        _neg: &TargetNegatives,
        _teacher: Option<&Self::Output>,
        losses: &mut LossTerms,
    ) {
        self.loss(out, targets, losses)
    }
    /// Candidates of frame `frame` of the batch scoring at least `score_threshold`, at most
    /// `pre_max` of them, decoded into boxes.
    fn candidates(&self, out: &Self::Output, frame: i64, score_threshold: f64, pre_max: i64) -> Candidates;
    /// The outputs as a tensor list (a TorchScript module's results), in a fixed order…
    fn output_tensors(out: &Self::Output) -> Vec<Tensor>;
    /// …and back.
    fn output_from_tensors(t: Vec<Tensor>) -> Option<Self::Output>;
}

/// Builds a head's training targets from the boxes of a sample (detector frame).
pub trait TargetAssigner: Send + Sync {
    type Frame: Send + 'static;
    type Batch: ToDevice + Send + 'static;
    /// Targets of `boxes` (class `classes[k]` each). Outputs of class `k` on an `ignored` box of
    /// class `k` (`ignored_classes`) count in no loss, unless they are positives of a box; they
    /// stay background for the other classes.
    fn assign(&self, boxes: &[Box3d], classes: &[usize], ignored: &[Box3d], ignored_classes: &[usize]) -> Self::Frame;
    fn collate(&self, frames: &[&Self::Frame]) -> Self::Batch;
}

/// A head's outputs, type-erased.
pub struct DenseOutput(Box<dyn Any>);

/// One frame's targets, type-erased (they cross from the loader thread).
pub struct FrameTargets(Box<dyn Any + Send>);

/// A batch's targets, type-erased.
pub struct BatchTargets(Box<dyn AnyBatch>);

trait AnyBatch: Send {
    fn to_device(&self, device: Device) -> Box<dyn AnyBatch>;
    fn as_any(&self) -> &dyn Any;
}

impl<T: ToDevice + Send + 'static> AnyBatch for T {
    fn to_device(&self, device: Device) -> Box<dyn AnyBatch> {
        Box::new(ToDevice::to_device(self, device))
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl BatchTargets {
    pub fn to_device(&self, device: Device) -> Self {
        Self(self.0.to_device(device))
    }

    /// The concrete targets, when they are of type `T`.
    pub fn downcast_ref<T: 'static>(&self) -> Option<&T> {
        self.0.as_any().downcast_ref()
    }
}

impl DenseOutput {
    pub fn downcast_ref<T: 'static>(&self) -> Option<&T> {
        self.0.downcast_ref()
    }
}

fn mismatch(what: &str) -> NnError {
    NnError::Model(format!("{what} do not belong to this detector's dense head (head/target mismatch)"))
}

/// Object-safe form of [`DenseHead`], implemented for every head.
pub trait AnyDenseHead {
    fn forward_t(&self, bev: &Tensor, train: bool) -> DenseOutput;
    fn loss(&self, out: &DenseOutput, targets: &BatchTargets, losses: &mut LossTerms) -> Result<()>;
    fn loss_target(
        &self,
        out: &DenseOutput,
        targets: &BatchTargets,
        neg: &TargetNegatives,
        teacher: Option<&DenseOutput>,
        losses: &mut LossTerms,
    ) -> Result<()>;
    fn candidates(&self, out: &DenseOutput, frame: i64, score_threshold: f64, pre_max: i64) -> Result<Candidates>;
    fn output_tensors(&self, out: &DenseOutput) -> Result<Vec<Tensor>>;
    fn output_from_tensors(&self, t: Vec<Tensor>) -> Result<DenseOutput>;
}

impl<H: DenseHead> AnyDenseHead for H {
    fn forward_t(&self, bev: &Tensor, train: bool) -> DenseOutput {
        DenseOutput(Box::new(DenseHead::forward_t(self, bev, train)))
    }
    fn loss(&self, out: &DenseOutput, targets: &BatchTargets, losses: &mut LossTerms) -> Result<()> {
        let out = out.downcast_ref::<H::Output>().ok_or_else(|| mismatch("outputs"))?;
        let t = targets.downcast_ref::<H::Targets>().ok_or_else(|| mismatch("targets"))?;
        DenseHead::loss(self, out, t, losses);
        Ok(())
    }
    fn loss_target(
        &self,
        out: &DenseOutput,
        targets: &BatchTargets,
        neg: &TargetNegatives,
        teacher: Option<&DenseOutput>,
        losses: &mut LossTerms,
    ) -> Result<()> {
        let out = out.downcast_ref::<H::Output>().ok_or_else(|| mismatch("outputs"))?;
        let t = targets.downcast_ref::<H::Targets>().ok_or_else(|| mismatch("targets"))?;
        let teacher = match teacher {
            Some(d) => Some(d.downcast_ref::<H::Output>().ok_or_else(|| mismatch("teacher outputs"))?),
            None => None,
        };
        DenseHead::loss_target(self, out, t, neg, teacher, losses);
        Ok(())
    }
    fn candidates(&self, out: &DenseOutput, frame: i64, score_threshold: f64, pre_max: i64) -> Result<Candidates> {
        let out = out.downcast_ref::<H::Output>().ok_or_else(|| mismatch("outputs"))?;
        Ok(DenseHead::candidates(self, out, frame, score_threshold, pre_max))
    }
    fn output_tensors(&self, out: &DenseOutput) -> Result<Vec<Tensor>> {
        Ok(H::output_tensors(out.downcast_ref::<H::Output>().ok_or_else(|| mismatch("outputs"))?))
    }
    fn output_from_tensors(&self, t: Vec<Tensor>) -> Result<DenseOutput> {
        let n = t.len();
        H::output_from_tensors(t)
            .map(|o| DenseOutput(Box::new(o)))
            .ok_or_else(|| NnError::Model(format!("{n} output tensors do not fit this detector's dense head")))
    }
}

/// Object-safe form of [`TargetAssigner`].
pub trait AnyAssigner: Send + Sync {
    fn assign(&self, boxes: &[Box3d], classes: &[usize], ignored: &[Box3d], ignored_classes: &[usize]) -> FrameTargets;
    fn collate(&self, frames: &[&FrameTargets]) -> Result<BatchTargets>;
}

impl<A: TargetAssigner> AnyAssigner for A {
    fn assign(&self, boxes: &[Box3d], classes: &[usize], ignored: &[Box3d], ignored_classes: &[usize]) -> FrameTargets {
        FrameTargets(Box::new(TargetAssigner::assign(self, boxes, classes, ignored, ignored_classes)))
    }
    fn collate(&self, frames: &[&FrameTargets]) -> Result<BatchTargets> {
        let typed: Vec<&A::Frame> = frames
            .iter()
            .map(|f| f.0.downcast_ref::<A::Frame>().ok_or_else(|| mismatch("frame targets")))
            .collect::<Result<_>>()?;
        Ok(BatchTargets(Box::new(TargetAssigner::collate(self, &typed))))
    }
}
