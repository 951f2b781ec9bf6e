//! Temporal smoothing of per-frame ground estimates along an ordered sequence: per channel (roll,
//! pitch, height) a random-walk Kalman filter with confidence-weighted measurements and innovation
//! gating, plus a Rauch–Tung–Striebel backward pass when the whole sequence is at hand.
//!
//! Smoothing must not erase real motion: a quadruped's gait swings roll and pitch by 10–20° at
//! ≈2 Hz, i.e. up to ≈20° between two 10 Hz frames, and a gusty drone can be as quick. A random
//! walk (not constant velocity: extrapolating a jittering attitude overshoots) with a per-platform
//! rate, raised to what the sequence itself shows, keeps such motion; what smoothing then buys on
//! jittery platforms is bridging frames without ground and rejecting planes that are wildly off,
//! while on a vehicle it also averages out per-frame noise.

use pi3det_data::Platform;
use serde::{Deserialize, Serialize};

use super::GroundEstimate;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SmoothingConfig {
    /// Typical rate of change of roll and pitch (random-walk intensity: variance grows by
    /// `(rate·dt)²` per frame).
    pub angle_rate_std_rad_s: f64,
    /// Typical rate of change of the height above the ground.
    pub height_rate_std_m_s: f64,
    /// Per-frame measurement noise at confidence 1 (variance scaled by `1/confidence`).
    pub angle_meas_std_rad: f64,
    pub height_meas_std_m: f64,
    /// A frame whose innovation exceeds this many standard deviations in any channel is an outlier.
    pub gate_sigma: f64,
    /// After this many outliers in a row the filter restarts from the next estimate: the motion
    /// model was wrong, not the measurements (a filter that keeps gating drifts away for good).
    pub max_consecutive_outliers: usize,
    /// [`smooth_sequence`] raises the rates to the frame-to-frame changes seen in the sequence
    /// itself (robust: median absolute difference of consecutive estimates), and never gates a
    /// change of that usual size, so a platform that moves more than its preset is followed.
    pub adaptive: bool,
    /// Estimates below this confidence are not used.
    pub min_confidence: f64,
    /// Frame spacing when a sequence has no timestamps (Pi3DET records at 10 Hz).
    pub default_dt_s: f64,
}

impl SmoothingConfig {
    /// Rates matched to how the platform moves (see the module note).
    pub fn for_platform(platform: Platform) -> Self {
        // Vehicle: suspension pitch of a degree or two within ~0.5 s. Drone: gusts of ~20° within a
        // second. Quadruped: 15° gait amplitude at 2 Hz → peak rate A·ω ≈ 0.26·4π ≈ 3.3 rad/s.
        let (angle, height) = match platform {
            Platform::Vehicle => (2f64.to_radians(), 0.2),
            Platform::Drone => (20f64.to_radians(), 2.0),
            Platform::Quadruped => (3.3, 1.0),
            Platform::Unknown => (20f64.to_radians(), 1.0),
        };
        Self {
            angle_rate_std_rad_s: angle,
            height_rate_std_m_s: height,
            angle_meas_std_rad: 0.3f64.to_radians(),
            height_meas_std_m: 0.03,
            gate_sigma: 4.0,
            max_consecutive_outliers: 2,
            adaptive: true,
            min_confidence: 0.2,
            default_dt_s: 0.1,
        }
    }
}

impl Default for SmoothingConfig {
    fn default() -> Self {
        Self::for_platform(Platform::Unknown)
    }
}

/// What happened to a frame's estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MeasurementUse {
    Used,
    /// No ground was found in the frame.
    Missing,
    LowConfidence,
    /// Too far from what the neighbouring frames predict.
    Outlier,
}

/// Filtered or smoothed attitude of one frame with its standard deviations. Values are NaN when
/// the sequence has no usable estimate at all.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SmoothedAttitude {
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub height_m: f64,
    pub roll_std_rad: f64,
    pub pitch_std_rad: f64,
    pub height_std_m: f64,
    pub measurement: MeasurementUse,
}

