//! Procedural static scenes: urban, suburban and park layouts on rolling ground, with buildings,
//! garden walls, poles, trees (trunk and crown), and for quadruped routes stairs and an underpass
//! (bridge deck overhead) placed on the route itself.

use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::rng::uniform_in;
use crate::roads::RoadGrid;
use crate::route::Route;
use crate::shapes::{Cylinder, Primitive, Shape, Sphere, UprightBox};
use crate::terrain::Terrain;
use crate::SimError;

/// The kind of place a sequence is recorded in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Layout {
    Urban,
    Suburban,
    Park,
}

impl Layout {
    pub const ALL: [Layout; 3] = [Layout::Urban, Layout::Suburban, Layout::Park];

    pub fn as_str(&self) -> &'static str {
        match self {
            Layout::Urban => "urban",
            Layout::Suburban => "suburban",
            Layout::Park => "park",
        }
    }
}

/// Everything that makes one layout look like itself. Ranges are `[min, max]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayoutConfig {
    pub block_m: f64,
    pub road_half_width_m: f64,
    pub sidewalk_width_m: f64,
    pub max_slope_deg: f64,
    pub incline_deg: f64,
    pub lot_size_m: [f64; 2],
    pub building_probability: f64,
    pub building_height_m: [f64; 2],
    pub setback_m: [f64; 2],
    pub wall_probability: f64,
    pub parking_lot_probability: f64,
    /// Street trees: spacing along each sidewalk (0: none).
    pub street_tree_spacing_m: f64,
    /// Trees on open land (lots without a building, park lawns).
    pub trees_per_hectare: f64,
    pub pole_spacing_m: f64,
    /// Bushes on open land and in front gardens.
    pub bushes_per_hectare: f64,
    /// Street furniture (bins, benches, bollards, planters) along each sidewalk (0: none).
    pub furniture_spacing_m: f64,
    /// Gap between cars parked along the curb; `[0, 0]` for no curb parking.
    pub parked_gap_m: [f64; 2],
    /// Moving vehicles per km of lane.
    pub traffic_per_km: f64,
    /// Pedestrians per km of sidewalk (or path edge).
    pub pedestrians_per_km: f64,
    /// Share of pedestrians standing still.
    pub standing_share: f64,
}

impl LayoutConfig {
    pub fn urban() -> Self {
        Self {
            block_m: 90.0,
            road_half_width_m: 7.0,
            sidewalk_width_m: 4.0,
            max_slope_deg: 2.0,
            incline_deg: 1.0,
            lot_size_m: [20.0, 34.0],
            building_probability: 0.85,
            building_height_m: [9.0, 40.0],
            setback_m: [0.5, 2.0],
            wall_probability: 0.05,
            parking_lot_probability: 0.1,
            street_tree_spacing_m: 22.0,
            trees_per_hectare: 8.0,
            pole_spacing_m: 30.0,
            bushes_per_hectare: 6.0,
            furniture_spacing_m: 14.0,
            parked_gap_m: [2.0, 30.0],
            traffic_per_km: 10.0,
            pedestrians_per_km: 25.0,
            standing_share: 0.3,
        }
    }

    pub fn suburban() -> Self {
        Self {
            block_m: 110.0,
            road_half_width_m: 6.0,
            sidewalk_width_m: 3.0,
            max_slope_deg: 3.0,
            incline_deg: 1.5,
            lot_size_m: [16.0, 26.0],
            building_probability: 0.55,
            building_height_m: [4.5, 9.0],
            setback_m: [3.0, 7.0],
            wall_probability: 0.35,
            parking_lot_probability: 0.15,
            street_tree_spacing_m: 14.0,
            trees_per_hectare: 20.0,
            pole_spacing_m: 38.0,
            bushes_per_hectare: 40.0,
            furniture_spacing_m: 30.0,
            parked_gap_m: [4.0, 45.0],
            traffic_per_km: 5.0,
            pedestrians_per_km: 8.0,
            standing_share: 0.3,
        }
    }

