//! Points per car against range: the simulator's vehicle platform with a sensor preset, against
//! the real KITTI statistics in `../shared/data/kitti_label_stats/boxes_lidar.csv` (HDL-64E, cars
//! in the left camera's field of view). Prints one row per range bin: median (quartiles) real and
//! simulated, and their ratio.
//!
//! `cargo run --release -p pi3det-sim --example kitti_density -- [hdl-64] [SEQUENCES] [FRAMES] [GLASS_RETURN_PROBABILITY]`

use pi3det_data::Platform;
use pi3det_sim::{Sequence, SequenceSpec, SimConfig};

/// The KITTI statistics' range bins (BEV distance of the box centre, m).
const BINS: [f64; 7] = [0.0, 10.0, 20.0, 30.0, 40.0, 60.0, 90.0];

fn quartiles(v: &mut [f64]) -> Option<[f64; 3]> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
    Some([q(0.25), q(0.5), q(0.75)])
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let preset = pi3det_sim::SensorPreset::parse(args.first().map_or("hdl-64", String::as_str)).expect("sensor preset");
    let sequences: u32 = args.get(1).map_or(6, |s| s.parse().expect("sequences"));
    let frames: u32 = args.get(2).map_or(10, |s| s.parse().expect("frames"));
    let csv =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/kitti_label_stats/boxes_lidar.csv");
    let text = std::fs::read_to_string(&csv).expect("../shared/data/kitti_label_stats/boxes_lidar.csv");
    let mut real: Vec<Vec<f64>> = vec![Vec::new(); BINS.len() - 1];
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.get(1) != Some(&"Car") {
            continue;
        }
        let (x, y, n): (f64, f64, f64) = (f[2].parse().unwrap(), f[3].parse().unwrap(), f[9].parse().unwrap());
        if let Some(b) = BINS.windows(2).position(|w| (w[0]..w[1]).contains(&x.hypot(y))) {
            real[b].push(n);
        }
    }
    let mut cfg = SimConfig { sensor: preset.config(), ..SimConfig::default() };
    if let Some(p) = args.get(3) {
        cfg.actors.glass_return_probability = p.parse().expect("glass return probability");
    }
    let mut sim: Vec<Vec<f64>> = vec![Vec::new(); BINS.len() - 1];
    for index in 0..sequences {
        let spec = SequenceSpec { platform: Platform::Vehicle, index, frames: frames * 5, seed: 11, layout: None };
        let seq = Sequence::generate(&cfg, spec).expect("simulate");
        for k in (0..seq.len()).step_by(5) {
            let frame = seq.render(k);
            for o in frame.objects.iter().filter(|o| o.name == "Car") {
                let b = o.box3d;
                // KITTI labels cars in the front camera's field of view (about ±40°).
                if b.x <= 0.0 || b.y.atan2(b.x).abs() > 40f64.to_radians() {
                    continue;
                }
                let n = b.count_points(frame.points.iter().map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]));
                if let Some(bin) = BINS.windows(2).position(|w| (w[0]..w[1]).contains(&b.x.hypot(b.y))) {
                    sim[bin].push(n as f64);
                }
            }
        }
    }
    println!(
        "{} vehicle, {sequences} sequences × {frames} frames, glass return probability {}, cars within ±40° ahead",
        cfg.sensor.name, cfg.actors.glass_return_probability
    );
    println!("| range m | KITTI cars | KITTI median (q1–q3) | sim cars | sim median (q1–q3) | sim / KITTI |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: |");
    for b in 0..BINS.len() - 1 {
        let (nr, ns) = (real[b].len(), sim[b].len());
        let (r, s) = (quartiles(&mut real[b]), quartiles(&mut sim[b]));
        let fmt = |q: Option<[f64; 3]>| q.map_or("–".into(), |q| format!("{:.0} ({:.0}–{:.0})", q[1], q[0], q[2]));
        let ratio = match (r, s) {
            (Some(r), Some(s)) => format!("{:.2}", s[1] / r[1]),
            _ => "–".into(),
        };
        println!("| {}–{} | {nr} | {} | {ns} | {} | {ratio} |", BINS[b], BINS[b + 1], fmt(r), fmt(s));
    }
}
