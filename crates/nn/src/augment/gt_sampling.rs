//! Ground-truth sampling (SECOND, Yan et al. 2018; OpenPCDet `DataBaseSampler`): a database of
//! every training object's box and points; each frame gets up to `count` objects of a class (minus
//! those it already has) pasted in at their recorded place when their box does not overlap
//! (BEV IoU > 0) any box already there, ignored ones included; the frame's own points inside a
//! pasted box are removed.
//! With `ground_align` (OpenPCDet's KITTI `USE_ROAD_PLANE`, here without a plane file) a pasted
//! object is set down on the ground of the frame it goes into: its recorded z belongs to another
//! frame, whose ground under that place can lie a metre higher or lower (terrain, platform tilt),
//! and a floating car teaches the network that z cannot be read off the ground.

use std::collections::BTreeMap;
use std::sync::Arc;

use pi3det_geometry::{bev_iou, Box3d};
use pi3det_ground::LocalGround;
use rand::seq::SliceRandom;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{points_in_box, Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleGroup {
    pub class: String,
    pub count: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GtSamplingConfig {
    /// Target number of objects per class in a frame.
    pub sample: Vec<SampleGroup>,
    /// Database objects need at least this many points (per class; others: 5).
    pub min_points: BTreeMap<String, usize>,
    /// Put pasted objects on the local ground of the receiving frame (see the module docs).
    pub ground_align: bool,
    /// The local ground is the `ground_quantile` of the z of the frame's points within
    /// `ground_margin_m` of the box footprint (outside it); with fewer than `min_ground_points`
    /// there the margin is doubled once, then the recorded z is kept.
    pub ground_margin_m: f64,
    pub ground_quantile: f64,
    pub min_ground_points: usize,
}

impl Default for GtSamplingConfig {
    /// OpenPCDet's KITTI settings (Car 15, Pedestrian 10 per frame; at least 5 points).
    fn default() -> Self {
        Self {
            sample: vec![
                SampleGroup { class: "Car".into(), count: 15 },
                SampleGroup { class: "Pedestrian".into(), count: 10 },
            ],
            min_points: [("Car".to_string(), 5), ("Pedestrian".to_string(), 5)].into_iter().collect(),
            ground_align: true,
            ground_margin_m: 2.0,
            ground_quantile: 0.1,
            min_ground_points: 8,
        }
    }
}

/// One database object.
#[derive(Debug, Clone, PartialEq)]
pub struct DbObject {
    pub box3d: Box3d,
    pub class: usize,
    pub points: Vec<[f32; 4]>,
}

/// Objects per class index.
#[derive(Debug, Default)]
pub struct GtDatabase {
    pub by_class: Vec<Vec<DbObject>>,
}

impl GtDatabase {
    /// Collects the objects of `samples` (already shifted, unaugmented training frames) with at
    /// least the configured number of points. `class_names[k]` names class `k`.
    pub fn build<'a>(
        samples: impl IntoIterator<Item = &'a Sample>,
        class_names: &[String],
        cfg: &GtSamplingConfig,
    ) -> Self {
        let mut by_class: Vec<Vec<DbObject>> = vec![Vec::new(); class_names.len()];
        for s in samples {
            Self::add_sample(&mut by_class, s, class_names, cfg);
        }
        Self { by_class }
    }

    pub fn add_sample(by_class: &mut [Vec<DbObject>], s: &Sample, class_names: &[String], cfg: &GtSamplingConfig) {
        for (b, &c) in s.boxes.iter().zip(&s.classes) {
            let Some(name) = class_names.get(c) else { continue };
            let min = cfg.min_points.get(name).copied().unwrap_or(5);
            let idx = points_in_box(&s.points, b);
            if idx.len() < min.max(1) {
                continue;
            }
            by_class[c].push(DbObject { box3d: *b, class: c, points: idx.iter().map(|&i| s.points[i]).collect() });
        }
    }

    pub fn len(&self) -> usize {
        self.by_class.iter().map(Vec::len).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

pub struct GtSampling {
    cfg: GtSamplingConfig,
    db: Arc<GtDatabase>,
    /// `(class index, count)` resolved against the database's classes at first use.
    groups: Vec<(usize, usize)>,
}

impl GtSampling {
    pub fn new(cfg: GtSamplingConfig, db: Arc<GtDatabase>) -> Self {
        Self { cfg, db, groups: Vec::new() }
    }

    /// Resolves class names to indices (`class_names[k]` names class `k`).
    pub fn with_classes(mut self, class_names: &[String]) -> Self {
        self.groups = self
            .cfg
            .sample
            .iter()
            .filter_map(|g| class_names.iter().position(|c| *c == g.class).map(|k| (k, g.count)))
            .collect();
        self
    }
}

impl Augment for GtSampling {
    fn name(&self) -> &'static str {
        "gt_sampling"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let mut pasted: Vec<&DbObject> = Vec::new();
        for &(class, count) in &self.groups {
            let have = s.classes.iter().filter(|&&c| c == class).count();
            let pool = match self.db.by_class.get(class) {
                Some(p) if !p.is_empty() => p,
                _ => continue,
            };
            let want = count.saturating_sub(have).min(pool.len());
            if want == 0 {
                continue;
            }
            // Distinct random picks.
            let picks: Vec<usize> = if want * 4 < pool.len() {
                let mut v: Vec<usize> = Vec::with_capacity(want);
                while v.len() < want {
                    let k = rng.random_range(0..pool.len());
                    if !v.contains(&k) {
                        v.push(k);
                    }
                }
                v
            } else {
                let mut all: Vec<usize> = (0..pool.len()).collect();
                all.shuffle(rng);
                all.truncate(want);
                all
            };
            for k in picks {
                let o = &pool[k];
                let r = o.box3d.bev_radius();
                // Ignored boxes are occupied space too: an object may well stand there.
                let clash = s.boxes.iter().chain(&s.ignored).chain(pasted.iter().map(|p| &p.box3d)).any(|b| {
                    let d = (b.x - o.box3d.x).hypot(b.y - o.box3d.y);
                    d < r + b.bev_radius() && bev_iou(b, &o.box3d) > 0.0
                });
                if !clash {
                    pasted.push(o);
                }
            }
        }
        if pasted.is_empty() {
            return;
        }
        // Set each object down on this frame's ground (before the frame's points change).
        let placed: Vec<(Box3d, f32)> = pasted
            .iter()
            .map(|o| {
                let ground = if self.cfg.ground_align { local_ground_z(&s.points, &o.box3d, &self.cfg) } else { None };
                let dz = ground.map_or(0.0, |g| g - o.box3d.bottom());
                (Box3d { z: o.box3d.z + dz, ..o.box3d }, dz as f32)
            })
            .collect();
        // Remove the frame's points inside the pasted boxes, then add the objects' points.
        let mut remove = vec![false; s.points.len()];
        for (b, _) in &placed {
            for i in points_in_box(&s.points, b) {
                remove[i] = true;
            }
        }
        let mut k = 0;
        s.points.retain(|_| {
            k += 1;
            !remove[k - 1]
        });
        for (o, (b, dz)) in pasted.into_iter().zip(placed) {
            s.points.extend(o.points.iter().map(|p| [p[0], p[1], p[2] + dz, p[3]]));
            s.boxes.push(b);
            s.classes.push(o.class);
        }
    }
}

/// The ground height under `b` in a frame, found as the config says ([`LocalGround`]).
pub fn local_ground_z(points: &[[f32; 4]], b: &Box3d, cfg: &GtSamplingConfig) -> Option<f64> {
    LocalGround { margin_m: cfg.ground_margin_m, quantile: cfg.ground_quantile, min_points: cfg.min_ground_points }
        .z(points, b)
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn pastes_non_overlapping_objects_with_their_points() {
        let names = vec!["Car".to_string(), "Pedestrian".to_string()];
        let s0 = sample();
        // A database from a second frame: the same objects moved 20 m along y, and one that
        // overlaps the frame's own car.
        let mut other = s0.clone();
        for b in &mut other.boxes {
            b.y += 20.0;
        }
        for p in &mut other.points {
            p[1] += 20.0;
        }
        let mut clash = s0.clone();
        clash.boxes.truncate(1);
        clash.classes.truncate(1);
        clash.boxes[0].x += 1.0;
        for p in &mut clash.points {
            p[0] += 1.0;
        }
        let cfg = GtSamplingConfig { ground_align: false, ..Default::default() };
        let db = Arc::new(GtDatabase::build([&other, &clash], &names, &cfg));
        assert_eq!(db.by_class[0].len(), 2);
        assert_eq!(db.by_class[1].len(), 1);
        let aug = GtSampling::new(cfg, db).with_classes(&names);
        let mut s = s0.clone();
        aug.apply(&mut s, &mut rng(2));
        // The car 20 m away and the pedestrian were pasted; the overlapping car was not.
        assert_eq!(s.boxes.len(), 4);
        assert_eq!(s.classes, vec![0, 1, 0, 1]);
        for b in &s.boxes[2..] {
            assert_eq!(points_in_box(&s.points, b).len(), 50);
        }
        assert_eq!(s.points.len(), s0.points.len() + 100);
    }

    /// An ignored box is occupied space whatever its class: the database car that would land on
    /// an ignored pedestrian box is not pasted, the database pedestrian is.
    #[test]
    fn ignored_boxes_block_pasting() {
        let names = vec!["Car".to_string(), "Pedestrian".to_string()];
        let s0 = sample();
        let mut other = s0.clone();
        for b in &mut other.boxes {
            b.y += 20.0;
        }
        for p in &mut other.points {
            p[1] += 20.0;
        }
        let cfg = GtSamplingConfig { ground_align: false, ..Default::default() };
        let db = Arc::new(GtDatabase::build([&other], &names, &cfg));
        let aug = GtSampling::new(cfg, db).with_classes(&names);
        let mut free = s0.clone();
        aug.apply(&mut free, &mut rng(2));
        assert_eq!(free.classes, vec![0, 1, 0, 1], "both pasted when nothing is in the way");
        let blocker = Box3d { heading: 0.0, dx: 3.0, dy: 3.0, ..other.boxes[0] };
        let mut s = Sample { ignored: vec![blocker], ignored_classes: vec![1], ..s0.clone() };
        aug.apply(&mut s, &mut rng(2));
        assert_eq!(s.classes, vec![0, 1, 1]);
        assert_eq!(s.boxes[2], other.boxes[1]);
        assert_eq!((s.ignored.clone(), s.ignored_classes.clone()), (vec![blocker], vec![1]));
    }

    /// A frame whose ground lies 0.8 m higher than the database object's: the pasted car and its
    /// points are lifted onto it; without ground alignment it would sink into the ground.
    #[test]
    fn ground_alignment_sets_objects_on_the_local_ground() {
        let names = vec!["Car".to_string(), "Pedestrian".to_string()];
        let car = Box3d::new(20.0, 0.0, -1.1, 4.0, 2.0, 1.6, 0.2); // bottom at −1.9
        let mut src = Sample { boxes: vec![car], classes: vec![0], ..Default::default() };
        for k in 0..40 {
            src.points.push([
                20.0 + (k % 8) as f32 * 0.4 - 1.6,
                (k / 8) as f32 * 0.3 - 0.6,
                -1.8 + (k % 5) as f32 * 0.3,
                0.5,
            ]);
        }
        let cfg = GtSamplingConfig::default();
        let db = Arc::new(GtDatabase::build([&src], &names, &cfg));
        assert_eq!(db.by_class[0].len(), 1);
        // The receiving frame: flat ground at z = −1.1 around x = 20 m, plus a lamp post.
        let mut dst = Sample::default();
        for i in 0..60 {
            for j in 0..30 {
                dst.points.push([12.0 + i as f32 * 0.25, -4.0 + j as f32 * 0.25, -1.1, 0.1]);
            }
        }
        for k in 0..20 {
            dst.points.push([24.5, 2.0, -1.1 + k as f32 * 0.2, 0.3]);
        }
        let mut s = dst.clone();
        GtSampling::new(cfg.clone(), db.clone()).with_classes(&names).apply(&mut s, &mut rng(0));
        assert_eq!(s.boxes.len(), 1);
        assert!((s.boxes[0].bottom() - -1.1).abs() < 1e-6, "{:?}", s.boxes[0]);
        assert_eq!(points_in_box(&s.points, &s.boxes[0]).len(), 40, "the object's points moved with it");
        assert!((local_ground_z(&dst.points, &car, &cfg).unwrap() - -1.1).abs() < 1e-6);
        // Off: the recorded z is kept.
        let mut s = dst.clone();
        let off = GtSamplingConfig { ground_align: false, ..cfg.clone() };
        GtSampling::new(off, db).with_classes(&names).apply(&mut s, &mut rng(0));
        assert_eq!(s.boxes[0].z, car.z);
        // No points around: no estimate.
        assert_eq!(local_ground_z(&[], &car, &cfg), None);
    }
}
