//! One simulated sequence: a scene, its actors and the platform's trajectory, all drawn from one
//! seed, rendered frame by frame into points and labels in the sensor frame.

use std::path::PathBuf;

use pi3det_data::{Frame, FrameInfo, Object, Platform, PointCloud};
use pi3det_geometry::{Box3d, Pose};
use rand::Rng;
use rayon::prelude::*;

use crate::actors::{self, Actor, PopulateContext};
use crate::config::SimConfig;
use crate::platform::{self, PlatformState};
use crate::raycast::World;
use crate::rng::{derive_seed, derive_seed_n, stream, RayRng};
use crate::roads::RoadGrid;
use crate::route::Route;
use crate::scene::{Layout, RouteContext, Scene};
use crate::sensor::SensorConfig;
use crate::SimError;

/// What to simulate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SequenceSpec {
    pub platform: Platform,
    /// Index within the platform's sequences (names and seeds derive from it).
    pub index: u32,
    pub frames: u32,
    /// The run's seed; the sequence's own seed derives from it, the platform and the index.
    pub seed: u64,
    /// Force a layout instead of drawing one by the platform's weights.
    pub layout: Option<Layout>,
}

/// A rendered frame: sensor-frame points `[x, y, z, intensity]` and labels.
#[derive(Debug, Clone, PartialEq)]
pub struct SimFrame {
    pub index: usize,
    pub timestamp_s: f64,
    pub world_from_lidar: Pose,
    pub points: Vec<[f32; 4]>,
    pub objects: Vec<Object>,
    /// Rays cast for this frame.
    pub rays: usize,
}

impl SimFrame {
    /// As a dataset frame with id `id`.
    pub fn to_frame(&self, id: &str, platform: Platform, sequence: &str) -> Frame {
        let mut info = FrameInfo::new(id, PathBuf::from(format!("training/point_cloud/{id}.bin")));
        info.platform = platform;
        info.sequence = Some(sequence.to_string());
        info.timestamp_s = Some(self.timestamp_s);
        info.world_from_lidar = Some(self.world_from_lidar);
        info.objects = self.objects.clone();
        Frame { info, points: PointCloud::from_xyzi(&self.points) }
    }
}

pub struct Sequence {
    pub spec: SequenceSpec,
    pub name: String,
    pub layout: Layout,
    pub route: Route,
    pub scene: Scene,
    pub actors: Vec<Actor>,
    pub states: Vec<PlatformState>,
    sensor: SensorConfig,
    ray_dirs: Vec<[f64; 3]>,
    /// Rays that hit the platform's own body.
    self_blocked: Vec<bool>,
    min_points: u32,
    label_range_m: f64,
    hide_clearance_m: f64,
    ray_seed: u64,
}

impl Sequence {
    pub fn generate(cfg: &SimConfig, spec: SequenceSpec) -> Result<Self, SimError> {
        cfg.validate()?;
        let pc = cfg.platform(spec.platform)?;
        let seed = derive_seed_n(spec.seed, spec.platform.as_str(), u64::from(spec.index));
        let layout = match spec.layout {
            Some(l) => l,
            None => pc.pick_layout(&mut stream(seed, "layout")),
        };
        let lc = cfg.scene.layout(layout);
        let mut road_rng = stream(seed, "roads");
        let m = &cfg.scene.materials;
        let roads = RoadGrid {
            block_m: lc.block_m,
            offset: [road_rng.random_range(0.0..lc.block_m), road_rng.random_range(0.0..lc.block_m)],
            road_half_width_m: lc.road_half_width_m,
            sidewalk_width_m: lc.sidewalk_width_m,
            reflectivity: [m.asphalt, m.marking, m.sidewalk, m.lawn],
        };
        let dt = 1.0 / cfg.sensor.rate_hz;
        let frames = spec.frames as usize;
        let route =
            platform::plan_route(pc, &roads, platform::max_travel_m(pc, frames, dt) + 10.0, &mut stream(seed, "route"));
        let reach = cfg.sensor.range_max_m + cfg.scene.margin_m;
        // Only the part of the route the platform can reach needs scenery around it.
        let reachable = platform::max_travel_m(pc, frames, dt) + 5.0;
        let mut bounds = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        let mut s = 0.0;
        while s <= reachable {
            let p = route.sample(s).xy;
            bounds = [bounds[0].min(p[0]), bounds[1].min(p[1]), bounds[2].max(p[0]), bounds[3].max(p[1])];
            s += 2.0;
        }
        let bounds = [bounds[0] - reach, bounds[1] - reach, bounds[2] + reach, bounds[3] + reach];
        let ctx = RouteContext {
            route: &route,
            clearance_m: pc.clearance_m,
            travel_m: platform::expected_travel_m(pc, frames, dt),
            steps: pc.steps,
            underpass: pc.underpass,
        };
        let scene = Scene::generate(&cfg.scene, layout, roads, bounds, &ctx, &mut stream(seed, "scene"));
        let support = |xy: [f64; 2]| scene.support_height(xy);
        let states = platform::simulate(pc, &route, &support, frames, dt, &mut stream(seed, "trajectory"));
        let pctx = PopulateContext {
            route: &route,
            clearance_m: pc.clearance_m,
            pedestrian_scale: pc.pedestrian_scale,
            companions: pc.companions,
            companion_offset_m: pc.companion_offset_m,
            companion_ahead_m: pc.companion_ahead_m,
            platform_track_s_m: states.iter().map(|st| st.s_m).collect(),
            rate_hz: cfg.sensor.rate_hz,
        };
        let actors = actors::populate(&cfg.actors, lc, &scene, bounds, &pctx, &mut stream(seed, "actors"));
        let name = format!("{}_{}_{:03}", spec.platform.as_str(), layout.as_str(), spec.index);
        Ok(Self {
            spec,
            name,
            layout,
            route,
            scene,
            actors,
            states,
            sensor: cfg.sensor.clone(),
            self_blocked: self_occlusion(&cfg.sensor.ray_directions(), pc.body_box_m),
            ray_dirs: cfg.sensor.ray_directions(),
            min_points: cfg.labels.min_points,
            label_range_m: cfg.label_range_m(),
            hide_clearance_m: cfg.labels.hide_clearance_m,
            ray_seed: derive_seed(seed, "rays"),
        })
    }

