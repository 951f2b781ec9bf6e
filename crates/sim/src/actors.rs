//! Movable things that get labels: vehicles (sedans, SUVs, vans, buses, each several boxes) and
//! pedestrians (legs, torso, arms, head), parked or moving along plausible paths.

use std::sync::Arc;

use pi3det_geometry::Box3d;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::rng::uniform_in;
use crate::route::Route;
use crate::scene::{poisson, LayoutConfig, Scene};
use crate::shapes::{Cylinder, Primitive, Shape, Sphere, UprightBox};

/// The label classes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ActorClass {
    Car,
    Pedestrian,
}

impl ActorClass {
    /// The class string stored in `gt_names`.
    pub fn label(&self) -> &'static str {
        match self {
            ActorClass::Car => "Car",
            ActorClass::Pedestrian => "Pedestrian",
        }
    }
}

/// Size ranges and share (a weight among the types) of one vehicle type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VehicleType {
    pub share: f64,
    pub length_m: [f64; 2],
    pub width_m: [f64; 2],
    pub height_m: [f64; 2],
}

impl Default for VehicleType {
    fn default() -> Self {
        Self { share: 1.0, length_m: [3.4, 4.8], width_m: [1.55, 1.85], height_m: [1.38, 1.52] }
    }
}

/// Actor sizes, looks and speeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ActorConfig {
    pub sedan: VehicleType,
    pub suv: VehicleType,
    pub van: VehicleType,
    pub bus: VehicleType,
    pub paint_reflectivity: [f64; 2],
    pub glass_reflectivity: f64,
    /// Share of beams a car's windows return (the cabin above the belt line of sedans and SUVs):
    /// real windows let most of a LiDAR's beam through or reflect it away, so a real car shows a
    /// hole where its glass is. 1.0 keeps the cabin solid.
    pub glass_return_probability: f64,
    pub tyre_reflectivity: f64,
    pub vehicle_speed_mps: [f64; 2],
    pub pedestrian_height_m: [f64; 2],
    pub pedestrian_speed_mps: [f64; 2],
    pub clothing_reflectivity: [f64; 2],
    pub skin_reflectivity: f64,
    /// Share of parking-lot bays that are taken.
    pub parking_occupancy: f64,
    /// Pedestrians per hectare of open land (lawns, squares).
    pub lawn_pedestrians_per_hectare: f64,
    /// Share of sidewalk and lawn pedestrians that come with company: `pedestrian_group_size`
    /// more people beside them (standing together or walking at the same pace), side by side
    /// `pedestrian_group_spacing_m` apart. Real streets have groups, and a detector that has only
    /// seen people alone may take a group for something else. 0 draws no group (and no random
    /// number: the scenes stay as they were).
    pub pedestrian_group_share: f64,
    pub pedestrian_group_size: [usize; 2],
    pub pedestrian_group_spacing_m: [f64; 2],
    /// Moving actors closer than this to the platform's start are left out (no one starts inside
    /// the platform).
    pub start_clearance_m: f64,
}

impl Default for ActorConfig {
    fn default() -> Self {
        Self {
            // Sedans down to compact hatchbacks: real cars are smaller than the larger sedans
            // alone (KITTI's cars, `../shared/data/kitti_label_stats`: length 3.2–4.5 m and
            // width 1.46–1.81 m from the 5th to the 95th percentile), and a detector that has only
            // seen 4.2 m and longer cars makes every real compact a long box. Shares are weights.
            sedan: VehicleType { share: 0.5, length_m: [3.4, 4.8], width_m: [1.55, 1.85], height_m: [1.38, 1.52] },
            suv: VehicleType { share: 0.3, length_m: [4.5, 5.1], width_m: [1.85, 2.0], height_m: [1.65, 1.85] },
            van: VehicleType { share: 0.15, length_m: [5.0, 6.0], width_m: [1.9, 2.1], height_m: [1.9, 2.5] },
            bus: VehicleType { share: 0.1, length_m: [10.5, 13.0], width_m: [2.5, 2.55], height_m: [3.0, 3.3] },
            paint_reflectivity: [0.05, 0.9],
            glass_reflectivity: 0.08,
            glass_return_probability: 1.0,
            tyre_reflectivity: 0.04,
            vehicle_speed_mps: [4.0, 13.0],
            pedestrian_height_m: [1.5, 1.95],
            pedestrian_speed_mps: [0.9, 1.6],
            clothing_reflectivity: [0.06, 0.6],
            skin_reflectivity: 0.35,
            parking_occupancy: 0.7,
            lawn_pedestrians_per_hectare: 1.5,
            pedestrian_group_share: 0.0,
            pedestrian_group_size: [1, 3],
            pedestrian_group_spacing_m: [0.7, 1.1],
            start_clearance_m: 6.0,
        }
    }
}