    pub fn park() -> Self {
        Self {
            block_m: 130.0,
            road_half_width_m: 3.5,
            sidewalk_width_m: 0.0,
            max_slope_deg: 5.0,
            incline_deg: 2.0,
            lot_size_m: [25.0, 45.0],
            building_probability: 0.06,
            building_height_m: [3.0, 6.0],
            setback_m: [4.0, 10.0],
            wall_probability: 0.05,
            parking_lot_probability: 0.2,
            street_tree_spacing_m: 12.0,
            trees_per_hectare: 35.0,
            pole_spacing_m: 45.0,
            bushes_per_hectare: 70.0,
            furniture_spacing_m: 18.0,
            parked_gap_m: [0.0, 0.0],
            traffic_per_km: 0.0,
            pedestrians_per_km: 20.0,
            standing_share: 0.4,
        }
    }
}

/// Surface reflectivities in `[0, 1]` (at the sensor's 865 nm: vegetation is bright, asphalt dark).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialConfig {
    pub asphalt: f64,
    pub marking: f64,
    pub sidewalk: f64,
    pub lawn: f64,
    pub building: [f64; 2],
    /// Share of pulses a facade returns (the rest hit glass and reflect away), per building.
    pub building_return_probability: [f64; 2],
    pub wall: f64,
    pub pole: f64,
    pub furniture: [f64; 2],
    pub trunk: f64,
    pub crown: f64,
    pub concrete: f64,
}

impl Default for MaterialConfig {
    fn default() -> Self {
        Self {
            asphalt: 0.09,
            marking: 0.6,
            sidewalk: 0.28,
            lawn: 0.45,
            building: [0.15, 0.55],
            building_return_probability: [0.5, 0.9],
            wall: 0.3,
            pole: 0.5,
            furniture: [0.1, 0.6],
            trunk: 0.3,
            crown: 0.5,
            concrete: 0.32,
        }
    }
}

/// A flight of steps up to a landing and down again, across a quadruped route.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StepsConfig {
    pub probability: f64,
    pub count: [u32; 2],
    pub rise_m: [f64; 2],
    pub run_m: [f64; 2],
    pub landing_m: [f64; 2],
    pub width_m: f64,
}

impl Default for StepsConfig {
    fn default() -> Self {
        Self {
            probability: 0.4,
            count: [4, 9],
            rise_m: [0.13, 0.17],
            run_m: [0.3, 0.36],
            landing_m: [3.0, 6.0],
            width_m: 3.5,
        }
    }
}

/// A bridge deck over a quadruped route, on two piers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct UnderpassConfig {
    pub probability: f64,
    pub clearance_m: [f64; 2],
    pub deck_thickness_m: f64,
    /// Along the route.
    pub deck_width_m: [f64; 2],
    /// Across the route.
    pub deck_length_m: f64,
    pub pier_size_m: [f64; 2],
}

impl Default for UnderpassConfig {
    fn default() -> Self {
        Self {
            probability: 0.6,
            clearance_m: [4.0, 6.0],
            deck_thickness_m: 1.2,
            deck_width_m: [8.0, 14.0],
            deck_length_m: 36.0,
            pier_size_m: [1.5, 6.0],
        }
    }
}

/// Scene generation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Grid cell of the terrain and of the ray-casting grid.
    pub cell_m: f64,
    /// Scenery extends this far beyond the sensor's range around the route.
    pub margin_m: f64,
    pub urban: LayoutConfig,
    pub suburban: LayoutConfig,
    pub park: LayoutConfig,
    pub materials: MaterialConfig,
    pub steps: StepsConfig,
    pub underpass: UnderpassConfig,
    pub tree_trunk_height_m: [f64; 2],
    pub tree_crown_radius_m: [f64; 2],
    pub pole_height_m: [f64; 2],
    pub wall_height_m: [f64; 2],
    pub bush_radius_m: [f64; 2],
    /// Street furniture: footprint edge and height ranges.
    pub furniture_size_m: [f64; 2],
    pub furniture_height_m: [f64; 2],
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            cell_m: 4.0,
            margin_m: 10.0,
            urban: LayoutConfig::urban(),
            suburban: LayoutConfig::suburban(),
            park: LayoutConfig::park(),
            materials: MaterialConfig::default(),
            steps: StepsConfig::default(),
            underpass: UnderpassConfig::default(),
            tree_trunk_height_m: [1.8, 3.5],
            tree_crown_radius_m: [1.4, 3.2],
            pole_height_m: [5.5, 9.0],
            wall_height_m: [0.9, 2.0],
            bush_radius_m: [0.4, 1.1],
            furniture_size_m: [0.4, 1.8],
            furniture_height_m: [0.5, 1.1],
        }
    }
}

