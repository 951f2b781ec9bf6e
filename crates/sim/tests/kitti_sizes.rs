//! Car sizes, the simulator against real data: the simulator's Car class (Pi3DET's: sedans down
//! to compact hatchbacks, SUVs, vans; buses left out here) against the 733 real KITTI cars of
//! `../shared/data/kitti_label_stats/boxes_lidar.csv`. Pi3DET's class is meant to be wider than
//! KITTI's, so the check is that KITTI's cars are inside what the simulator draws: KITTI's middle
//! half of lengths and of widths (25th–75th percentile) and cars no longer than its median are
//! drawn often. (The former default, sedans of 4.2 m and longer, drew almost none.)

use pi3det_sim::actors::{vehicle, ActorConfig, Motion};
use rand::SeedableRng;

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

#[test]
fn kittis_cars_are_among_the_simulated_ones() {
    let csv =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/kitti_label_stats/boxes_lidar.csv");
    let text = std::fs::read_to_string(&csv).unwrap_or_else(|e| panic!("{}: {e}", csv.display()));
    let (mut len, mut wid) = (Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[1] == "Car" {
            len.push(f[5].parse::<f64>().unwrap());
            wid.push(f[6].parse::<f64>().unwrap());
        }
    }
    assert!(len.len() > 700, "{} KITTI cars", len.len());
    let l = [quantile(&mut len, 0.25), quantile(&mut len, 0.5), quantile(&mut len, 0.75)];
    let w = [quantile(&mut wid, 0.25), quantile(&mut wid, 0.5), quantile(&mut wid, 0.75)];

    let cfg = ActorConfig::default();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let n = 4000;
    let sizes: Vec<[f64; 3]> = (0..n)
        .map(|_| vehicle(&cfg, &mut rng, false, Motion::Static { xy: [0.0; 2], heading_rad: 0.0 }).size_m)
        .collect();
    let share = |f: &dyn Fn(&[f64; 3]) -> bool| sizes.iter().filter(|s| f(s)).count() as f64 / n as f64;
    let lengths = share(&|s| (l[0]..=l[2]).contains(&s[0]));
    let widths = share(&|s| (w[0]..=w[2]).contains(&s[1]));
    let shorter_than_median = share(&|s| s[0] <= l[1]);
    assert!(lengths >= 0.2, "KITTI's middle half of lengths {l:?}: {:.0} % of simulated cars", 100.0 * lengths);
    assert!(widths >= 0.15, "KITTI's middle half of widths {w:?}: {:.0} % of simulated cars", 100.0 * widths);
    assert!(
        shorter_than_median >= 1.0 / 6.0,
        "{:.0} % no longer than KITTI's median car ({} m)",
        100.0 * shorter_than_median,
        l[1]
    );
}