/// Value and variance of one channel.
#[derive(Debug, Clone, Copy, PartialEq)]
struct State {
    x: f64,
    p: f64,
}

const NAN_STATE: State = State { x: f64::NAN, p: f64::NAN };

/// One frame's state in the forward pass, kept for the backward pass.
#[derive(Debug, Clone, Copy)]
struct Step {
    predicted: [State; 3],
    filtered: [State; 3],
    measurement: MeasurementUse,
    /// The filter restarted here: the backward pass does not cross this frame.
    restart: bool,
}

/// Causal (forward) filter: feed frames in time order, get the filtered attitude of each.
#[derive(Debug, Clone)]
pub struct AttitudeFilter {
    config: SmoothingConfig,
    /// Random-walk rate of roll, pitch, height.
    rate_std: [f64; 3],
    /// Innovations below these never count as outliers (see [`SmoothingConfig::adaptive`]).
    gate_floor: [f64; 3],
    state: Option<[State; 3]>,
    last_time_s: Option<f64>,
    outliers_in_row: usize,
}

impl AttitudeFilter {
    pub fn new(config: SmoothingConfig) -> Self {
        let a = config.angle_rate_std_rad_s;
        Self::with_noise(config, [a, a, config.height_rate_std_m_s], [0.0; 3])
    }

    fn with_noise(config: SmoothingConfig, rate_std: [f64; 3], gate_floor: [f64; 3]) -> Self {
        Self { config, rate_std, gate_floor, state: None, last_time_s: None, outliers_in_row: 0 }
    }

    fn step(&mut self, time_s: f64, estimate: Option<&GroundEstimate>) -> Step {
        let dt = match self.last_time_s {
            Some(t) if time_s > t => time_s - t,
            Some(_) => self.config.default_dt_s,
            None => 0.0,
        };
        self.last_time_s = Some(time_s);
        let usable = estimate.filter(|e| e.confidence >= self.config.min_confidence);
        let mut measurement = match (estimate, usable) {
            (None, _) => MeasurementUse::Missing,
            (Some(_), None) => MeasurementUse::LowConfidence,
            (Some(_), Some(_)) => MeasurementUse::Used,
        };
        let meas = usable.map(|e| measurement_of(&self.config, e));
        let start =
            |(z, r): ([f64; 3], [f64; 3])| -> [State; 3] { std::array::from_fn(|i| State { x: z[i], p: r[i] }) };
        let Some(mut state) = self.state else {
            // Not started: the first usable estimate starts it.
            return match meas {
                Some(m) => {
                    let s = start(m);
                    self.state = Some(s);
                    Step { predicted: s, filtered: s, measurement, restart: true }
                }
                None => Step { predicted: [NAN_STATE; 3], filtered: [NAN_STATE; 3], measurement, restart: false },
            };
        };
        for (s, rate) in state.iter_mut().zip(self.rate_std) {
            s.p += (rate * dt).powi(2);
        }
        let predicted = state;
        let mut restart = false;
        if let Some((z, r)) = meas {
            let outlier = (0..3).any(|i| {
                let miss = (z[i] - state[i].x).abs();
                miss > self.config.gate_sigma * (state[i].p + r[i]).sqrt() && miss > self.gate_floor[i]
            });
            if !outlier {
                for i in 0..3 {
                    let k = state[i].p / (state[i].p + r[i]);
                    state[i] = State { x: state[i].x + k * (z[i] - state[i].x), p: (1.0 - k) * state[i].p };
                }
                self.outliers_in_row = 0;
            } else if self.outliers_in_row >= self.config.max_consecutive_outliers {
                state = start((z, r));
                self.outliers_in_row = 0;
                restart = true;
            } else {
                self.outliers_in_row += 1;
                measurement = MeasurementUse::Outlier;
            }
        }
        self.state = Some(state);
        Step { predicted, filtered: state, measurement, restart }
    }

    /// Filters one frame (time in seconds, increasing); `None` when the frame has no ground.
    pub fn update(&mut self, time_s: f64, estimate: Option<&GroundEstimate>) -> SmoothedAttitude {
        let s = self.step(time_s, estimate);
        attitude(&s.filtered, s.measurement)
    }
}