impl ActorConfig {
    pub fn validate(&self) -> Result<(), crate::SimError> {
        let [lo, hi] = self.pedestrian_group_size;
        let [s0, s1] = self.pedestrian_group_spacing_m;
        if !(0.0..=1.0).contains(&self.pedestrian_group_share) {
            return Err(crate::SimError::invalid("actors.pedestrian_group_share must be within [0, 1]"));
        }
        if lo > hi || hi > 10 {
            return Err(crate::SimError::invalid(
                "actors.pedestrian_group_size must be [min, max] with min ≤ max ≤ 10",
            ));
        }
        if !(s0.is_finite() && s1.is_finite() && 0.5 <= s0 && s0 <= s1) {
            return Err(crate::SimError::invalid(
                "actors.pedestrian_group_spacing_m must be [min, max] with 0.5 ≤ min ≤ max (people side by side, not inside one another)",
            ));
        }
        Ok(())
    }
}

/// A part of an actor in the actor's frame (u forward, v left, z up from the ground under its
/// centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Part {
    Box {
        center: [f64; 3],
        size: [f64; 3],
        reflectivity: f64,
    },
    /// A box of glass: returns only a share of the beams that hit it.
    Glass {
        center: [f64; 3],
        size: [f64; 3],
        reflectivity: f64,
        return_probability: f64,
    },
    Cylinder {
        uv: [f64; 2],
        radius: f64,
        z: [f64; 2],
        reflectivity: f64,
    },
    Sphere {
        center: [f64; 3],
        radius: f64,
        reflectivity: f64,
    },
}

/// How an actor moves.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    Static {
        xy: [f64; 2],
        heading_rad: f64,
    },
    /// Along a route from arc length `s0_m` at constant speed, `lateral_m` to the left of it.
    Along {
        route: Route,
        s0_m: f64,
        speed_mps: f64,
        lateral_m: f64,
    },
    /// Keeping pace with the platform: `ahead_m` along its route from where the platform is
    /// (`track_s_m`: the platform's arc length at each frame, `rate_hz` apart), `lateral_m` left.
    Escort {
        route: Route,
        track_s_m: Arc<[f64]>,
        rate_hz: f64,
        ahead_m: f64,
        lateral_m: f64,
    },
}

fn offset_left(route: &Route, s: f64, lateral_m: f64) -> ([f64; 2], f64) {
    let p = route.sample(s);
    let (sn, cs) = p.heading_rad.sin_cos();
    ([p.xy[0] - lateral_m * sn, p.xy[1] + lateral_m * cs], p.heading_rad)
}

/// A labelled actor.
#[derive(Debug, Clone, PartialEq)]
pub struct Actor {
    pub class: ActorClass,
    /// Label size: length (along heading), width, height.
    pub size_m: [f64; 3],
    pub parts: Vec<Part>,
    pub motion: Motion,
}

impl Actor {
    /// Position and heading at time `t_s`.
    pub fn pose_at(&self, t_s: f64) -> ([f64; 2], f64) {
        match &self.motion {
            Motion::Static { xy, heading_rad } => (*xy, *heading_rad),
            Motion::Along { route, s0_m, speed_mps, lateral_m } => {
                offset_left(route, s0_m + speed_mps * t_s, *lateral_m)
            }
            Motion::Escort { route, track_s_m, rate_hz, ahead_m, lateral_m } => {
                let x = (t_s * rate_hz).max(0.0);
                let k = (x.floor() as usize).min(track_s_m.len().saturating_sub(1));
                let next = (k + 1).min(track_s_m.len().saturating_sub(1));
                let s = track_s_m.get(k).map_or(0.0, |a| a + (x - k as f64).min(1.0) * (track_s_m[next] - a));
                offset_left(route, s + ahead_m, *lateral_m)
            }
        }
    }