impl SceneConfig {
    pub fn layout(&self, layout: Layout) -> &LayoutConfig {
        match layout {
            Layout::Urban => &self.urban,
            Layout::Suburban => &self.suburban,
            Layout::Park => &self.park,
        }
    }

    pub fn validate(&self) -> Result<(), SimError> {
        if self.cell_m.is_nan() || self.cell_m < 0.5 {
            return Err(SimError::invalid("scene.cell_m must be at least 0.5"));
        }
        for l in Layout::ALL {
            let c = self.layout(l);
            let edge = c.road_half_width_m + c.sidewalk_width_m;
            if c.block_m.is_nan() || c.block_m <= 2.0 * edge + 4.0 {
                return Err(SimError::invalid(format!(
                    "scene.{}: block_m must exceed the street and sidewalk widths",
                    l.as_str()
                )));
            }
            if c.lot_size_m[0].is_nan() || c.lot_size_m[0] <= 1.0 {
                return Err(SimError::invalid(format!("scene.{}: lot_size_m must exceed 1 m", l.as_str())));
            }
        }
        Ok(())
    }
}

/// Kinds of static objects, for counting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StaticKind {
    Building,
    Wall,
    Pole,
    Tree,
    Bush,
    Furniture,
    Steps,
    Underpass,
}

/// What a quadruped route gets in its way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RouteFeatures {
    /// Arc length along the route where a flight of steps starts, if any.
    pub steps_at_m: Option<f64>,
    /// Arc length of the underpass centre, if any.
    pub underpass_at_m: Option<f64>,
}

/// Where open land (a lot with no building, a park lawn, a parking lot) lies, for placing actors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpenLot {
    pub bounds: [f64; 4],
    pub parking: bool,
}

/// A static scene: ground, road network and scenery.
pub struct Scene {
    pub layout: Layout,
    pub roads: RoadGrid,
    pub terrain: Terrain,
    pub statics: Vec<Primitive>,
    /// Surfaces one can stand on above the terrain (step treads), for support heights.
    pub walkables: Vec<UprightBox>,
    pub objects: Vec<StaticKind>,
    pub open_lots: Vec<OpenLot>,
    pub features: RouteFeatures,
}

/// What scene generation needs to know about the platform's route.
pub struct RouteContext<'a> {
    pub route: &'a Route,
    /// Keep scenery this far (plus its own radius) from the route.
    pub clearance_m: f64,
    /// Expected distance travelled in the sequence (for placing route features within reach).
    pub travel_m: f64,
    pub steps: bool,
    pub underpass: bool,
}