    pub fn len(&self) -> usize {
        self.states.len()
    }

    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }

    /// Labelled objects in the scene (parked and moving actors).
    pub fn actor_count(&self) -> usize {
        self.actors.len()
    }

    pub fn sensor(&self) -> &SensorConfig {
        &self.sensor
    }

    /// Renders frame `index` (rays in parallel; the result does not depend on the thread count).
    pub fn render(&self, index: usize) -> SimFrame {
        let state = &self.states[index];
        let t_s = index as f64 / self.sensor.rate_hz;
        let world_from_lidar = state.world_from_lidar;
        let origin = world_from_lidar.translation.vector;
        let sensor_xy = [origin.x, origin.y];
        let reach = self.sensor.range_max_m + 15.0;

        // Actors present this frame (within reach, not overlapping the platform).
        let mut prims = self.scene.statics.clone();
        let mut present: Vec<(usize, Box3d)> = Vec::new();
        for (k, actor) in self.actors.iter().enumerate() {
            let (xy, heading) = actor.pose_at(t_s);
            if (xy[0] - sensor_xy[0]).hypot(xy[1] - sensor_xy[1]) > reach {
                continue;
            }
            let ground = self.scene.support_height(xy);
            let b = actor.world_box(xy, heading, ground);
            let c = self.hide_clearance_m;
            let grown = Box3d { dx: b.dx + 2.0 * c, dy: b.dy + 2.0 * c, dz: b.dz + 2.0 * c, ..b };
            if grown.contains([origin.x, origin.y, origin.z]) {
                continue;
            }
            actor.push_primitives(xy, heading, ground, &mut prims);
            present.push((k, b));
        }
        let world = World::build(&self.scene.terrain, Some(&self.scene.roads), prims, self.scene.roads.reflectivity[0]);

        // Cast every ray; each writes only its own slot, so the order is fixed.
        let rot = world_from_lidar.rotation.to_rotation_matrix();
        let r = rot.matrix();
        let cols = self.sensor.columns as usize;
        let frame_seed = crate::rng::mix64(self.ray_seed ^ (index as u64).wrapping_mul(0x9E37_79B9));
        let t_max = self.sensor.range_max_m + 5.0 * self.sensor.range_noise_std_m;
        let o = [origin.x, origin.y, origin.z];
        let mut slots = vec![[f32::NAN; 4]; self.ray_dirs.len()];
        slots.par_chunks_mut(cols).enumerate().for_each(|(beam, row)| {
            for (col, slot) in row.iter_mut().enumerate() {
                let k = beam * cols + col;
                if self.self_blocked[k] {
                    continue;
                }
                let d = self.ray_dirs[k];
                let dw = [
                    r[(0, 0)] * d[0] + r[(0, 1)] * d[1] + r[(0, 2)] * d[2],
                    r[(1, 0)] * d[0] + r[(1, 1)] * d[1] + r[(1, 2)] * d[2],
                    r[(2, 0)] * d[0] + r[(2, 1)] * d[1] + r[(2, 2)] * d[2],
                ];
                let ray = crate::shapes::Ray { origin: o, dir: dw };
                let Some(hit) = world.cast(&ray, t_max) else { continue };
                let cos_i = -(hit.normal[0] * dw[0] + hit.normal[1] * dw[1] + hit.normal[2] * dw[2]);
                let mut rng = RayRng::new(frame_seed, k as u64);
                if hit.return_probability < 1.0 && rng.uniform() >= f64::from(hit.return_probability) {
                    continue;
                }
                if let Some((range, intensity)) =
                    self.sensor.measure(hit.t, cos_i, f64::from(hit.reflectivity), &mut rng)
                {
                    *slot = [(d[0] * range) as f32, (d[1] * range) as f32, (d[2] * range) as f32, intensity];
                }
            }
        });
        let points: Vec<[f32; 4]> = slots.into_iter().filter(|p| !p[0].is_nan()).collect();

        // Labels in the sensor frame, counted with the stored (float32) box on the stored points.
        let lidar_from_world = world_from_lidar.inverse();
        let index_grid = PointIndex::new(&points, self.sensor.range_max_m + 1.0, 2.0);
        let mut objects = Vec::new();
        for (k, world_box) in present {
            let b = world_box.transformed(&lidar_from_world).with_wrapped_heading();
            // Stored as float32: count with exactly the box a reader gets back. float32 π lies
            // outside [−π, π), so a heading that rounds to ±π becomes the nearest float32 inside.
            let mut b = Box3d::from_array(b.to_array().map(|v| f64::from(v as f32)));
            if b.heading.abs() >= std::f64::consts::PI {
                let inside = f32::from_bits(std::f32::consts::PI.to_bits() - 1);
                b.heading = f64::from(inside).copysign(b.heading);
            }
            if b.x.hypot(b.y) > self.label_range_m {
                continue;
            }
            let n = index_grid.count_in(&b, &points);
            if n >= self.min_points as usize {
                let mut obj = Object::new(self.actors[k].class.label(), b);
                obj.num_points = Some(n as u32);
                objects.push(obj);
            }
        }
        SimFrame { index, timestamp_s: t_s, world_from_lidar, points, objects, rays: self.ray_dirs.len() }
    }
}