    /// The upright label box in the world frame for an actor standing on `ground_z`.
    pub fn world_box(&self, xy: [f64; 2], heading_rad: f64, ground_z: f64) -> Box3d {
        Box3d::new(
            xy[0],
            xy[1],
            ground_z + 0.5 * self.size_m[2],
            self.size_m[0],
            self.size_m[1],
            self.size_m[2],
            heading_rad,
        )
    }

    /// Appends the actor's shapes, placed at `xy`, `heading_rad` on `ground_z`.
    pub fn push_primitives(&self, xy: [f64; 2], heading_rad: f64, ground_z: f64, out: &mut Vec<Primitive>) {
        let (s, c) = heading_rad.sin_cos();
        let place = |uv: [f64; 2]| [xy[0] + c * uv[0] - s * uv[1], xy[1] + s * uv[0] + c * uv[1]];
        for part in &self.parts {
            let prim = match *part {
                Part::Box { center, size, reflectivity } => {
                    let p = place([center[0], center[1]]);
                    Primitive::new(
                        Shape::Box(UprightBox::new([p[0], p[1], ground_z + center[2]], size, heading_rad)),
                        reflectivity,
                    )
                }
                Part::Glass { center, size, reflectivity, return_probability } => {
                    let p = place([center[0], center[1]]);
                    Primitive::new(
                        Shape::Box(UprightBox::new([p[0], p[1], ground_z + center[2]], size, heading_rad)),
                        reflectivity,
                    )
                    .with_return_probability(return_probability)
                }
                Part::Cylinder { uv, radius, z, reflectivity } => {
                    let cyl = Cylinder { xy: place(uv), radius, z0: ground_z + z[0], z1: ground_z + z[1] };
                    Primitive::new(Shape::Cylinder(cyl), reflectivity)
                }
                Part::Sphere { center, radius, reflectivity } => {
                    let p = place([center[0], center[1]]);
                    Primitive::new(
                        Shape::Sphere(Sphere { center: [p[0], p[1], ground_z + center[2]], radius }),
                        reflectivity,
                    )
                }
            };
            out.push(prim);
        }
    }
}

fn draw_vehicle_type<'a, R: Rng + ?Sized>(
    cfg: &'a ActorConfig,
    rng: &mut R,
    allow_bus: bool,
) -> (usize, &'a VehicleType) {
    let types = [&cfg.sedan, &cfg.suv, &cfg.van, &cfg.bus];
    let n = if allow_bus { 4 } else { 3 };
    let total: f64 = types[..n].iter().map(|t| t.share.max(0.0)).sum();
    let mut x = rng.random_range(0.0..1.0) * total.max(1e-12);
    for (k, t) in types[..n].iter().enumerate() {
        x -= t.share.max(0.0);
        if x <= 0.0 {
            return (k, t);
        }
    }
    (0, types[0])
}