impl Scene {
    /// Builds a scene over `bounds` around the route.
    pub fn generate<R: Rng + ?Sized>(
        cfg: &SceneConfig,
        layout: Layout,
        roads: RoadGrid,
        bounds: [f64; 4],
        ctx: &RouteContext,
        rng: &mut R,
    ) -> Self {
        let lc = cfg.layout(layout);
        let m = &cfg.materials;
        let start = ctx.route.sample(0.0).xy;
        let terrain = Terrain::rolling(bounds, cfg.cell_m, lc.max_slope_deg, lc.incline_deg, start, rng);
        let mut scene = Scene {
            layout,
            roads,
            terrain,
            statics: Vec::new(),
            walkables: Vec::new(),
            objects: Vec::new(),
            open_lots: Vec::new(),
            features: RouteFeatures { steps_at_m: None, underpass_at_m: None },
        };
        let clear = |xy: [f64; 2], radius: f64| ctx.route.distance_to(xy) > radius + ctx.clearance_m;

        // Route features first, so scenery keeps out of their way.
        if ctx.steps && rng.random_bool(cfg.steps.probability.clamp(0.0, 1.0)) {
            let s = rng.random_range(0.2..0.7) * ctx.travel_m.max(1.0);
            scene.add_steps(&cfg.steps, m.concrete, ctx.route, s, rng);
        }
        if ctx.underpass && rng.random_bool(cfg.underpass.probability.clamp(0.0, 1.0)) {
            let s = rng.random_range(0.5..0.9) * ctx.travel_m.max(1.0) + 4.0;
            scene.add_underpass(&cfg.underpass, m.concrete, ctx.route, s, rng);
        }

        // Blocks: buildings on lots, or open land with trees; sometimes a parking lot.
        let blocks = scene.roads.blocks_in(bounds);
        for block in blocks {
            if rng.random_bool(lc.parking_lot_probability.clamp(0.0, 1.0)) {
                scene.open_lots.push(OpenLot { bounds: block, parking: true });
                continue;
            }
            for lot in split_block(block, lc.lot_size_m, rng) {
                if rng.random_bool(lc.building_probability.clamp(0.0, 1.0)) {
                    let sb = [uniform_in(rng, lc.setback_m), uniform_in(rng, lc.setback_m)];
                    let fp = [lot[0] + sb[0], lot[1] + sb[1], lot[2] - sb[0], lot[3] - sb[1]];
                    if fp[2] - fp[0] < 3.0 || fp[3] - fp[1] < 3.0 {
                        continue;
                    }
                    let centre = [0.5 * (fp[0] + fp[2]), 0.5 * (fp[1] + fp[3])];
                    let radius = 0.5 * (fp[2] - fp[0]).hypot(fp[3] - fp[1]);
                    if !clear(centre, radius) {
                        continue;
                    }
                    let bottom = scene.terrain.min_height_over(fp) - 0.5;
                    let top = scene.terrain.height(centre) + uniform_in(rng, lc.building_height_m);
                    let b = UprightBox::from_bottom_top(centre, [fp[2] - fp[0], fp[3] - fp[1]], bottom, top, 0.0);
                    let glass = uniform_in(rng, m.building_return_probability);
                    scene.statics.push(
                        Primitive::new(Shape::Box(b), uniform_in(rng, m.building)).with_return_probability(glass),
                    );
                    scene.objects.push(StaticKind::Building);
                    if rng.random_bool(lc.wall_probability.clamp(0.0, 1.0)) {
                        scene.add_wall(cfg, lot, rng, &clear);
                    }
                    // Front gardens: bushes in the setback strips around the building.
                    let garden_ha =
                        ((lot[2] - lot[0]) * (lot[3] - lot[1]) - (fp[2] - fp[0]) * (fp[3] - fp[1])) / 10_000.0;
                    for _ in 0..poisson(rng, lc.bushes_per_hectare * garden_ha) {
                        let xy = [rng.random_range(lot[0]..lot[2]), rng.random_range(lot[1]..lot[3])];
                        if !(xy[0] > fp[0] - 1.0 && xy[0] < fp[2] + 1.0 && xy[1] > fp[1] - 1.0 && xy[1] < fp[3] + 1.0) {
                            scene.add_bush(cfg, xy, rng, &clear);
                        }
                    }
                } else {
                    scene.open_lots.push(OpenLot { bounds: lot, parking: false });
                    let area_ha = (lot[2] - lot[0]) * (lot[3] - lot[1]) / 10_000.0;
                    let n = poisson(rng, lc.trees_per_hectare * area_ha);
                    for _ in 0..n {
                        let xy = [rng.random_range(lot[0]..lot[2]), rng.random_range(lot[1]..lot[3])];
                        scene.add_tree(cfg, xy, rng, &clear);
                    }
                    for _ in 0..poisson(rng, lc.bushes_per_hectare * area_ha) {
                        let xy = [rng.random_range(lot[0]..lot[2]), rng.random_range(lot[1]..lot[3])];
                        scene.add_bush(cfg, xy, rng, &clear);
                    }
                }
            }
        }

        // Along every street: poles and street trees near the curb, on both sides.
        let (xs, ys) = scene.roads.streets_in(bounds);
        let curb = scene.roads.road_half_width_m + 0.6;
        let mut lines: Vec<([f64; 2], [f64; 2])> = Vec::new();
        for x in xs {
            lines.push(([x, bounds[1]], [x, bounds[3]]));
        }
        for y in ys {
            lines.push(([bounds[0], y], [bounds[2], y]));
        }
        for (a, b) in lines {
            let along_x = (b[0] - a[0]).abs() > (b[1] - a[1]).abs();
            let len = (b[0] - a[0]).abs().max((b[1] - a[1]).abs());
            for side in [-1.0, 1.0] {
                for (spacing, kind) in [
                    (lc.pole_spacing_m, StaticKind::Pole),
                    (lc.street_tree_spacing_m, StaticKind::Tree),
                    (lc.furniture_spacing_m, StaticKind::Furniture),
                ] {
                    if spacing <= 0.0 {
                        continue;
                    }
                    let mut s = rng.random_range(0.0..spacing);
                    while s < len {
                        let off = side
                            * match kind {
                                StaticKind::Tree => curb + 0.6,
                                // Against the far edge of the sidewalk (or beside the path).
                                StaticKind::Furniture => {
                                    scene.roads.road_half_width_m + scene.roads.sidewalk_width_m + 0.6
                                }
                                _ => curb,
                            };
                        let xy = if along_x { [a[0] + s, a[1] + off] } else { [a[0] + off, a[1] + s] };
                        // Keep junctions free: near a street crossing this one.
                        let in_junction = if along_x {
                            scene.roads.distance_to_street_along_y(xy[0]) < curb + 2.0
                        } else {
                            scene.roads.distance_to_street_along_x(xy[1]) < curb + 2.0
                        };
                        if !in_junction {
                            if kind == StaticKind::Tree {
                                scene.add_tree(cfg, xy, rng, &clear);
                            } else if kind == StaticKind::Furniture {
                                scene.add_furniture(
                                    cfg,
                                    xy,
                                    if along_x { 0.0 } else { std::f64::consts::FRAC_PI_2 },
                                    rng,
                                    &clear,
                                );
                            } else if clear(xy, 0.2) {
                                let h = scene.terrain.height(xy);
                                let c = Cylinder {
                                    xy,
                                    radius: 0.12,
                                    z0: h - 0.2,
                                    z1: h + uniform_in(rng, cfg.pole_height_m),
                                };
                                scene.push(StaticKind::Pole, Shape::Cylinder(c), m.pole);
                            }
                        }
                        s += spacing * rng.random_range(0.8..1.2);
                    }
                }
            }
        }
        scene
    }

