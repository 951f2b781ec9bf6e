//! Throughput of full frame rendering (world build, ray casting, labels) for one sequence.

use std::time::Instant;

use pi3det_data::Platform;
use serde::Serialize;

use crate::config::SimConfig;
use crate::scene::Layout;
use crate::sequence::{Sequence, SequenceSpec};
use crate::SimError;

#[derive(Debug, Clone, PartialEq)]
pub struct BenchOptions {
    pub platform: Platform,
    pub layout: Layout,
    pub frames: usize,
    pub warmup_frames: usize,
    pub seed: u64,
    /// Rayon threads (`None`: rayon's default, all cores).
    pub threads: Option<usize>,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            platform: Platform::Vehicle,
            layout: Layout::Urban,
            frames: 50,
            warmup_frames: 3,
            seed: 1,
            threads: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    pub platform: String,
    pub layout: String,
    pub sensor: String,
    pub beams: u32,
    pub columns: u32,
    pub threads: usize,
    pub frames: usize,
    /// Static objects (buildings, trees, poles, walls…) plus actors in the whole scene.
    pub scene_objects: usize,
    /// Of those, the ones within the sensor's range at the first frame.
    pub objects_in_range: usize,
    pub primitives_per_frame: usize,
    pub points_per_frame: f64,
    pub boxes_per_frame: f64,
    pub seconds: f64,
    pub frames_per_s: f64,
    pub rays_per_s: f64,
    pub sequence_setup_s: f64,
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "sim bench: {} {} scene, {} {}x{}, {} threads",
            self.platform, self.layout, self.sensor, self.beams, self.columns, self.threads
        )?;
        writeln!(
            f,
            "  scene: {} objects ({} within range at frame 0), {} primitives, setup {:.3} s",
            self.scene_objects, self.objects_in_range, self.primitives_per_frame, self.sequence_setup_s
        )?;
        writeln!(
            f,
            "  {} frames in {:.3} s: {:.1} points/frame, {:.1} boxes/frame",
            self.frames, self.seconds, self.points_per_frame, self.boxes_per_frame
        )?;
        writeln!(f, "  frames/s: {:.1}", self.frames_per_s)?;
        write!(f, "  rays/s:   {:.0} ({:.2} M)", self.rays_per_s, self.rays_per_s / 1e6)
    }
}

pub fn run(cfg: &SimConfig, opts: &BenchOptions) -> Result<BenchReport, SimError> {
    let body = || -> Result<BenchReport, SimError> {
        let t0 = Instant::now();
        let total = opts.frames + opts.warmup_frames;
        let spec = SequenceSpec {
            platform: opts.platform,
            index: 0,
            frames: total as u32,
            seed: opts.seed,
            layout: Some(opts.layout),
        };
        let seq = Sequence::generate(cfg, spec)?;
        let setup = t0.elapsed().as_secs_f64();
        let origin = seq.states[0].world_from_lidar.translation.vector;
        let in_range = |xy: [f64; 2]| (xy[0] - origin.x).hypot(xy[1] - origin.y) <= cfg.sensor.range_max_m;
        let statics_in_range = {
            // Count objects by their first primitive's footprint centre.
            let mut n = 0;
            let mut k = 0;
            for kind in &seq.scene.objects {
                let prim = &seq.scene.statics[k];
                let b = prim.bev_bounds();
                if in_range([0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])]) {
                    n += 1;
                }
                k += match kind {
                    crate::scene::StaticKind::Tree => 2,
                    crate::scene::StaticKind::Underpass => 3,
                    crate::scene::StaticKind::Steps => seq.scene.walkables.len(),
                    _ => 1,
                };
            }
            n
        };
        let actors_in_range = seq.actors.iter().filter(|a| in_range(a.pose_at(0.0).0)).count();
        for f in 0..opts.warmup_frames {
            seq.render(f);
        }
        let t1 = Instant::now();
        let (mut points, mut boxes, mut rays) = (0usize, 0usize, 0usize);
        for f in opts.warmup_frames..total {
            let fr = seq.render(f);
            points += fr.points.len();
            boxes += fr.objects.len();
            rays += fr.rays;
        }
        let secs = t1.elapsed().as_secs_f64().max(1e-9);
        let n = opts.frames.max(1) as f64;
        Ok(BenchReport {
            platform: opts.platform.to_string(),
            layout: opts.layout.as_str().into(),
            sensor: cfg.sensor.name.clone(),
            beams: cfg.sensor.beams,
            columns: cfg.sensor.columns,
            threads: rayon::current_num_threads(),
            frames: opts.frames,
            scene_objects: seq.scene.object_count() + seq.actor_count(),
            objects_in_range: statics_in_range + actors_in_range,
            primitives_per_frame: seq.scene.statics.len() + seq.actors.iter().map(|a| a.parts.len()).sum::<usize>(),
            points_per_frame: points as f64 / n,
            boxes_per_frame: boxes as f64 / n,
            seconds: secs,
            frames_per_s: opts.frames as f64 / secs,
            rays_per_s: rays as f64 / secs,
            sequence_setup_s: setup,
        })
    };
    match opts.threads {
        Some(t) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(t.max(1))
                .build()
                .map_err(|e| SimError::invalid(format!("cannot start {t} threads: {e}")))?;
            pool.install(body)
        }
        None => body(),
    }
}