/// A vehicle: body and cabin (sedan, SUV), cargo box and hood (van), or body and roof unit (bus),
/// on four wheels.
pub fn vehicle<R: Rng + ?Sized>(cfg: &ActorConfig, rng: &mut R, allow_bus: bool, motion: Motion) -> Actor {
    let (kind, t) = draw_vehicle_type(cfg, rng, allow_bus);
    let (l, w, h) = (uniform_in(rng, t.length_m), uniform_in(rng, t.width_m), uniform_in(rng, t.height_m));
    let paint = uniform_in(rng, cfg.paint_reflectivity);
    let glass_mix = 0.35 * paint + 0.65 * cfg.glass_reflectivity;
    let clearance = if kind == 3 { 0.35 } else { 0.28 };
    let mut parts = Vec::new();
    let body_box = |u0: f64, u1: f64, z0: f64, z1: f64, width: f64, r: f64| Part::Box {
        center: [0.5 * (u0 + u1), 0.0, 0.5 * (z0 + z1)],
        size: [u1 - u0, width, z1 - z0],
        reflectivity: r,
    };
    match kind {
        0 | 1 => {
            let belt = clearance + (h - clearance) * if kind == 0 { 0.48 } else { 0.52 };
            parts.push(body_box(-0.5 * l, 0.5 * l, clearance, belt, w, paint));
            let cabin_len = l * if kind == 0 { 0.48 } else { 0.62 };
            let centre = -l * if kind == 0 { 0.05 } else { 0.08 };
            let cabin = body_box(centre - 0.5 * cabin_len, centre + 0.5 * cabin_len, belt, h, w - 0.14, glass_mix);
            parts.push(match cabin {
                Part::Box { center, size, reflectivity } if cfg.glass_return_probability < 1.0 => Part::Glass {
                    center,
                    size,
                    reflectivity,
                    return_probability: cfg.glass_return_probability.clamp(0.0, 1.0),
                },
                other => other,
            });
        }
        2 => {
            let hood = 1.0f64.min(0.25 * l);
            parts.push(body_box(-0.5 * l, 0.5 * l - hood, clearance, h, w, paint));
            parts.push(body_box(
                0.5 * l - hood,
                0.5 * l,
                clearance,
                clearance + 0.5 * (h - clearance),
                w - 0.06,
                paint,
            ));
        }
        _ => {
            parts.push(body_box(-0.5 * l, 0.5 * l, clearance, h - 0.25, w, paint));
            parts.push(body_box(-0.15 * l, 0.15 * l, h - 0.25, h, 0.6 * w, 0.5 * paint + 0.2));
        }
    }
    let wheel_r = if kind == 3 { 0.5 } else { 0.33 };
    let axle = 0.5 * l - if kind == 3 { 2.2 } else { 0.85 };
    for (su, sv) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        parts.push(Part::Box {
            center: [su * axle, sv * (0.5 * w - 0.13), wheel_r],
            size: [2.0 * wheel_r, 0.24, 2.0 * wheel_r],
            reflectivity: cfg.tyre_reflectivity,
        });
    }
    Actor { class: ActorClass::Car, size_m: [l, w, h], parts, motion }
}

/// A pedestrian of human proportions: two legs, torso, two arms, head.
pub fn pedestrian<R: Rng + ?Sized>(cfg: &ActorConfig, rng: &mut R, walking: bool, motion: Motion) -> Actor {
    let h = uniform_in(rng, cfg.pedestrian_height_m);
    let shoulder = h * rng.random_range(0.24..0.28);
    let cloth = uniform_in(rng, cfg.clothing_reflectivity);
    let legs = uniform_in(rng, cfg.clothing_reflectivity);
    let hip = 0.47 * h;
    let stride = if walking { rng.random_range(0.12..0.22) } else { 0.0 };
    let head_r = 0.062 * h;
    let mut parts = vec![
        Part::Cylinder { uv: [stride, 0.1], radius: 0.075, z: [0.0, hip], reflectivity: legs },
        Part::Cylinder { uv: [-stride, -0.1], radius: 0.075, z: [0.0, hip], reflectivity: legs },
        Part::Box {
            center: [0.0, 0.0, 0.5 * (hip + 0.82 * h)],
            size: [0.24, shoulder, 0.82 * h - hip + 0.02],
            reflectivity: cloth,
        },
        Part::Sphere { center: [0.0, 0.0, h - head_r], radius: head_r, reflectivity: cfg.skin_reflectivity },
    ];
    for side in [-1.0, 1.0] {
        let swing = if walking { -side * 0.6 * stride } else { 0.0 };
        parts.push(Part::Box {
            center: [swing, side * (0.5 * shoulder + 0.05), 0.5 * (0.45 * h + 0.8 * h)],
            size: [0.09, 0.08, 0.35 * h],
            reflectivity: cloth,
        });
    }
    let length = (0.3 + 2.0 * stride + 0.15).max(0.45);
    Actor { class: ActorClass::Pedestrian, size_m: [length, shoulder + 0.2, h], parts, motion }
}