    fn push(&mut self, kind: StaticKind, shape: Shape, reflectivity: f64) {
        self.statics.push(Primitive::new(shape, reflectivity));
        self.objects.push(kind);
    }

    fn add_tree<R: Rng + ?Sized>(
        &mut self,
        cfg: &SceneConfig,
        xy: [f64; 2],
        rng: &mut R,
        clear: &dyn Fn([f64; 2], f64) -> bool,
    ) {
        let crown_r = uniform_in(rng, cfg.tree_crown_radius_m);
        if !clear(xy, crown_r) {
            return;
        }
        let h = self.terrain.height(xy);
        let trunk_top = h + uniform_in(rng, cfg.tree_trunk_height_m);
        let trunk = Cylinder { xy, radius: rng.random_range(0.1..0.3), z0: h - 0.2, z1: trunk_top + 0.5 * crown_r };
        self.statics.push(Primitive::new(Shape::Cylinder(trunk), cfg.materials.trunk));
        let crown = Sphere { center: [xy[0], xy[1], trunk_top + crown_r], radius: crown_r };
        self.statics.push(Primitive::new(Shape::Sphere(crown), cfg.materials.crown * rng.random_range(0.8..1.1)));
        self.objects.push(StaticKind::Tree);
    }

    fn add_bush<R: Rng + ?Sized>(
        &mut self,
        cfg: &SceneConfig,
        xy: [f64; 2],
        rng: &mut R,
        clear: &dyn Fn([f64; 2], f64) -> bool,
    ) {
        let r = uniform_in(rng, cfg.bush_radius_m);
        if !clear(xy, r) {
            return;
        }
        // Partly sunk, so it sits on the ground like a shrub rather than a ball.
        let z = self.terrain.height(xy) + 0.45 * r;
        self.push(
            StaticKind::Bush,
            Shape::Sphere(Sphere { center: [xy[0], xy[1], z], radius: r }),
            cfg.materials.crown * rng.random_range(0.8..1.1),
        );
    }

