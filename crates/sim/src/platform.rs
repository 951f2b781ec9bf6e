//! The three platforms: how they move, how high they carry the sensor and how they tilt.
//! Vehicle: on the road, smooth, attitude from terrain, acceleration and cornering (< 2°).
//! Quadruped: on sidewalks and paths, low, with gait oscillation and stair/slope tilt.
//! Drone: over the streets at 4–20 m, slow flight and hover, attitude from acceleration and gusts.

use pi3det_data::Platform;
use pi3det_geometry::{Pose, PoseExt};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::rng::{normal, uniform_in};
use crate::roads::RoadGrid;
use crate::route::Route;
use crate::scene::Layout;
use crate::SimError;

/// Where on the street a platform travels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Lane {
    /// The right-hand lane.
    Road,
    /// The middle of the right-hand sidewalk (the path itself where there is none).
    Sidewalk,
    /// Above the street's centre line.
    Centre,
}

/// Motion and attitude model of one platform. Ranges are `[min, max]`; per-sequence values are
/// drawn from them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlatformConfig {
    /// Relative weights of the urban, suburban and park layouts.
    pub layout_weights: [f64; 3],
    pub lane: Lane,
    /// Sensor height above what the platform stands on (the ground under a drone).
    pub sensor_height_m: [f64; 2],
    /// Per-sequence heights are drawn as `min + (max − min)·u^height_exponent` with `u` uniform:
    /// 1 is uniform, below 1 favours the upper end (drones mostly fly well above the minimum).
    pub height_exponent: f64,
    /// Slow random variation of that height (drone altitude changes), one sigma.
    pub height_variation_m: f64,
    pub speed_mps: [f64; 2],
    /// Random speed variation (Ornstein–Uhlenbeck sigma, m/s) and its time constant.
    pub speed_variation_mps: f64,
    pub speed_time_constant_s: f64,
    pub max_accel_mps2: f64,
    /// Speed is reduced ahead of curves so that `v²·curvature` stays below this.
    pub max_lateral_accel_mps2: f64,
    /// Share of time spent hovering or standing still.
    pub hover_share: f64,
    pub turn_radius_m: f64,
    /// Body length and width over which the ground's slope is felt.
    pub body_length_m: f64,
    pub body_width_m: f64,
    /// Low-pass time constant of the terrain tilt (suspension, legs).
    pub terrain_tilt_time_constant_s: f64,
    /// Gait: frequency range and roll/pitch amplitudes at full speed.
    pub gait_frequency_hz: [f64; 2],
    pub gait_roll_amplitude_deg: f64,
    pub gait_pitch_amplitude_deg: f64,
    pub gait_bounce_m: f64,
    /// Random attitude disturbance (suspension, footfalls, gusts): sigma and time constant.
    pub jitter_std_deg: f64,
    pub jitter_time_constant_s: f64,
    /// Pitch and roll per m/s² of forward and lateral acceleration (body squat and lean; a drone
    /// tilts into its acceleration).
    pub pitch_per_accel_deg: f64,
    pub roll_per_lateral_accel_deg: f64,
    /// Tilt into acceleration like a multirotor (`atan(a/g)`) instead of the linear body lean.
    pub thrust_tilt: bool,
    /// Slow yaw wander around the route heading, sigma.
    pub yaw_wander_deg: f64,
    pub attitude_limit_deg: f64,
    /// The platform's own body as a box in the sensor frame, `[cx, cy, cz, dx, dy, dz]`: rays
    /// that hit it return nothing (real pipelines crop self-returns). All zero: no body.
    pub body_box_m: [f64; 6],
    /// Keep scenery and parked actors this far from the route.
    pub clearance_m: f64,
    pub steps: bool,
    pub underpass: bool,
    /// Multiplies the layout's pedestrian densities.
    pub pedestrian_scale: f64,
    /// People keeping pace with the platform beside it: count, lateral offset and distance
    /// ahead (negative: behind) ranges.
    pub companions: [u32; 2],
    pub companion_offset_m: [f64; 2],
    pub companion_ahead_m: [f64; 2],
}

