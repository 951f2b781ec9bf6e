//! A seeded synthetic split for timing: frames with Car / Pedestrian ground truth in the LiDAR
//! frame and detections (noisy copies, misses, false positives), like a detector's output on a
//! KITTI-val-sized split.

use pi3det_data::{FrameInfo, Object};
use pi3det_eval::{Detection, Detections};
use pi3det_geometry::Box3d;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub struct Split {
    pub gt: Vec<FrameInfo>,
    pub dets: Detections,
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller; good enough for noise.
    let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-12), rng.random());
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

fn object(rng: &mut ChaCha8Rng) -> Object {
    let car = rng.random::<f64>() < 0.6;
    let (name, l, w, h) = if car { ("Car", 3.9, 1.65, 1.55) } else { ("Pedestrian", 0.8, 0.65, 1.75) };
    let b = Box3d::new(
        rng.random_range(0.0..70.0),
        rng.random_range(-35.0..35.0),
        -1.0 + 0.1 * gauss(rng),
        l * rng.random_range(0.85..1.15),
        w * rng.random_range(0.9..1.1),
        h * rng.random_range(0.9..1.1),
        rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
    );
    Object::new(name, b)
}

/// `frames` frames with about `gt_per_frame` ground truths and `det_per_frame` detections.
pub fn split(seed: u64, frames: usize, gt_per_frame: usize, det_per_frame: usize) -> Split {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut gt = Vec::with_capacity(frames);
    let mut dets = Vec::with_capacity(frames);
    for i in 0..frames {
        let id = format!("{i:06}");
        let mut info = FrameInfo::new(id.clone(), Default::default());
        let n = rng.random_range(gt_per_frame / 2..=gt_per_frame * 3 / 2);
        info.objects = (0..n).map(|_| object(&mut rng)).collect();
        let mut d = Vec::new();
        for o in &info.objects {
            if rng.random::<f64>() < 0.85 && d.len() < det_per_frame {
                let s = 0.15 * o.box3d.dy;
                let b = Box3d {
                    x: o.box3d.x + s * gauss(&mut rng),
                    y: o.box3d.y + s * gauss(&mut rng),
                    z: o.box3d.z + 0.05 * gauss(&mut rng),
                    heading: o.box3d.heading + 0.05 * gauss(&mut rng),
                    ..o.box3d
                };
                let score = (0.9 - 0.3 * rng.random::<f64>()).clamp(0.0, 1.0);
                d.push(Detection {
                    name: o.name.clone(),
                    score,
                    lidar: Some(b),
                    camera: None,
                    bbox: None,
                    alpha: None,
                });
            }
        }
        while d.len() < det_per_frame {
            let o = object(&mut rng);
            let score = 0.7 * rng.random::<f64>();
            d.push(Detection { name: o.name, score, lidar: Some(o.box3d), camera: None, bbox: None, alpha: None });
        }
        gt.push(info);
        dets.push((id, d));
    }
    Split { gt, dets: Detections { source: "synthetic".into(), frames: dets.into_iter().collect() } }
}
