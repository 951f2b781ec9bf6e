//! Pose-free sensor attitude from the ground: a robust plane fit to one LiDAR scan gives the
//! sensor's roll, pitch and height above the ground, assuming the ground is level in the world.
//! The released Pi3DET layout has no poses, yet Virtual Platform Pose needs exactly these three
//! numbers; [`estimate_ground`] is the function the adaptation code calls, and
//! [`smoothing`] filters the per-frame estimates along an ordered sequence.
//!
//! Its own crate (no plotting dependencies) so that the detector crate can level frames with it;
//! `pi3det-analysis` re-exports it as `pi3det_analysis::ground` with its statistics.
//!
//! Angles follow the geometry crate (`RollPitchYaw`, extrinsic 'xyz', `R = Rz·Ry·Rx`): for a sensor
//! with roll r and pitch p over level ground, the world's up axis seen in the LiDAR frame is
//! `(-sin p, sin r cos p, cos r cos p)`, which is the fitted ground normal.

pub mod local;
pub mod plane;
pub mod smoothing;

pub use local::{LabelGroundCheck, LocalGround};

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use pi3det_geometry::{level_from_sensor, Pose, RollPitchYaw};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use plane::{fit_least_squares, inliers, ransac, Plane, PlaneFit, PlanePrior, RansacParams};

/// What we assume before looking: the sensor is mounted roughly level (its attitude within
/// `max_tilt_rad` of `roll_rad`/`pitch_rad`) and the ground is below it, between `min_height_m`
/// and `max_height_m`. Hypotheses outside are never considered, which rules out walls, overhead
/// decks (underpasses, bridges) and ceilings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AttitudePrior {
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub max_tilt_rad: f64,
    pub min_height_m: f64,
    pub max_height_m: f64,
}

impl Default for AttitudePrior {
    fn default() -> Self {
        // 35°: drones and quadrupeds reach ±20° in roll and pitch at once (≈28° of tilt).
        Self { roll_rad: 0.0, pitch_rad: 0.0, max_tilt_rad: 35f64.to_radians(), min_height_m: 0.1, max_height_m: 200.0 }
    }
}

/// Settings of the ground fit; the defaults suit 32–128 beam spinning LiDARs on all three
/// platforms.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GroundConfig {
    /// Inlier band around the plane. 10 cm: above range noise (≈2 cm) and road camber over the
    /// dense near field, below kerb height (≈12–15 cm) so pavements don't tilt the road plane.
    pub inlier_threshold_m: f64,
    /// Points closer than this are ignored (returns from the platform's own body).
    pub min_range_m: f64,
    /// Points farther than this are ignored (sparse, and the ground is rarely one plane that far).
    pub max_range_m: f64,
    /// At most this many points (every k-th) enter the fit; keeps a frame at a few milliseconds.
    pub max_candidates: usize,
    pub min_iterations: usize,
    pub max_iterations: usize,
    pub success_probability: f64,
    /// Least-squares / inlier re-selection rounds after RANSAC.
    pub refine_rounds: usize,
    /// After a first fit on every candidate, the fit is redone on the points within
    /// `max(local_range_min_m, local_range_factor · height)` of the sensor: the attitude relative
    /// to the ground the platform stands on, not to a road that bends 60 m away. A high drone
    /// (ground only seen far away) keeps the first fit.
    pub local_range_min_m: f64,
    pub local_range_factor: f64,
    /// Fewer inliers than this: no ground found.
    pub min_inliers: usize,
    pub prior: AttitudePrior,
    /// RANSAC's random generator seed: the same points and seed give the same estimate.
    pub seed: u64,
}

impl Default for GroundConfig {
    fn default() -> Self {
        Self {
            inlier_threshold_m: 0.10,
            min_range_m: 1.0,
            max_range_m: 80.0,
            max_candidates: 30_000,
            min_iterations: 60,
            max_iterations: 1000,
            success_probability: 0.999,
            refine_rounds: 3,
            local_range_min_m: 20.0,
            local_range_factor: 4.0,
            min_inliers: 100,
            prior: AttitudePrior::default(),
            seed: 0,
        }
    }
}