impl PlatformConfig {
    pub fn preset(platform: Platform) -> Self {
        match platform {
            Platform::Drone => Self::drone(),
            Platform::Quadruped => Self::quadruped(),
            _ => Self::vehicle(),
        }
    }

    pub fn vehicle() -> Self {
        Self {
            layout_weights: [0.55, 0.45, 0.0],
            lane: Lane::Road,
            sensor_height_m: [1.8, 2.0],
            height_exponent: 1.0,
            height_variation_m: 0.0,
            speed_mps: [3.0, 12.0],
            speed_variation_mps: 1.0,
            speed_time_constant_s: 4.0,
            max_accel_mps2: 2.0,
            max_lateral_accel_mps2: 3.0,
            hover_share: 0.0,
            turn_radius_m: 9.0,
            body_length_m: 2.8,
            body_width_m: 1.6,
            terrain_tilt_time_constant_s: 0.15,
            gait_frequency_hz: [0.0, 0.0],
            gait_roll_amplitude_deg: 0.0,
            gait_pitch_amplitude_deg: 0.0,
            gait_bounce_m: 0.0,
            jitter_std_deg: 0.3,
            jitter_time_constant_s: 0.3,
            pitch_per_accel_deg: 0.4,
            roll_per_lateral_accel_deg: 0.35,
            thrust_tilt: false,
            yaw_wander_deg: 0.0,
            attitude_limit_deg: 4.0,
            body_box_m: [0.0; 6],
            clearance_m: 2.0,
            steps: false,
            underpass: false,
            pedestrian_scale: 1.0,
            companions: [0, 0],
            companion_offset_m: [1.5, 2.5],
            companion_ahead_m: [-3.0, 6.0],
        }
    }

    pub fn quadruped() -> Self {
        Self {
            layout_weights: [0.45, 0.35, 0.2],
            lane: Lane::Sidewalk,
            sensor_height_m: [0.5, 0.7],
            height_exponent: 1.0,
            height_variation_m: 0.0,
            speed_mps: [0.5, 1.5],
            speed_variation_mps: 0.2,
            speed_time_constant_s: 3.0,
            max_accel_mps2: 1.0,
            max_lateral_accel_mps2: 1.0,
            hover_share: 0.1,
            turn_radius_m: 2.0,
            body_length_m: 0.9,
            body_width_m: 0.45,
            terrain_tilt_time_constant_s: 0.25,
            gait_frequency_hz: [1.5, 2.5],
            gait_roll_amplitude_deg: 10.0,
            gait_pitch_amplitude_deg: 7.0,
            gait_bounce_m: 0.02,
            jitter_std_deg: 3.5,
            jitter_time_constant_s: 0.2,
            pitch_per_accel_deg: 1.5,
            roll_per_lateral_accel_deg: 1.5,
            thrust_tilt: false,
            yaw_wander_deg: 3.0,
            attitude_limit_deg: 30.0,
            body_box_m: [0.1, 0.0, -0.35, 1.1, 0.6, 0.5],
            clearance_m: 1.0,
            steps: true,
            underpass: true,
            pedestrian_scale: 2.5,
            companions: [2, 6],
            companion_offset_m: [1.2, 2.5],
            companion_ahead_m: [-3.0, 6.0],
        }
    }