/// Which sensor-frame rays hit the body box `[cx, cy, cz, dx, dy, dz]` (fixed to the sensor, so
/// computed once per sequence).
fn self_occlusion(dirs: &[[f64; 3]], body: [f64; 6]) -> Vec<bool> {
    if body[3] <= 0.0 || body[4] <= 0.0 || body[5] <= 0.0 {
        return vec![false; dirs.len()];
    }
    let b = crate::shapes::UprightBox::new([body[0], body[1], body[2]], [body[3], body[4], body[5]], 0.0);
    dirs.iter().map(|d| b.intersect(&crate::shapes::Ray { origin: [0.0; 3], dir: *d }, 1e3).is_some()).collect()
}

/// Points bucketed on a BEV grid, so counting the points in a box looks only at nearby cells.
/// Counting goes through `Box3d::count_points` on a superset of the box's points, so the result
/// is exactly what `count_points` gives on the whole cloud.
struct PointIndex {
    half_extent_m: f64,
    cell_m: f64,
    n: usize,
    start: Vec<u32>,
    order: Vec<u32>,
}

impl PointIndex {
    fn new(points: &[[f32; 4]], half_extent_m: f64, cell_m: f64) -> Self {
        let n = ((2.0 * half_extent_m / cell_m).ceil() as usize).max(1);
        let cell_of = |p: &[f32; 4]| -> usize {
            let i = (((f64::from(p[0]) + half_extent_m) / cell_m).floor().max(0.0) as usize).min(n - 1);
            let j = (((f64::from(p[1]) + half_extent_m) / cell_m).floor().max(0.0) as usize).min(n - 1);
            j * n + i
        };
        let mut start = vec![0u32; n * n + 1];
        for p in points {
            start[cell_of(p) + 1] += 1;
        }
        for c in 0..n * n {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut order = vec![0u32; points.len()];
        for (k, p) in points.iter().enumerate() {
            let c = cell_of(p);
            order[fill[c] as usize] = k as u32;
            fill[c] += 1;
        }
        Self { half_extent_m, cell_m, n, start, order }
    }

    fn count_in(&self, b: &Box3d, points: &[[f32; 4]]) -> usize {
        let r = b.bev_radius() + 0.01;
        let idx = |v: f64| (((v + self.half_extent_m) / self.cell_m).floor().max(0.0) as usize).min(self.n - 1);
        let (i0, i1, j0, j1) = (idx(b.x - r), idx(b.x + r), idx(b.y - r), idx(b.y + r));
        let mut total = 0;
        for j in j0..=j1 {
            let row = j * self.n;
            let (s, e) = (self.start[row + i0] as usize, self.start[row + i1 + 1] as usize);
            total += b.count_points(self.order[s..e].iter().map(|&k| {
                let p = points[k as usize];
                [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]
            }));
        }
        total
    }
}