/// The ground seen from one scan and the sensor attitude it implies.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GroundEstimate {
    /// Sensor roll and pitch relative to the ground plane (= to the world if the ground is level).
    pub roll_rad: f64,
    pub pitch_rad: f64,
    /// Sensor height above the plane.
    pub height_m: f64,
    /// Unit ground normal (up) in the LiDAR frame.
    pub normal_lidar: [f64; 3],
    pub inliers: usize,
    /// Points that entered the fit (after the range filter and subsampling).
    pub candidates: usize,
    /// `inliers / candidates`: the share of the scan on the ground plane.
    pub inlier_ratio: f64,
    /// RMS distance of the inliers to the plane.
    pub rms_m: f64,
    /// Spread of the inliers along the plane's weaker axis.
    pub spread_m: f64,
    /// 0..1: `min(1, ratio/0.25) · (1 − e^(−inliers/200)) · min(1, spread/2 m)` — low when little of
    /// the scan is ground, when there are few inliers, or when they lie along a thin strip.
    pub confidence: f64,
    pub iterations: usize,
}

impl GroundEstimate {
    /// Roll and pitch (yaw is unobservable from the ground and set to 0).
    pub fn attitude(&self) -> RollPitchYaw {
        RollPitchYaw { roll_rad: self.roll_rad, pitch_rad: self.pitch_rad, yaw_rad: 0.0 }
    }

    /// Rotation taking LiDAR-frame vectors to a level frame with the sensor's yaw
    /// (`R_y(pitch)·R_x(roll)`, as Virtual Platform Pose undoes roll and pitch).
    pub fn level_from_lidar(&self) -> UnitQuaternion<f64> {
        level_from_sensor(self.attitude())
    }

    /// Pose of the LiDAR in a level frame whose origin is on the ground right below the sensor.
    pub fn ground_from_lidar(&self) -> Pose {
        Pose::from_parts(Translation3::new(0.0, 0.0, self.height_m), self.level_from_lidar())
    }
}

/// Why no ground was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GroundError {
    #[error("only {candidates} points in the fitting range ({needed} needed)")]
    TooFewPoints { candidates: usize, needed: usize },
    #[error(
        "no plane below the sensor within the tilt prior has {needed} inliers (best: {best_inliers} of {candidates})"
    )]
    NoPlane { candidates: usize, best_inliers: usize, needed: usize },
}

fn norm2(p: &[f64; 3]) -> f64 {
    p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
}

/// The up axis of the world seen in the LiDAR frame of a sensor with this roll and pitch.
pub fn up_in_lidar(roll_rad: f64, pitch_rad: f64) -> Vector3<f64> {
    let (sr, cr) = roll_rad.sin_cos();
    let (sp, cp) = pitch_rad.sin_cos();
    Vector3::new(-sp, sr * cp, cr * cp)
}

/// Roll and pitch of a sensor that sees the world's up axis as `up` (unit, LiDAR frame).
pub fn roll_pitch_from_up(up: &Vector3<f64>) -> (f64, f64) {
    (up.y.atan2(up.z), (-up.x).atan2(up.y.hypot(up.z)))
}

