//! Writes a simulated Pi3DET-layout dataset for detector experiments (until `pi3det simulate`
//! is wired): `cargo run --release -p pi3det-nn --example simulate -- OUT [VEHICLE_SEQ FRAMES]
//! [QUAD_SEQ FRAMES] [DRONE_SEQ FRAMES] [SEED]`. Layout: `OUT/<platform>/<split>/`.

use std::path::PathBuf;

use pi3det_data::Platform;
use pi3det_sim::{export, ExportOptions, PlatformPlan, SimConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(args.first().ok_or("usage: simulate OUT [vs vf qs qf ds df seed]")?);
    let n = |i: usize, d: u32| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let plans = vec![
        PlatformPlan::new(Platform::Vehicle, n(1, 8), n(2, 50)),
        PlatformPlan::new(Platform::Quadruped, n(3, 4), n(4, 20)),
        PlatformPlan::new(Platform::Drone, n(5, 4), n(6, 20)),
    ];
    let seed = args.get(7).and_then(|s| s.parse().ok()).unwrap_or(0);
    let opts = ExportOptions { out, seed, overwrite: true, per_platform_folders: true, layout: None };
    let t = std::time::Instant::now();
    let report = export(&SimConfig::default(), &plans, &opts, &mut |_, _| {})?;
    for s in &report.splits {
        println!(
            "{} {}: {} frames, {} boxes, {} points → {}",
            s.platform,
            s.split,
            s.frames,
            s.boxes,
            s.points,
            s.root.display()
        );
    }
    println!("{} frames in {:.1} s", report.frames(), t.elapsed().as_secs_f64());
    Ok(())
}