/// Measured values and their variances (scaled by `1/confidence`).
fn measurement_of(config: &SmoothingConfig, e: &GroundEstimate) -> ([f64; 3], [f64; 3]) {
    let c = e.confidence.max(0.05);
    let (sa, sh) = (config.angle_meas_std_rad, config.height_meas_std_m);
    ([e.roll_rad, e.pitch_rad, e.height_m], [sa * sa / c, sa * sa / c, sh * sh / c])
}

/// Robust standard deviation of the frame-to-frame change of each channel over consecutive usable
/// estimates (1.4826 · median |Δ|); `None` with fewer than five changes.
fn observed_step_std(estimates: &[Option<GroundEstimate>], config: &SmoothingConfig) -> [Option<f64>; 3] {
    let used: Vec<[f64; 3]> = estimates
        .iter()
        .flatten()
        .filter(|e| e.confidence >= config.min_confidence)
        .map(|e| measurement_of(config, e).0)
        .collect();
    std::array::from_fn(|c| {
        let mut d: Vec<f64> = used.windows(2).map(|w| (w[1][c] - w[0][c]).abs()).collect();
        if d.len() < 5 {
            return None;
        }
        let mid = d.len() / 2;
        Some(1.4826 * *d.select_nth_unstable_by(mid, f64::total_cmp).1)
    })
}

fn attitude(state: &[State; 3], measurement: MeasurementUse) -> SmoothedAttitude {
    SmoothedAttitude {
        roll_rad: state[0].x,
        pitch_rad: state[1].x,
        height_m: state[2].x,
        roll_std_rad: state[0].p.sqrt(),
        pitch_std_rad: state[1].p.sqrt(),
        height_std_m: state[2].p.sqrt(),
        measurement,
    }
}

/// Frame times of a sequence: the timestamps when every frame has one, else `index · default_dt_s`.
pub fn sequence_times(timestamps_s: &[Option<f64>], default_dt_s: f64) -> Vec<f64> {
    if timestamps_s.iter().all(Option::is_some) {
        timestamps_s.iter().map(|t| t.unwrap_or_default()).collect()
    } else {
        (0..timestamps_s.len()).map(|i| i as f64 * default_dt_s).collect()
    }
}