    pub fn drone() -> Self {
        Self {
            layout_weights: [0.2, 0.4, 0.4],
            lane: Lane::Centre,
            sensor_height_m: [4.0, 20.0],
            height_exponent: 0.5,
            height_variation_m: 1.0,
            speed_mps: [0.5, 4.0],
            speed_variation_mps: 0.6,
            speed_time_constant_s: 3.0,
            max_accel_mps2: 1.5,
            max_lateral_accel_mps2: 2.0,
            hover_share: 0.3,
            turn_radius_m: 6.0,
            body_length_m: 0.0,
            body_width_m: 0.0,
            terrain_tilt_time_constant_s: 0.0,
            gait_frequency_hz: [0.0, 0.0],
            gait_roll_amplitude_deg: 0.0,
            gait_pitch_amplitude_deg: 0.0,
            gait_bounce_m: 0.0,
            jitter_std_deg: 7.5,
            jitter_time_constant_s: 0.6,
            pitch_per_accel_deg: 0.0,
            roll_per_lateral_accel_deg: 0.0,
            thrust_tilt: true,
            yaw_wander_deg: 10.0,
            attitude_limit_deg: 20.0,
            body_box_m: [0.0; 6],
            clearance_m: 4.0,
            steps: false,
            underpass: false,
            pedestrian_scale: 1.0,
            companions: [0, 0],
            companion_offset_m: [1.5, 2.5],
            companion_ahead_m: [-3.0, 6.0],
        }
    }

    pub fn validate(&self, name: &str) -> Result<(), SimError> {
        let bad = |m: &str| Err(SimError::invalid(format!("{name}: {m}")));
        if self.layout_weights.iter().any(|w| *w < 0.0) || self.layout_weights.iter().sum::<f64>() <= 0.0 {
            return bad("layout_weights must be non-negative with a positive sum");
        }
        if !(self.speed_mps[0] >= 0.0 && self.speed_mps[1] >= self.speed_mps[0]) {
            return bad("speed_mps must be an increasing non-negative range");
        }
        if self.sensor_height_m[0].is_nan() || self.sensor_height_m[0] <= 0.0 {
            return bad("sensor_height_m must be positive");
        }
        Ok(())
    }

    /// Draws a layout by the weights.
    pub fn pick_layout<R: Rng + ?Sized>(&self, rng: &mut R) -> Layout {
        let total: f64 = self.layout_weights.iter().sum();
        let mut x = rng.random_range(0.0..1.0) * total;
        for (w, l) in self.layout_weights.iter().zip(Layout::ALL) {
            x -= w;
            if x < 0.0 && *w > 0.0 {
                return l;
            }
        }
        Layout::ALL[self.layout_weights.iter().rposition(|w| *w > 0.0).unwrap_or(0)]
    }

    /// Lateral offset of the route from the street centre line (positive: right of travel).
    pub fn lane_offset_m(&self, roads: &RoadGrid) -> f64 {
        match self.lane {
            Lane::Road => 0.3 * roads.road_half_width_m,
            Lane::Sidewalk if roads.sidewalk_width_m > 0.0 => roads.road_half_width_m + 0.5 * roads.sidewalk_width_m,
            Lane::Sidewalk => 0.4 * roads.road_half_width_m,
            Lane::Centre => 0.0,
        }
    }
}