    /// A bin, bench, bollard or planter: a small box along the sidewalk.
    fn add_furniture<R: Rng + ?Sized>(
        &mut self,
        cfg: &SceneConfig,
        xy: [f64; 2],
        heading: f64,
        rng: &mut R,
        clear: &dyn Fn([f64; 2], f64) -> bool,
    ) {
        let len = uniform_in(rng, cfg.furniture_size_m);
        let width = uniform_in(rng, [cfg.furniture_size_m[0], cfg.furniture_size_m[0].max(0.7)]);
        if !clear(xy, 0.5 * len) {
            return;
        }
        let h = self.terrain.height(xy);
        let b = UprightBox::from_bottom_top(
            xy,
            [len, width],
            h - 0.2,
            h + uniform_in(rng, cfg.furniture_height_m),
            heading,
        );
        self.push(StaticKind::Furniture, Shape::Box(b), uniform_in(rng, cfg.materials.furniture));
    }

    /// A low wall along the street-facing edge of a lot (the edge nearest a street).
    fn add_wall<R: Rng + ?Sized>(
        &mut self,
        cfg: &SceneConfig,
        lot: [f64; 4],
        rng: &mut R,
        clear: &dyn Fn([f64; 2], f64) -> bool,
    ) {
        let edges = [
            ([0.5 * (lot[0] + lot[2]), lot[1] + 0.2], lot[2] - lot[0], 0.0),
            ([0.5 * (lot[0] + lot[2]), lot[3] - 0.2], lot[2] - lot[0], 0.0),
            ([lot[0] + 0.2, 0.5 * (lot[1] + lot[3])], lot[3] - lot[1], std::f64::consts::FRAC_PI_2),
            ([lot[2] - 0.2, 0.5 * (lot[1] + lot[3])], lot[3] - lot[1], std::f64::consts::FRAC_PI_2),
        ];
        let Some(&(xy, len, heading)) = edges
            .iter()
            .min_by(|a, b| self.roads.distance_to_street(a.0).total_cmp(&self.roads.distance_to_street(b.0)))
        else {
            return;
        };
        if !clear(xy, 0.5 * len) {
            return;
        }
        let h = self.terrain.height(xy);
        let b = UprightBox::from_bottom_top(xy, [len, 0.3], h - 0.3, h + uniform_in(rng, cfg.wall_height_m), heading);
        self.push(StaticKind::Wall, Shape::Box(b), cfg.materials.wall);
    }

    fn add_steps<R: Rng + ?Sized>(&mut self, c: &StepsConfig, refl: f64, route: &Route, s0: f64, rng: &mut R) {
        let n = rng.random_range(c.count[0].min(c.count[1])..=c.count[0].max(c.count[1])) as usize;
        let (rise, run, landing) = (uniform_in(rng, c.rise_m), uniform_in(rng, c.run_m), uniform_in(rng, c.landing_m));
        let base = self.terrain.height(route.sample(s0).xy);
        // Up n steps, a landing at height n·rise, down n steps: one box per tread, each from
        // below ground to its own top so the flight is solid.
        let mut s = s0;
        let mut treads = Vec::new();
        for k in 1..=n {
            treads.push((s, run, k as f64 * rise));
            s += run;
        }
        treads.push((s, landing, (n + 1) as f64 * rise));
        s += landing;
        for k in (1..=n).rev() {
            treads.push((s, run, k as f64 * rise));
            s += run;
        }
        for (start, length, height) in treads {
            let mid = route.sample(start + 0.5 * length);
            let b =
                UprightBox::from_bottom_top(mid.xy, [length, c.width_m], base - 0.5, base + height, mid.heading_rad);
            self.walkables.push(b);
            self.statics.push(Primitive::new(Shape::Box(b), refl));
        }
        self.objects.push(StaticKind::Steps);
        self.features.steps_at_m = Some(s0);
    }