/// Smooths a whole sequence (forward filter + Rauch–Tung–Striebel backward pass): each frame's
/// attitude uses the frames before and after it. `times_s` increasing, one per estimate.
pub fn smooth_sequence(
    times_s: &[f64],
    estimates: &[Option<GroundEstimate>],
    config: &SmoothingConfig,
) -> Vec<SmoothedAttitude> {
    assert_eq!(times_s.len(), estimates.len(), "one time per estimate");
    let a = config.angle_rate_std_rad_s;
    let mut rate = [a, a, config.height_rate_std_m_s];
    let mut gate_floor = [0.0; 3];
    if config.adaptive {
        let dt = config.default_dt_s.max(1e-3);
        let seen = observed_step_std(estimates, config);
        let noise = [config.angle_meas_std_rad, config.angle_meas_std_rad, config.height_meas_std_m];
        for c in 0..3 {
            let Some(step) = seen[c] else { continue };
            // Differences of two noisy estimates carry 2σ² of noise; the rest is motion.
            let motion = (step * step - 2.0 * noise[c] * noise[c]).max(0.0).sqrt();
            rate[c] = rate[c].max(motion / dt);
            gate_floor[c] = config.gate_sigma * step;
        }
        // One rate for roll and pitch: the platform shakes about both axes.
        let angle = rate[0].max(rate[1]);
        rate[0] = angle;
        rate[1] = angle;
    }
    let mut filter = AttitudeFilter::with_noise(*config, rate, gate_floor);
    let steps: Vec<Step> = times_s.iter().zip(estimates).map(|(&t, e)| filter.step(t, e.as_ref())).collect();
    let Some(first) = steps.iter().position(|s| s.filtered[0].x.is_finite()) else {
        return steps.iter().map(|s| attitude(&s.filtered, s.measurement)).collect();
    };
    let n = steps.len();
    let mut smoothed: Vec<[State; 3]> = steps.iter().map(|s| s.filtered).collect();
    for k in (first..n.saturating_sub(1)).rev() {
        if steps[k + 1].restart {
            continue;
        }
        let next = smoothed[k + 1];
        for (c, out) in smoothed[k].iter_mut().enumerate() {
            let (f, pred) = (steps[k].filtered[c], steps[k + 1].predicted[c]);
            if pred.p <= 0.0 {
                continue;
            }
            let gain = f.p / pred.p;
            *out = State { x: f.x + gain * (next[c].x - pred.x), p: f.p + gain * gain * (next[c].p - pred.p) };
        }
    }
    // Frames before the first usable estimate take the first smoothed value.
    for k in 0..first {
        smoothed[k] = smoothed[first];
    }
    smoothed.iter().zip(&steps).map(|(s, st)| attitude(s, st.measurement)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(roll: f64, pitch: f64, height: f64, confidence: f64) -> GroundEstimate {
        GroundEstimate {
            roll_rad: roll,
            pitch_rad: pitch,
            height_m: height,
            normal_lidar: [0.0, 0.0, 1.0],
            inliers: 1000,
            candidates: 2000,
            inlier_ratio: 0.5,
            rms_m: 0.02,
            spread_m: 10.0,
            confidence,
            iterations: 100,
        }
    }

    /// Deterministic white pseudo-noise, uniform in [-1, 1] (a SplitMix64 hash of k and salt).
    fn noise(k: usize, salt: usize) -> f64 {
        let mut z = (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (salt as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }

    #[test]
    fn smoothing_reduces_noise_fills_gaps_and_rejects_outliers() {
        let n = 200;
        let times: Vec<f64> = (0..n).map(|k| k as f64 * 0.1).collect();
        // Vehicle: slow pitch oscillation of 1° at 0.2 Hz, noisy 0.5° measurements.
        let truth = |t: f64| (1f64.to_radians() * (std::f64::consts::TAU * 0.2 * t).sin(), 1.8);
        let mut est: Vec<Option<GroundEstimate>> = times
            .iter()
            .enumerate()
            .map(|(k, &t)| {
                let (p, h) = truth(t);
                Some(estimate(
                    0.5f64.to_radians() * noise(k, 1),
                    p + 0.5f64.to_radians() * noise(k, 2),
                    h + 0.03 * noise(k, 3),
                    1.0,
                ))
            })
            .collect();
        est[50] = None;
        est[51] = Some(estimate(0.0, 0.0, 1.8, 0.05)); // low confidence
        est[120] = Some(estimate(0.4, -0.3, 0.2, 1.0)); // a wrong plane (a car roof, say)
        let cfg = SmoothingConfig::for_platform(Platform::Vehicle);
        let out = smooth_sequence(&times, &est, &cfg);
        assert_eq!(out[50].measurement, MeasurementUse::Missing);
        assert_eq!(out[51].measurement, MeasurementUse::LowConfidence);
        assert_eq!(out[120].measurement, MeasurementUse::Outlier);
        let rms = |f: &dyn Fn(usize) -> f64| ((0..n).map(|k| f(k).powi(2)).sum::<f64>() / n as f64).sqrt();
        let raw_err = rms(&|k| match (k, &est[k]) {
            (50 | 51 | 120, _) => 0.0,
            (_, Some(e)) => e.pitch_rad - truth(times[k]).0,
            _ => 0.0,
        });
        let smooth_err = rms(&|k| out[k].pitch_rad - truth(times[k]).0);
        assert!(smooth_err < 0.7 * raw_err, "smoothed {smooth_err} vs raw {raw_err}");
        assert!(
            (out[120].height_m - 1.8).abs() < 0.05 && (out[50].pitch_rad - truth(5.0).0).abs() < 0.3f64.to_radians()
        );
    }

    #[test]
    fn quadruped_gait_is_not_smoothed_away() {
        // 15° roll at 2 Hz sampled at 10 Hz, accurate measurements: the smoother must follow it.
        let times: Vec<f64> = (0..100).map(|k| k as f64 * 0.1).collect();
        let truth = |t: f64| 15f64.to_radians() * (std::f64::consts::TAU * 2.0 * t + 0.3).sin();
        let est: Vec<_> = times.iter().map(|&t| Some(estimate(truth(t), 0.0, 0.6, 1.0))).collect();
        let out = smooth_sequence(&times, &est, &SmoothingConfig::for_platform(Platform::Quadruped));
        let worst = times.iter().zip(&out).map(|(&t, s)| (s.roll_rad - truth(t)).abs()).fold(0.0, f64::max);
        assert!(worst < 0.5f64.to_radians(), "worst {:.3}°", worst.to_degrees());
        assert!(out.iter().all(|s| s.measurement == MeasurementUse::Used));
    }

    #[test]
    fn jitter_beyond_the_preset_is_followed_not_smoothed_away() {
        // Drone-like attitude jumping by up to ±8° between frames, seen through accurate estimates,
        // smoothed with the (too calm) vehicle preset: the adaptive process noise must follow it.
        let times: Vec<f64> = (0..150).map(|k| k as f64 * 0.1).collect();
        let truth: Vec<f64> = (0..150).map(|k| 8f64.to_radians() * noise(k, 9)).collect();
        let est: Vec<_> = truth.iter().map(|&p| Some(estimate(0.0, p, 12.0, 1.0))).collect();
        let out = smooth_sequence(&times, &est, &SmoothingConfig::for_platform(Platform::Vehicle));
        let worst = truth.iter().zip(&out).map(|(t, s)| (s.pitch_rad - t).abs()).fold(0.0, f64::max);
        assert!(worst < 1f64.to_radians(), "worst {:.2}°", worst.to_degrees());
    }

    #[test]
    fn restarts_after_consecutive_outliers() {
        // A step of 20° in pitch that stays (the sensor was re-mounted): gated at first, then the
        // filter restarts and follows instead of drifting away.
        let cfg = SmoothingConfig { adaptive: false, ..SmoothingConfig::for_platform(Platform::Vehicle) };
        let times: Vec<f64> = (0..40).map(|k| k as f64 * 0.1).collect();
        let truth = |k: usize| if k < 20 { 0.0 } else { 20f64.to_radians() };
        let est: Vec<_> = (0..40).map(|k| Some(estimate(0.0, truth(k), 1.8, 1.0))).collect();
        let out = smooth_sequence(&times, &est, &cfg);
        assert_eq!(out[20].measurement, MeasurementUse::Outlier);
        assert_eq!(out[21].measurement, MeasurementUse::Outlier);
        assert_eq!(out[22].measurement, MeasurementUse::Used);
        assert!((25..40).all(|k| (out[k].pitch_rad - truth(k)).abs() < 0.2f64.to_radians()));
        assert!((0..20).all(|k| out[k].pitch_rad.abs() < 1e-6));
    }

    #[test]
    fn causal_filter_and_empty_sequences() {
        let mut f = AttitudeFilter::new(SmoothingConfig::default());
        let a = f.update(0.0, None);
        assert!(a.roll_rad.is_nan() && a.measurement == MeasurementUse::Missing);
        let b = f.update(0.1, Some(&estimate(0.1, 0.2, 1.0, 1.0)));
        assert!((b.roll_rad - 0.1).abs() < 1e-12 && (b.height_m - 1.0).abs() < 1e-12);
        let out = smooth_sequence(&[0.0, 0.1], &[None, None], &SmoothingConfig::default());
        assert!(out.iter().all(|s| s.pitch_rad.is_nan()));
        assert_eq!(sequence_times(&[Some(3.0), None], 0.1), vec![0.0, 0.1]);
        assert_eq!(sequence_times(&[Some(3.0), Some(3.2)], 0.1), vec![3.0, 3.2]);
    }
}
