//! Points per car against range, the simulator against real data: a simulated HDL-64E vehicle
//! (KITTI's sensor) with windows that return a fifth of the beams, against the 733 real KITTI
//! cars of `../shared/data/kitti_label_stats/boxes_lidar.csv`. The stated tolerance: from 10 m
//! to 90 m the median points per car of every range bin is within a factor of 2 of KITTI's
//! (below 10 m KITTI's cars are often cut by the camera's field of view, which the counts cover,
//! so that bin is left out). `cargo run --release -p pi3det-sim --example kitti_density` prints
//! the whole table.

use pi3det_data::Platform;
use pi3det_sim::{SensorPreset, Sequence, SequenceSpec, SimConfig};

const BINS: [f64; 6] = [10.0, 20.0, 30.0, 40.0, 60.0, 90.0];
const FACTOR: f64 = 2.0;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn bin(range_m: f64) -> Option<usize> {
    BINS.windows(2).position(|w| (w[0]..w[1]).contains(&range_m))
}

#[test]
fn simulated_hdl64_cars_have_kittis_points_per_range() {
    let csv =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/kitti_label_stats/boxes_lidar.csv");
    let text = std::fs::read_to_string(&csv).unwrap_or_else(|e| panic!("{}: {e}", csv.display()));
    let mut real = vec![Vec::new(); BINS.len() - 1];
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[1] == "Car" {
            let (x, y, n): (f64, f64, f64) = (f[2].parse().unwrap(), f[3].parse().unwrap(), f[9].parse().unwrap());
            if let Some(b) = bin(x.hypot(y)) {
                real[b].push(n);
            }
        }
    }
    let mut cfg = SimConfig { sensor: SensorPreset::Hdl64.config(), ..SimConfig::default() };
    cfg.actors.glass_return_probability = 0.2;
    let mut sim = vec![Vec::new(); BINS.len() - 1];
    for index in 0..8 {
        let spec = SequenceSpec { platform: Platform::Vehicle, index, frames: 30, seed: 11, layout: None };
        let seq = Sequence::generate(&cfg, spec).unwrap();
        for k in (0..seq.len()).step_by(3) {
            let frame = seq.render(k);
            for b in frame.objects.iter().filter(|o| o.name == "Car").map(|o| o.box3d) {
                // KITTI labels the cars in front of the camera (about ±40°).
                if b.x > 0.0 && b.y.atan2(b.x).abs() < 40f64.to_radians() {
                    if let Some(k) = bin(b.x.hypot(b.y)) {
                        let pts = frame.points.iter().map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]);
                        sim[k].push(b.count_points(pts) as f64);
                    }
                }
            }
        }
    }
    for (k, w) in BINS.windows(2).enumerate() {
        assert!(sim[k].len() >= 5, "{}–{} m: only {} simulated cars", w[0], w[1], sim[k].len());
        let (r, s) = (median(real[k].clone()), median(sim[k].clone()));
        let ratio = s / r;
        eprintln!(
            "{}–{} m: KITTI {r} ({} cars), simulated {s} ({} cars), ratio {ratio:.2}",
            w[0],
            w[1],
            real[k].len(),
            sim[k].len()
        );
        assert!(
            (1.0 / FACTOR..=FACTOR).contains(&ratio),
            "{}–{} m: simulated median {s} points per car against KITTI's {r} ({} cars): ratio {ratio:.2}",
            w[0],
            w[1],
            sim[k].len()
        );
    }
}