/// A random drive/walk/flight over the street grid of at least `length_m`: from a point between two
/// junctions to the next junction, then straight on (half the time) or turning, never back.
pub fn plan_route<R: Rng + ?Sized>(cfg: &PlatformConfig, roads: &RoadGrid, length_m: f64, rng: &mut R) -> Route {
    let dirs: [[i64; 2]; 4] = [[1, 0], [0, 1], [-1, 0], [0, -1]];
    let mut d = rng.random_range(0..4usize);
    let mut ij = (0i64, 0i64);
    let start_frac: f64 = rng.random_range(0.15..0.6);
    let first = roads.intersection(ij);
    let mut centre = vec![[
        first[0] + dirs[d][0] as f64 * start_frac * roads.block_m,
        first[1] + dirs[d][1] as f64 * start_frac * roads.block_m,
    ]];
    let mut travelled = -start_frac * roads.block_m;
    let mut headings = vec![d];
    while travelled < length_m + 20.0 {
        ij = (ij.0 + dirs[d][0], ij.1 + dirs[d][1]);
        centre.push(roads.intersection(ij));
        travelled += roads.block_m;
        let r: f64 = rng.random_range(0.0..1.0);
        d = if r < 0.5 {
            d
        } else if r < 0.75 {
            (d + 1) % 4
        } else {
            (d + 3) % 4
        };
        headings.push(d);
    }
    // One more point past the last junction so the route ends on a street.
    let last = *centre.last().unwrap_or(&first);
    centre.push([last[0] + dirs[d][0] as f64 * 0.5 * roads.block_m, last[1] + dirs[d][1] as f64 * 0.5 * roads.block_m]);
    headings.push(d);
    // Shift right of travel by the lane offset, mitred at corners.
    let off = cfg.lane_offset_m(roads);
    let right = |k: usize| [dirs[headings[k]][1] as f64, -(dirs[headings[k]][0] as f64)];
    let n = centre.len();
    let mut corners = Vec::with_capacity(n);
    for (k, c) in centre.iter().enumerate() {
        let n_in = right(k.saturating_sub(1));
        let n_out = right(k.min(n - 2));
        let dot = n_in[0] * n_out[0] + n_in[1] * n_out[1];
        let m = off / (1.0 + dot).max(1e-6);
        corners.push([c[0] + m * (n_in[0] + n_out[0]), c[1] + m * (n_in[1] + n_out[1])]);
    }
    Route::rounded(&corners, cfg.turn_radius_m, 0.5)
}

/// Ornstein–Uhlenbeck step (exact discretisation) with stationary standard deviation `sigma`.
fn ou_step<R: Rng + ?Sized>(x: f64, mean: f64, sigma: f64, tau_s: f64, dt: f64, rng: &mut R) -> f64 {
    if tau_s <= 0.0 {
        return mean + sigma * normal(rng);
    }
    let a = (-dt / tau_s).exp();
    mean + a * (x - mean) + sigma * (1.0 - a * a).sqrt() * normal(rng)
}

/// The platform at one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformState {
    pub world_from_lidar: Pose,
    pub speed_mps: f64,
    /// Arc length travelled along the route.
    pub s_m: f64,
    pub height_above_support_m: f64,
}