    fn add_underpass<R: Rng + ?Sized>(&mut self, c: &UnderpassConfig, refl: f64, route: &Route, s: f64, rng: &mut R) {
        let mid = route.sample(s);
        let ground = self.terrain.height(mid.xy);
        let underside = ground + uniform_in(rng, c.clearance_m);
        let width = uniform_in(rng, c.deck_width_m);
        // The deck runs across the route: its own x axis is the route's normal.
        let across = mid.heading_rad + std::f64::consts::FRAC_PI_2;
        let deck = UprightBox::from_bottom_top(
            mid.xy,
            [c.deck_length_m, width],
            underside,
            underside + c.deck_thickness_m,
            across,
        );
        self.statics.push(Primitive::new(Shape::Box(deck), refl));
        let (sa, ca) = across.sin_cos();
        for side in [-1.0, 1.0] {
            let d = side * (0.5 * c.deck_length_m - 0.5 * c.pier_size_m[0]);
            let xy = [mid.xy[0] + d * ca, mid.xy[1] + d * sa];
            let pier = UprightBox::from_bottom_top(
                xy,
                [c.pier_size_m[0], c.pier_size_m[1].min(width)],
                self.terrain.height(xy) - 0.5,
                underside,
                across,
            );
            self.statics.push(Primitive::new(Shape::Box(pier), refl));
        }
        self.objects.push(StaticKind::Underpass);
        self.features.underpass_at_m = Some(s);
    }

    /// Height of what one stands on at `xy`: a step tread if there is one, else the ground.
    pub fn support_height(&self, xy: [f64; 2]) -> f64 {
        let ground = self.terrain.height(xy);
        self.walkables.iter().filter(|b| b.footprint_contains(xy)).map(|b| b.top_z()).fold(ground, f64::max)
    }

    /// Number of static objects (a tree or a flight of steps counts once).
    pub fn object_count(&self) -> usize {
        self.objects.len()
    }
}

/// Splits a block into a grid of lots with sizes drawn from `lot_size_m`.
fn split_block<R: Rng + ?Sized>(b: [f64; 4], lot_size_m: [f64; 2], rng: &mut R) -> Vec<[f64; 4]> {
    let cuts = |lo: f64, hi: f64, rng: &mut R| -> Vec<f64> {
        let mut v = vec![lo];
        let mut x = lo;
        loop {
            let w = uniform_in(rng, lot_size_m);
            if hi - (x + w) < 0.5 * lot_size_m[0] {
                break;
            }
            x += w;
            v.push(x);
        }
        v.push(hi);
        v
    };
    let xs = cuts(b[0], b[2], rng);
    let ys = cuts(b[1], b[3], rng);
    let mut lots = Vec::new();
    for wy in ys.windows(2) {
        for wx in xs.windows(2) {
            lots.push([wx[0], wy[0], wx[1], wy[1]]);
        }
    }
    lots
}

/// Poisson draw (Knuth for small means, normal approximation above 30).
pub(crate) fn poisson<R: Rng + ?Sized>(rng: &mut R, mean: f64) -> usize {
    if mean <= 0.0 {
        return 0;
    }
    if mean > 30.0 {
        return (mean + mean.sqrt() * crate::rng::normal(rng)).round().max(0.0) as usize;
    }
    let l = (-mean).exp();
    let mut k = 0;
    let mut p = 1.0;
    loop {
        p *= rng.random::<f64>();
        if p <= l {
            return k;
        }
        k += 1;
    }
}