/// What populating needs to know about the platform.
pub struct PopulateContext<'a> {
    pub route: &'a Route,
    /// Parked things keep this far from the route (plus their half width).
    pub clearance_m: f64,
    /// Multiplies the layout's pedestrian densities.
    pub pedestrian_scale: f64,
    /// Pedestrians keeping pace with the platform along its route: count range, lateral offset
    /// range and distance ahead (negative: behind) range.
    pub companions: [u32; 2],
    pub companion_offset_m: [f64; 2],
    pub companion_ahead_m: [f64; 2],
    /// The platform's arc length along `route` at each frame, and the frame rate.
    pub platform_track_s_m: Arc<[f64]>,
    pub rate_hz: f64,
}

/// Places parked and moving actors over `bounds`.
pub fn populate<R: Rng + ?Sized>(
    cfg: &ActorConfig,
    lc: &LayoutConfig,
    scene: &Scene,
    bounds: [f64; 4],
    ctx: &PopulateContext,
    rng: &mut R,
) -> Vec<Actor> {
    let roads = &scene.roads;
    let start = ctx.route.sample(0.0).xy;
    let mut actors = Vec::new();
    let clear = |xy: [f64; 2], half_w: f64| ctx.route.distance_to(xy) > ctx.clearance_m + half_w;
    let away_from_start = |xy: [f64; 2]| (xy[0] - start[0]).hypot(xy[1] - start[1]) > cfg.start_clearance_m;
    let (xs, ys) = roads.streets_in(bounds);
    // Streets as (point on line, unit direction, length); lines run across the whole bounds.
    let mut streets: Vec<([f64; 2], [f64; 2], f64)> = Vec::new();
    for x in xs {
        streets.push(([x, bounds[1]], [0.0, 1.0], bounds[3] - bounds[1]));
    }
    for y in ys {
        streets.push(([bounds[0], y], [1.0, 0.0], bounds[2] - bounds[0]));
    }
    let at = |a: [f64; 2], d: [f64; 2], s: f64, off: f64| [a[0] + d[0] * s - d[1] * off, a[1] + d[1] * s + d[0] * off];
    let in_junction = |xy: [f64; 2], d: [f64; 2], margin: f64| {
        let cross =
            if d[0] != 0.0 { roads.distance_to_street_along_y(xy[0]) } else { roads.distance_to_street_along_x(xy[1]) };
        cross < roads.road_half_width_m + margin
    };
    let heading_of = |d: [f64; 2]| d[1].atan2(d[0]);
    for &(a, d, len) in &streets {
        // Curb parking on both sides; right-hand traffic, so cars on the left side of `d` face −d.
        if lc.parked_gap_m[1] > 0.0 {
            for side in [-1.0, 1.0] {
                let mut s = rng.random_range(0.0..lc.parked_gap_m[1].max(1.0));
                while s < len {
                    let facing = if side > 0.0 { std::f64::consts::PI } else { 0.0 };
                    let flip = if rng.random_bool(0.1) { std::f64::consts::PI } else { 0.0 };
                    let xy0 = at(a, d, s, side * (roads.road_half_width_m - 1.15));
                    let mut car = vehicle(cfg, rng, false, Motion::Static { xy: xy0, heading_rad: 0.0 });
                    let xy =
                        at(a, d, s + 0.5 * car.size_m[0], side * (roads.road_half_width_m - 0.2 - 0.5 * car.size_m[1]));
                    car.motion = Motion::Static { xy, heading_rad: heading_of(d) + facing + flip };
                    // Parallel to the route where the route runs along this street: its half
                    // width is what keeps it off the route.
                    if !in_junction(xy, d, 6.0) && clear(xy, 0.5 * car.size_m[1]) {
                        s += car.size_m[0];
                        actors.push(car);
                    } else {
                        s += 5.0;
                    }
                    s += uniform_in(rng, lc.parked_gap_m);
                }
            }
        }
        // Traffic: one lane each way; lines extended beyond the bounds so cars keep driving.
        let n_lane = poisson(rng, lc.traffic_per_km * len / 1000.0);
        let lane = 0.3 * roads.road_half_width_m;
        for dir in [1.0, -1.0] {
            let dd = [d[0] * dir, d[1] * dir];
            let p0 = if dir > 0.0 { at(a, d, -300.0, 0.0) } else { at(a, d, len + 300.0, 0.0) };
            let route = Route::straight(p0, [p0[0] + dd[0] * (len + 600.0), p0[1] + dd[1] * (len + 600.0)]);
            for _ in 0..n_lane {
                let s0 = 300.0 + rng.random_range(0.0..len);
                let speed = uniform_in(rng, cfg.vehicle_speed_mps);
                let motion = Motion::Along { route: route.clone(), s0_m: s0, speed_mps: speed, lateral_m: -lane };
                let car = vehicle(cfg, rng, true, motion);
                if away_from_start(car.pose_at(0.0).0) {
                    actors.push(car);
                }
            }
        }
        // Pedestrians on the sidewalks (or along the path edges where there are none).
        let n_ped = poisson(rng, lc.pedestrians_per_km * ctx.pedestrian_scale * len / 1000.0);
        for _ in 0..n_ped {
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let off = if roads.sidewalk_width_m > 0.0 {
                roads.road_half_width_m + rng.random_range(0.6..(roads.sidewalk_width_m - 0.3).max(0.7))
            } else {
                (roads.road_half_width_m - rng.random_range(0.4..1.2)).max(0.3)
            };
            let s = rng.random_range(0.0..len);
            let xy = at(a, d, s, side * off);
            let p = walker(cfg, lc, rng, xy, heading_of(d), side * off, a, d, s);
            if away_from_start(p.pose_at(0.0).0) {
                actors.extend(company(cfg, rng, &p));
                actors.push(p);
            }
        }
    }
    // Open land: parking lots and lawns.
    for lot in &scene.open_lots {
        let b = lot.bounds;
        if lot.parking {
            let mut y = b[1] + 3.0;
            while y + 3.0 < b[3] {
                let mut x = b[0] + 1.5;
                while x + 1.5 < b[2] {
                    if rng.random_bool(cfg.parking_occupancy.clamp(0.0, 1.0)) {
                        let heading = if rng.random_bool(0.5) {
                            std::f64::consts::FRAC_PI_2
                        } else {
                            -std::f64::consts::FRAC_PI_2
                        };
                        let car = vehicle(cfg, rng, false, Motion::Static { xy: [x, y], heading_rad: heading });
                        if clear([x, y], 0.5 * car.size_m[0]) {
                            actors.push(car);
                        }
                    }
                    x += 2.7;
                }
                y += 7.5;
            }
        } else {
            let area_ha = (b[2] - b[0]) * (b[3] - b[1]) / 10_000.0;
            for _ in 0..poisson(rng, cfg.lawn_pedestrians_per_hectare * ctx.pedestrian_scale * area_ha) {
                let xy = [rng.random_range(b[0]..b[2]), rng.random_range(b[1]..b[3])];
                let heading = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
                let standing = rng.random_bool(lc.standing_share.clamp(0.0, 1.0));
                let motion = if standing {
                    Motion::Static { xy, heading_rad: heading }
                } else {
                    let (s, c) = heading.sin_cos();
                    Motion::Along {
                        route: Route::straight(xy, [xy[0] + 100.0 * c, xy[1] + 100.0 * s]),
                        s0_m: 0.0,
                        speed_mps: uniform_in(rng, cfg.pedestrian_speed_mps),
                        lateral_m: 0.0,
                    }
                };
                if clear(xy, 0.3) {
                    let p = pedestrian(cfg, rng, !standing, motion);
                    actors.extend(company(cfg, rng, &p).into_iter().filter(|c| clear(c.pose_at(0.0).0, 0.3)));
                    actors.push(p);
                }
            }
        }
    }
    // Companions: people walking with the platform, beside it.
    let (c0, c1) = (ctx.companions[0].min(ctx.companions[1]), ctx.companions[0].max(ctx.companions[1]));
    let n_comp = if c1 > 0 { rng.random_range(c0..=c1) } else { 0 };
    for _ in 0..n_comp {
        let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let motion = Motion::Escort {
            route: ctx.route.clone(),
            track_s_m: ctx.platform_track_s_m.clone(),
            rate_hz: ctx.rate_hz,
            ahead_m: uniform_in(rng, ctx.companion_ahead_m),
            lateral_m: side * uniform_in(rng, ctx.companion_offset_m),
        };
        actors.push(pedestrian(cfg, rng, true, motion));
    }
    actors
}