/// Simulates `frames` states at `dt_s` along `route`; `support(xy)` is the height of what the
/// platform stands on (or flies over).
pub fn simulate<R: Rng + ?Sized>(
    cfg: &PlatformConfig,
    route: &Route,
    support: &dyn Fn([f64; 2]) -> f64,
    frames: usize,
    dt_s: f64,
    rng: &mut R,
) -> Vec<PlatformState> {
    let deg = std::f64::consts::PI / 180.0;
    let g = 9.81;
    let u: f64 = rng.random_range(0.0..=1.0);
    let base_height = cfg.sensor_height_m[0]
        + (cfg.sensor_height_m[1] - cfg.sensor_height_m[0]) * u.powf(cfg.height_exponent.max(1e-3));
    let cruise = uniform_in(rng, cfg.speed_mps);
    let gait_hz = uniform_in(rng, cfg.gait_frequency_hz);
    let (phase_r, phase_p): (f64, f64) =
        (rng.random_range(0.0..std::f64::consts::TAU), rng.random_range(0.0..std::f64::consts::TAU));
    // Substeps keep the dynamics smooth at 10 Hz output.
    let sub = 4usize;
    let h = dt_s / sub as f64;
    let mut s = 0.0;
    let mut v = cruise * rng.random_range(0.6..1.0);
    let mut v_target = cruise;
    let mut hovering = false;
    let mut height_dev = 0.0;
    let (mut jr, mut jp, mut yaw_w) = (0.0, 0.0, 0.0);
    let mut t = 0.0;
    let mut prev_v = v;
    let mut out = Vec::with_capacity(frames);
    let terrain_tilt = |xy: [f64; 2], heading: f64| -> (f64, f64) {
        if cfg.body_length_m <= 0.0 {
            return (0.0, 0.0);
        }
        let (sh, ch) = heading.sin_cos();
        let (hl, hw) = (0.5 * cfg.body_length_m, 0.5 * cfg.body_width_m);
        let front = support([xy[0] + hl * ch, xy[1] + hl * sh]);
        let back = support([xy[0] - hl * ch, xy[1] - hl * sh]);
        let left = support([xy[0] - hw * sh, xy[1] + hw * ch]);
        let right = support([xy[0] + hw * sh, xy[1] - hw * ch]);
        // Positive pitch is nose down (R = Rz·Ry·Rx), positive roll lifts the left side.
        ((left - right).atan2(cfg.body_width_m), -(front - back).atan2(cfg.body_length_m))
    };
    let (mut tilt_r, mut tilt_p) = {
        let rs = route.sample(0.0);
        terrain_tilt(rs.xy, rs.heading_rad)
    };
    for frame in 0..frames {
        if frame > 0 {
            for _ in 0..sub {
                // Hover/stand episodes: a two-state Markov chain whose stationary share of
                // hovering is `hover_share`, with a cycle of a few seconds.
                if cfg.hover_share > 0.0 {
                    let cycle_s = 4.0;
                    let p_on = (cfg.hover_share / cycle_s * h).clamp(0.0, 1.0);
                    let p_off = ((1.0 - cfg.hover_share) / cycle_s * h).clamp(0.0, 1.0);
                    hovering = if hovering { !rng.random_bool(p_off) } else { rng.random_bool(p_on) };
                }
                v_target = ou_step(v_target, cruise, cfg.speed_variation_mps, cfg.speed_time_constant_s, h, rng)
                    .clamp(cfg.speed_mps[0], cfg.speed_mps[1]);
                // Slow down for the sharpest curve within the next two seconds.
                let kappa = (0..=4)
                    .map(|k| route.sample(s + 0.5 * k as f64 * v.max(1.0)).curvature_per_m.abs())
                    .fold(0.0, f64::max);
                let v_curve = if kappa > 1e-6 { (cfg.max_lateral_accel_mps2 / kappa).sqrt() } else { f64::INFINITY };
                let goal = if hovering { 0.0 } else { v_target.min(v_curve) };
                let dv = (goal - v).clamp(-cfg.max_accel_mps2 * h, cfg.max_accel_mps2 * h);
                v = (v + dv).max(0.0);
                s += v * h;
                t += h;
                jr = ou_step(jr, 0.0, cfg.jitter_std_deg * deg, cfg.jitter_time_constant_s, h, rng);
                jp = ou_step(jp, 0.0, cfg.jitter_std_deg * deg, cfg.jitter_time_constant_s, h, rng);
                yaw_w = ou_step(yaw_w, 0.0, cfg.yaw_wander_deg * deg, 4.0, h, rng);
                height_dev = ou_step(height_dev, 0.0, cfg.height_variation_m, 6.0, h, rng);
                let rs = route.sample(s);
                let (r_t, p_t) = terrain_tilt(rs.xy, rs.heading_rad);
                let a = if cfg.terrain_tilt_time_constant_s > 0.0 {
                    1.0 - (-h / cfg.terrain_tilt_time_constant_s).exp()
                } else {
                    1.0
                };
                tilt_r += a * (r_t - tilt_r);
                tilt_p += a * (p_t - tilt_p);
            }
        }
        let rs = route.sample(s);
        let accel = (v - prev_v) / dt_s;
        prev_v = v;
        let lateral = v * v * rs.curvature_per_m;
        let (accel_p, accel_r) = if cfg.thrust_tilt {
            // A multirotor tilts its thrust into the acceleration: nose down to speed up, and
            // toward the inside of a turn (left side down for a left turn).
            ((accel / g).atan(), -(lateral / g).atan())
        } else {
            // A body on springs or legs squats back when accelerating and leans out in turns.
            (-cfg.pitch_per_accel_deg * deg * accel, cfg.roll_per_lateral_accel_deg * deg * lateral)
        };
        let speed_share = if cfg.speed_mps[1] > 0.0 { (v / cfg.speed_mps[1]).clamp(0.0, 1.0) } else { 0.0 };
        let gait_scale = if v > 0.05 { 0.5 + 0.5 * speed_share } else { 0.25 };
        let w = std::f64::consts::TAU * gait_hz * t;
        let gait_r = gait_scale * cfg.gait_roll_amplitude_deg * deg * (w + phase_r).sin();
        let gait_p = gait_scale * cfg.gait_pitch_amplitude_deg * deg * (2.0 * w + phase_p).sin();
        let limit = cfg.attitude_limit_deg * deg;
        let roll = (tilt_r + accel_r + gait_r + jr).clamp(-limit, limit);
        let pitch = (tilt_p + accel_p + gait_p + jp).clamp(-limit, limit);
        let yaw = rs.heading_rad + yaw_w;
        let bounce = cfg.gait_bounce_m * (2.0 * w).sin() * gait_scale;
        let height = (base_height + height_dev + bounce).max(0.3 * cfg.sensor_height_m[0]);
        let z = support(rs.xy) + height;
        out.push(PlatformState {
            world_from_lidar: Pose::from_xyz_rpy([rs.xy[0], rs.xy[1], z], roll, pitch, yaw),
            speed_mps: v,
            s_m: s,
            height_above_support_m: height,
        });
    }
    out
}

