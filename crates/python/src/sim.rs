//! `pi3det.sim`: the multi-platform simulator as an iterator of frames, rendered one at a time
//! (each sequence is generated when its first frame is asked for), the same frames
//! `pi3det simulate` writes for the same platform, seed, sequence indices and frame count.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use pi3det_data::Platform;
use pi3det_sim::export::frame_id;
use pi3det_sim::{Layout, Sequence, SequenceSpec, SimConfig};
use pyo3::exceptions::{PyStopIteration, PyValueError};
use pyo3::prelude::*;

use crate::data::Frame;
use crate::error;

/// An iterator over `sequences × frames` simulated frames (`len()` gives the count).
#[pyclass(module = "pi3det", frozen)]
pub struct Simulation {
    cfg: SimConfig,
    platform: Platform,
    first_sequence: u32,
    sequences: u32,
    frames: u32,
    seed: u64,
    layout: Option<Layout>,
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    /// The next frame to yield, counted over all sequences.
    next: u64,
    /// The sequence being rendered and its index.
    current: Option<(u32, Arc<Sequence>)>,
}

#[pymethods]
impl Simulation {
    fn __len__(&self) -> usize {
        self.sequences as usize * self.frames as usize
    }

    fn __iter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Frame> {
        let (index, f) = {
            let mut st = self.state.lock().map_err(|_| PyValueError::new_err("simulation state poisoned"))?;
            if st.next >= self.__len__() as u64 {
                return Err(PyStopIteration::new_err(()));
            }
            let k = st.next;
            st.next += 1;
            (self.first_sequence + (k / u64::from(self.frames)) as u32, (k % u64::from(self.frames)) as usize)
        };
        let seq = self.sequence(py, index)?;
        let platform = self.platform;
        let frame = py.detach(move || seq.render(f).to_frame(&frame_id(index, f), platform, &seq.name));
        Frame::from_frame(py, frame)
    }

    fn __repr__(&self) -> String {
        format!(
            "Simulation(platform={:?}, sequences={}, frames={}, seed={})",
            self.platform.as_str(),
            self.sequences,
            self.frames,
            self.seed
        )
    }
}

impl Simulation {
    fn sequence(&self, py: Python<'_>, index: u32) -> PyResult<Arc<Sequence>> {
        let mut st = self.state.lock().map_err(|_| PyValueError::new_err("simulation state poisoned"))?;
        if let Some((i, s)) = &st.current {
            if *i == index {
                return Ok(s.clone());
            }
        }
        let spec =
            SequenceSpec { platform: self.platform, index, frames: self.frames, seed: self.seed, layout: self.layout };
        let cfg = &self.cfg;
        let seq = Arc::new(py.detach(|| Sequence::generate(cfg, spec)).map_err(error::sim)?);
        st.current = Some((index, seq.clone()));
        Ok(seq)
    }
}

/// Simulated frames of `platform` (vehicle, drone, quadruped): sequences `first_sequence ..
/// first_sequence + sequences`, `frames` each at 10 Hz, from `seed`; `config` a TOML file of
/// settings to change (`pi3det simulate --print-config` lists them), `layout` urban / suburban /
/// park for every sequence.
#[pyfunction]
#[pyo3(signature = (platform, sequences=1, frames=200, seed=0, layout=None, config=None, first_sequence=0))]
pub fn simulate(
    platform: &str,
    sequences: u32,
    frames: u32,
    seed: u64,
    layout: Option<&str>,
    config: Option<PathBuf>,
    first_sequence: u32,
) -> PyResult<Simulation> {
    let platform = match Platform::parse(platform) {
        Platform::Unknown => {
            return Err(PyValueError::new_err(format!("unknown platform {platform:?} (vehicle, drone, quadruped)")))
        }
        p => p,
    };
    let layout = match layout {
        None => None,
        Some(s) => Some(
            Layout::ALL
                .into_iter()
                .find(|l| l.as_str().eq_ignore_ascii_case(s))
                .ok_or_else(|| PyValueError::new_err(format!("unknown layout {s:?} (urban, suburban, park)")))?,
        ),
    };
    if frames == 0 || frames > 9999 {
        return Err(PyValueError::new_err(format!("frames must be 1..=9999, not {frames}")));
    }
    let cfg = match config {
        Some(p) => SimConfig::load(&p).map_err(error::sim)?,
        None => SimConfig::default(),
    };
    cfg.validate().map_err(error::sim)?;
    cfg.platform(platform).map_err(error::sim)?;
    Ok(Simulation {
        cfg,
        platform,
        first_sequence,
        sequences,
        frames,
        seed,
        layout,
        state: Mutex::new(State::default()),
    })
}