/// The people with pedestrian `p` ([`ActorConfig::pedestrian_group_share`]): side by side with
/// it, alternately to its left and right, each a little ahead or behind, standing where it
/// stands or walking at its pace.
fn company<R: Rng + ?Sized>(cfg: &ActorConfig, rng: &mut R, p: &Actor) -> Vec<Actor> {
    if cfg.pedestrian_group_share <= 0.0 || !rng.random_bool(cfg.pedestrian_group_share.min(1.0)) {
        return Vec::new();
    }
    let [lo, hi] = cfg.pedestrian_group_size;
    let n = if hi > lo { rng.random_range(lo..=hi) } else { lo };
    let walking = !matches!(p.motion, Motion::Static { .. });
    let mut out = Vec::with_capacity(n);
    for k in 1..=n {
        let side = if k % 2 == 1 { 1.0 } else { -1.0 };
        let left = side * k.div_ceil(2) as f64 * uniform_in(rng, cfg.pedestrian_group_spacing_m);
        let ahead = rng.random_range(-0.3..0.3);
        let motion = match &p.motion {
            Motion::Static { xy, heading_rad } => {
                let (sn, cs) = heading_rad.sin_cos();
                let xy = [xy[0] + ahead * cs - left * sn, xy[1] + ahead * sn + left * cs];
                Motion::Static { xy, heading_rad: heading_rad + rng.random_range(-0.8..0.8) }
            }
            Motion::Along { route, s0_m, speed_mps, lateral_m } => Motion::Along {
                route: route.clone(),
                s0_m: s0_m + ahead,
                speed_mps: *speed_mps,
                lateral_m: lateral_m + left,
            },
            // Companions of the platform walk alone.
            Motion::Escort { .. } => return out,
        };
        out.push(pedestrian(cfg, rng, walking, motion));
    }
    out
}

