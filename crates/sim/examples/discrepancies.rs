//! Prints the three cross-platform discrepancies of simulated sequences, per platform.
//! `SEED=1 cargo run --release -p pi3det-sim --example discrepancies -- [frames] [sequences] [columns]`

use pi3det_data::Platform;
use pi3det_sim::{Layout, Sequence, SequenceSpec, SimConfig, StatsAccumulator};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let frames: u32 = args.get(1).map_or(Ok(100), |s| s.parse())?;
    let sequences: u32 = args.get(2).map_or(Ok(3), |s| s.parse())?;
    let mut cfg = SimConfig::default();
    if let Some(c) = args.get(3) {
        cfg.sensor.columns = c.parse()?;
    }
    // SEED and LAYOUT (urban, suburban, park) from the environment.
    let seed: u64 = std::env::var("SEED").map_or(Ok(42), |s| s.parse())?;
    let layout = match std::env::var("LAYOUT").as_deref() {
        Ok("urban") => Some(Layout::Urban),
        Ok("suburban") => Some(Layout::Suburban),
        Ok("park") => Some(Layout::Park),
        _ => None,
    };
    for platform in [Platform::Vehicle, Platform::Drone, Platform::Quadruped] {
        let mut acc = StatsAccumulator::default();
        let t0 = std::time::Instant::now();
        let mut n = 0;
        for index in 0..sequences {
            let seq = Sequence::generate(&cfg, SequenceSpec { platform, index, frames, seed, layout })?;
            println!(
                "  {}: {} actors, {} static objects, features {:?}",
                seq.name,
                seq.actor_count(),
                seq.scene.object_count(),
                seq.scene.features
            );
            for f in 0..seq.len() {
                let sim = seq.render(f);
                acc.add(&sim.to_frame("0", platform, &seq.name));
                n += 1;
            }
        }
        let s = acc.finish();
        println!("{platform}: {n} frames in {:.1} s", t0.elapsed().as_secs_f64());
        println!(
            "  roll std {:.2}°, pitch std {:.2}° (max |roll| {:.1}°, |pitch| {:.1}°)",
            s.roll_std_deg, s.pitch_std_deg, s.roll_max_abs_deg, s.pitch_max_abs_deg
        );
        println!(
            "  elevation median {:.2} m (q25 {:.2}, q75 {:.2}), share above sensor {:.1} %",
            s.elevation_median_m,
            s.elevation_q25_m,
            s.elevation_q75_m,
            100.0 * s.share_above_sensor
        );
        println!(
            "  boxes {} ({:.1}/frame): relative pitch median {:.1}° (std {:.1}°), BEV distance median {:.1} m",
            s.boxes,
            s.boxes as f64 / n as f64,
            s.relative_pitch_median_deg,
            s.relative_pitch_std_deg,
            s.bev_distance_median_m
        );
    }
    Ok(())
}