/// Estimates roll, pitch and height of the sensor above the ground from one scan's points (LiDAR
/// frame): RANSAC over three-point planes that the prior accepts (below the sensor, roughly level),
/// then least squares on the inliers. Deterministic for a given `config.seed`.
pub fn estimate_ground<I>(points: I, config: &GroundConfig) -> Result<GroundEstimate, GroundError>
where
    I: IntoIterator<Item = [f64; 3]>,
{
    let (r2_min, r2_max) = (config.min_range_m.powi(2), config.max_range_m.powi(2));
    let mut candidates: Vec<[f64; 3]> = points
        .into_iter()
        .filter(|p| {
            let r2 = norm2(p);
            p.iter().all(|v| v.is_finite()) && r2 >= r2_min && r2 <= r2_max
        })
        .collect();
    if candidates.len() > config.max_candidates && config.max_candidates > 0 {
        // Every k-th point: deterministic and spread over the whole scan (points are stored by
        // beam or by azimuth, both fine to stride through).
        let step = candidates.len().div_ceil(config.max_candidates);
        candidates = candidates.into_iter().step_by(step).collect();
    }
    let needed = config.min_inliers.max(3);
    if candidates.len() < needed {
        return Err(GroundError::TooFewPoints { candidates: candidates.len(), needed });
    }
    let prior = &config.prior;
    let plane_prior = PlanePrior {
        up: up_in_lidar(prior.roll_rad, prior.pitch_rad),
        cos_max_tilt: prior.max_tilt_rad.cos(),
        min_height_m: prior.min_height_m,
        max_height_m: prior.max_height_m,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let global = fit_pass(&candidates, config, &plane_prior, &mut rng)?;
    // Second pass on the ground around the platform (see `local_range_min_m`).
    let r = config.local_range_min_m.max(config.local_range_factor * global.plane.offset_m);
    let chosen = if r < config.max_range_m {
        let near: Vec<[f64; 3]> = candidates.iter().copied().filter(|p| norm2(p) <= r * r).collect();
        match fit_pass(&near, config, &plane_prior, &mut rng) {
            Ok(local) => (local, near),
            Err(_) => (global, candidates),
        }
    } else {
        (global, candidates)
    };
    let (pass, used) = chosen;
    let inlier_ratio = pass.inliers as f64 / used.len() as f64;
    let confidence = (inlier_ratio / 0.25).min(1.0)
        * (1.0 - (-(pass.inliers as f64) / 200.0).exp())
        * (pass.fit.spread_m / 2.0).min(1.0);
    let (roll_rad, pitch_rad) = roll_pitch_from_up(&pass.plane.normal);
    Ok(GroundEstimate {
        roll_rad,
        pitch_rad,
        height_m: pass.plane.offset_m,
        normal_lidar: pass.plane.normal.into(),
        inliers: pass.inliers,
        candidates: used.len(),
        inlier_ratio,
        rms_m: pass.fit.rms_m,
        spread_m: pass.fit.spread_m,
        confidence,
        iterations: pass.iterations,
    })
}

/// One RANSAC + least-squares pass.
struct Pass {
    plane: Plane,
    fit: PlaneFit,
    inliers: usize,
    iterations: usize,
}

fn fit_pass(
    candidates: &[[f64; 3]],
    config: &GroundConfig,
    prior: &PlanePrior,
    rng: &mut ChaCha8Rng,
) -> Result<Pass, GroundError> {
    let needed = config.min_inliers.max(3);
    let no_plane = |best| GroundError::NoPlane { candidates: candidates.len(), best_inliers: best, needed };
    if candidates.len() < needed {
        return Err(no_plane(0));
    }
    let params = RansacParams {
        threshold_m: config.inlier_threshold_m,
        min_iterations: config.min_iterations,
        max_iterations: config.max_iterations.max(1),
        success_probability: config.success_probability,
    };
    let found = ransac(candidates, prior, &params, rng).ok_or_else(|| no_plane(0))?;
    let mut plane = found.plane;
    let mut idx = inliers(candidates, &plane, config.inlier_threshold_m);
    let mut fit = fit_least_squares(candidates, &idx, &prior.up).ok_or_else(|| no_plane(idx.len()))?;
    for _ in 0..config.refine_rounds {
        // A refit that leaves the prior (it can only drift there on a degenerate inlier set)
        // is not taken.
        if !prior.accepts(&fit.plane) {
            break;
        }
        plane = fit.plane;
        let next = inliers(candidates, &plane, config.inlier_threshold_m);
        if next == idx {
            break;
        }
        idx = next;
        match fit_least_squares(candidates, &idx, &prior.up) {
            Some(f) => fit = f,
            None => break,
        }
    }
    if prior.accepts(&fit.plane) {
        plane = fit.plane;
    }
    let count = inliers(candidates, &plane, config.inlier_threshold_m).len();
    if count < needed {
        return Err(no_plane(count));
    }
    Ok(Pass { plane, fit, inliers: count, iterations: found.iterations })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use pi3det_geometry::PoseExt;

    /// Level ground at world z = 0 on a polar grid (like a spinning LiDAR's rings), a wall, a
    /// box-shaped car and an overhead deck, seen by a sensor at `height` with roll/pitch.
    fn scene(height: f64, roll: f64, pitch: f64, yaw: f64) -> Vec<[f64; 3]> {
        let world_from_lidar = Pose::from_xyz_rpy([3.0, -2.0, height], roll, pitch, yaw);
        let lidar_from_world = world_from_lidar.inverse();
        let mut world = Vec::new();
        for ring in 0..40 {
            let r = 2.0 + ring as f64 * 0.8;
            for k in 0..180 {
                let a = k as f64 * std::f64::consts::TAU / 180.0;
                world.push([3.0 + r * a.cos(), -2.0 + r * a.sin(), 0.0]);
            }
        }
        for i in 0..2000 {
            // Wall 8 m away along world y, 6 m tall.
            world.push([-10.0 + (i % 100) as f64 * 0.2, 6.0, (i / 100) as f64 * 0.3]);
            // Deck 4 m above the ground (above every sensor height we test except the drone).
            world.push([(i % 50) as f64 * 0.4 - 10.0, (i / 50) as f64 * 0.4 - 8.0, 4.0]);
        }
        for i in 0..400 {
            world.push([8.0 + (i % 20) as f64 * 0.2, -5.0 + (i / 20) as f64 * 0.1, 1.5]);
        }
        world
            .into_iter()
            .map(|p| {
                let q = lidar_from_world.transform_point(&Point3::from(p));
                [q.x, q.y, q.z]
            })
            .collect()
    }

    #[test]
    fn recovers_roll_pitch_height_of_known_poses() {
        for &(h, r, p, y) in
            &[(1.73, 0.0, 0.0, 0.0), (0.6, 0.2, -0.15, 1.0), (1.9, -0.03, 0.02, -2.0), (0.55, -0.3, 0.25, 0.4)]
        {
            let est = estimate_ground(scene(h, r, p, y), &GroundConfig::default()).unwrap();
            assert!((est.roll_rad - r).abs() < 1e-6, "roll {} vs {r}", est.roll_rad);
            assert!((est.pitch_rad - p).abs() < 1e-6, "pitch {} vs {p}", est.pitch_rad);
            assert!((est.height_m - h).abs() < 1e-6, "height {} vs {h}", est.height_m);
            assert!(est.confidence > 0.9, "{est:?}");
            // Levelling the points puts the ground at z = -height.
            let ground_from_lidar = est.ground_from_lidar();
            let g = ground_from_lidar.transform_point(&Point3::new(0.0, 0.0, 0.0));
            assert!((g.z - h).abs() < 1e-9);
            let rpy_from_pose = Pose::from_xyz_rpy([0.0; 3], r, p, y).roll_pitch_yaw();
            assert!((rpy_from_pose.roll_rad - est.roll_rad).abs() < 1e-6);
        }
    }

    #[test]
    fn deterministic_for_a_seed() {
        let pts = scene(1.8, 0.05, 0.03, 0.0);
        let a = estimate_ground(pts.iter().copied(), &GroundConfig::default()).unwrap();
        let b = estimate_ground(pts.iter().copied(), &GroundConfig::default()).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn ground_must_be_below_and_roughly_level() {
        // A ceiling 2 m above the sensor: the sensor must be above the ground.
        let ceiling: Vec<[f64; 3]> =
            (0..3000).map(|i| [(i % 60) as f64 * 0.3 - 9.0, (i / 60) as f64 * 0.3 - 7.0, 2.0]).collect();
        assert!(matches!(estimate_ground(ceiling, &GroundConfig::default()), Err(GroundError::NoPlane { .. })));
        // A 50° slope below the sensor: steeper than the 35° tilt prior.
        let slope: Vec<[f64; 3]> = (0..3000)
            .map(|i| {
                let (x, y) = ((i % 60) as f64 * 0.2 + 1.0, (i / 60) as f64 * 0.3 - 7.0);
                [x, y, -5.0 + x * 50f64.to_radians().tan()]
            })
            .collect();
        assert!(matches!(estimate_ground(slope, &GroundConfig::default()), Err(GroundError::NoPlane { .. })));
        assert!(matches!(
            estimate_ground(vec![[0.0, 0.0, 0.0]; 10], &GroundConfig::default()),
            Err(GroundError::TooFewPoints { .. })
        ));
    }

    #[test]
    fn up_and_roll_pitch_are_inverse() {
        for &(r, p) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4)] {
            let up = up_in_lidar(r, p);
            let world_from_lidar = Pose::from_xyz_rpy([0.0; 3], r, p, 0.7);
            // up seen in LiDAR = R^T e_z.
            let expected = world_from_lidar.rotation.inverse() * Vector3::z();
            assert!((up - expected).norm() < 1e-12);
            let (r2, p2) = roll_pitch_from_up(&up);
            assert!((r2 - r).abs() < 1e-12 && (p2 - p).abs() < 1e-12);
        }
    }
}