/// A pedestrian on a sidewalk line: standing, or walking along it either way.
#[allow(clippy::too_many_arguments)]
fn walker<R: Rng + ?Sized>(
    cfg: &ActorConfig,
    lc: &LayoutConfig,
    rng: &mut R,
    xy: [f64; 2],
    street_heading: f64,
    offset: f64,
    a: [f64; 2],
    d: [f64; 2],
    s: f64,
) -> Actor {
    if rng.random_bool(lc.standing_share.clamp(0.0, 1.0)) {
        let heading = street_heading + rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        return pedestrian(cfg, rng, false, Motion::Static { xy, heading_rad: heading });
    }
    let dir = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    // A line through the walker's start along the street; walking 20 s never reaches its end.
    let p0 = [a[0] - d[1] * offset, a[1] + d[0] * offset];
    let (from, to) = if dir > 0.0 {
        ([p0[0] - d[0] * 500.0, p0[1] - d[1] * 500.0], [p0[0] + d[0] * 5000.0, p0[1] + d[1] * 5000.0])
    } else {
        ([p0[0] + d[0] * 5000.0, p0[1] + d[1] * 5000.0], [p0[0] - d[0] * 500.0, p0[1] - d[1] * 500.0])
    };
    let route = Route::straight(from, to);
    let s0 = if dir > 0.0 { 500.0 + s } else { 5000.0 - s };
    let speed_mps = uniform_in(rng, cfg.pedestrian_speed_mps);
    pedestrian(cfg, rng, true, Motion::Along { route, s0_m: s0, speed_mps, lateral_m: 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn parts_stay_inside_the_label_box() {
        let cfg = ActorConfig::default();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for k in 0..200 {
            let motion = Motion::Static { xy: [3.0, -2.0], heading_rad: 0.3 * k as f64 };
            let a = if k % 2 == 0 {
                vehicle(&cfg, &mut rng, true, motion)
            } else {
                pedestrian(&cfg, &mut rng, k % 4 == 1, motion)
            };
            if a.class == ActorClass::Car {
                assert!(a.parts.len() >= 2);
            } else {
                assert!((1.5..=1.95).contains(&a.size_m[2]));
            }
            let (xy, h) = a.pose_at(0.0);
            let b = a.world_box(xy, h, 10.0);
            let mut prims = Vec::new();
            a.push_primitives(xy, h, 10.0, &mut prims);
            let grown = Box3d { dx: b.dx + 1e-6, dy: b.dy + 1e-6, dz: b.dz + 1e-6, ..b };
            for p in prims {
                let corners: Vec<[f64; 3]> = match p.shape {
                    Shape::Box(ub) => Box3d::new(
                        ub.center[0],
                        ub.center[1],
                        ub.center[2],
                        2.0 * ub.half[0],
                        2.0 * ub.half[1],
                        2.0 * ub.half[2],
                        ub.heading_rad(),
                    )
                    .corners()
                    .iter()
                    .map(|c| [c.x, c.y, c.z])
                    .collect(),
                    Shape::Cylinder(c) => [[c.radius, 0.0], [-c.radius, 0.0], [0.0, c.radius], [0.0, -c.radius]]
                        .iter()
                        .flat_map(|o| [[c.xy[0] + o[0], c.xy[1] + o[1], c.z0], [c.xy[0] + o[0], c.xy[1] + o[1], c.z1]])
                        .collect(),
                    Shape::Sphere(s) => vec![
                        [s.center[0], s.center[1], s.center[2] + s.radius],
                        [s.center[0], s.center[1], s.center[2] - s.radius],
                    ],
                };
                for c in corners {
                    assert!(grown.contains(c), "actor {k} {:?}: {c:?} outside {b:?}", a.class);
                }
            }
        }
    }

    #[test]
    fn groups_stand_and_walk_side_by_side_and_none_is_drawn_by_default() {
        let leader = |walking: bool, rng: &mut rand_chacha::ChaCha8Rng| {
            let motion = if walking {
                Motion::Along {
                    route: Route::straight([0.0, 0.0], [100.0, 0.0]),
                    s0_m: 10.0,
                    speed_mps: 1.2,
                    lateral_m: 0.0,
                }
            } else {
                Motion::Static { xy: [10.0, 0.0], heading_rad: 0.0 }
            };
            pedestrian(&ActorConfig::default(), rng, walking, motion)
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let p = leader(true, &mut rng);
        // Off by default, without touching the random stream.
        let mut a = rng.clone();
        assert!(company(&ActorConfig::default(), &mut a, &p).is_empty());
        assert_eq!(a.random::<u64>(), rng.clone().random::<u64>());
        let cfg = ActorConfig { pedestrian_group_share: 1.0, pedestrian_group_size: [3, 3], ..Default::default() };
        for walking in [true, false] {
            let p = leader(walking, &mut rng);
            let group = company(&cfg, &mut rng, &p);
            assert_eq!(group.len(), 3);
            let mut boxes = vec![p.world_box(p.pose_at(0.0).0, p.pose_at(0.0).1, 0.0)];
            for c in &group {
                assert_eq!(c.class, ActorClass::Pedestrian);
                let (xy, h) = c.pose_at(0.0);
                let d = (xy[0] - 10.0).hypot(xy[1]);
                assert!((0.6..=2.5).contains(&d), "{d} m from the leader");
                boxes.push(c.world_box(xy, h, 0.0));
                if walking {
                    // Still beside the leader ten seconds later.
                    let (a, b) = (p.pose_at(10.0).0, c.pose_at(10.0).0);
                    assert!((a[0] - b[0]).abs() < 0.31 && (a[1] - b[1]).abs() > 0.6);
                }
            }
            // Side by side, not inside one another.
            for i in 0..boxes.len() {
                for j in i + 1..boxes.len() {
                    let (a, b) = (boxes[i], boxes[j]);
                    assert!((a.x - b.x).hypot(a.y - b.y) > 0.6, "{a:?} {b:?}");
                }
            }
        }
    }

    #[test]
    fn buses_are_over_ten_metres() {
        let cfg = ActorConfig {
            sedan: VehicleType { share: 0.0, ..Default::default() },
            suv: VehicleType { share: 0.0, ..Default::default() },
            van: VehicleType { share: 0.0, ..Default::default() },
            ..Default::default()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let bus = vehicle(&cfg, &mut rng, true, Motion::Static { xy: [0.0; 2], heading_rad: 0.0 });
        assert!(bus.size_m[0] > 10.0);
    }
}
