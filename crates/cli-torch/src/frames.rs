//! Simulated frames for commands that need a few and were given none.

use pi3det_data::{Frame, Platform};
use pi3det_sim::{Sequence, SequenceSpec, SimConfig, SimError};

/// The first `n` frames of simulated vehicle sequence 0 (seed 0): `pi3det bench nn`'s default
/// input.
pub fn vehicle_frames(n: usize) -> Result<Vec<Frame>, SimError> {
    let frames = u32::try_from(n).map_err(|_| SimError::invalid("too many frames"))?;
    let spec = SequenceSpec { platform: Platform::Vehicle, index: 0, frames, seed: 0, layout: None };
    let seq = Sequence::generate(&SimConfig::default(), spec)?;
    Ok((0..seq.len()).map(|f| seq.render(f).to_frame(&format!("{f:07}"), Platform::Vehicle, &seq.name)).collect())
}