/// Metres a platform is expected to travel in `frames` at `dt_s` (for route and feature planning).
pub fn expected_travel_m(cfg: &PlatformConfig, frames: usize, dt_s: f64) -> f64 {
    0.5 * (cfg.speed_mps[0] + cfg.speed_mps[1]) * (1.0 - cfg.hover_share) * frames as f64 * dt_s
}

/// Metres a platform can at most travel in `frames` (route length).
pub fn max_travel_m(cfg: &PlatformConfig, frames: usize, dt_s: f64) -> f64 {
    cfg.speed_mps[1] * frames as f64 * dt_s
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn grid() -> RoadGrid {
        RoadGrid {
            block_m: 90.0,
            offset: [0.0, 0.0],
            road_half_width_m: 7.0,
            sidewalk_width_m: 4.0,
            reflectivity: [0.1; 4],
        }
    }

    #[test]
    fn routes_follow_the_lane_offset() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        for p in [Platform::Vehicle, Platform::Quadruped, Platform::Drone] {
            let cfg = PlatformConfig::preset(p);
            let route = plan_route(&cfg, &grid(), 400.0, &mut rng);
            assert!(route.length_m() >= 380.0);
            let off = cfg.lane_offset_m(&grid());
            // Mid-segment points are exactly at the lane offset from a street centre line.
            let s = route.sample(10.0);
            assert!((grid().distance_to_street(s.xy) - off).abs() < 1e-6, "{p}: {s:?}");
        }
    }

    #[test]
    fn flat_vehicle_stays_level_and_drone_tilts() {
        let route = Route::straight([0.0, 0.0], [1000.0, 0.0]);
        let flat = |_: [f64; 2]| 0.0;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let std_deg = |states: &[PlatformState]| {
            let p: Vec<f64> =
                states.iter().map(|s| s.world_from_lidar.roll_pitch_yaw().pitch_rad.to_degrees()).collect();
            let m = p.iter().sum::<f64>() / p.len() as f64;
            (p.iter().map(|x| (x - m).powi(2)).sum::<f64>() / p.len() as f64).sqrt()
        };
        let v = simulate(&PlatformConfig::vehicle(), &route, &flat, 300, 0.1, &mut rng);
        assert!(std_deg(&v) < 1.0);
        let z = v[10].world_from_lidar.translation.z;
        assert!((1.8..=2.0).contains(&z));
        let d = simulate(&PlatformConfig::drone(), &route, &flat, 300, 0.1, &mut rng);
        assert!(std_deg(&d) > 4.0);
    }
}
