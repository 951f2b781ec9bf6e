//! The ground estimator (crate `pi3det-ground`, re-exported here) and its statistics over a
//! dataset.

pub mod stats;

pub use pi3det_ground::*;
