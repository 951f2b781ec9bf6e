//! Bounded fuzzing of the fusion and tracking TOML configurations (run in CI): mutations of the
//! defaults and arbitrary text give a configuration or an error, never a panic — and a
//! configuration that passes validation fuses and tracks a small scene without panicking.

use pi3det_autolabel::fusion::{fuse_frame, FusionConfig};
use pi3det_autolabel::tracking::{track_sequence, TrackFrame, TrackingConfig};
use pi3det_data::Object;
use pi3det_geometry::{Box3d, Pose};
use proptest::prelude::*;

fn mutate(text: &str, e: &[(usize, u8, bool)]) -> String {
    let mut b = text.as_bytes().to_vec();
    for &(i, v, insert) in e {
        let at = i % b.len().max(1);
        if insert {
            b.insert(at, v)
        } else if !b.is_empty() {
            b[at] = v
        }
    }
    String::from_utf8_lossy(&b).into_owned()
}

fn scene() -> Vec<Object> {
    (0..6)
        .map(|k| {
            let mut o = Object::new(
                if k % 2 == 0 { "Car" } else { "Pedestrian" },
                Box3d {
                    x: 10.0 + 0.1 * k as f64,
                    y: 0.05 * k as f64,
                    z: -0.8,
                    dx: 4.0,
                    dy: 1.8,
                    dz: 1.6,
                    heading: 0.1,
                },
            );
            o.score = Some(0.3 + 0.1 * k as f64);
            o
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn fusion_config_mutated(e in prop::collection::vec((any::<usize>(), any::<u8>(), any::<bool>()), 1..8)) {
        let text = mutate(&toml::to_string_pretty(&FusionConfig::default()).unwrap(), &e);
        if let Ok(cfg) = FusionConfig::from_toml_str(&text) {
            let dets = scene();
            let w = vec![1.0; cfg.classes.len()];
            let _ = fuse_frame(&[(&dets, &w), (&dets, &w)], &cfg);
        }
    }

    #[test]
    fn tracking_config_mutated(e in prop::collection::vec((any::<usize>(), any::<u8>(), any::<bool>()), 1..8)) {
        let text = mutate(&toml::to_string_pretty(&TrackingConfig::default()).unwrap(), &e);
        if let Ok(cfg) = toml::from_str::<TrackingConfig>(&text) {
            if cfg.validate().is_ok() {
                let frames: Vec<TrackFrame> = (0..4)
                    .map(|i| TrackFrame {
                        frame_id: i.to_string(),
                        timestamp_s: 0.1 * i as f64,
                        world_from_lidar: Pose::identity(),
                        detections: scene(),
                    })
                    .collect();
                let _ = track_sequence(&frames, &cfg, &mut 0);
            }
        }
    }

    #[test]
    fn configs_arbitrary(text in "\\PC{0,200}") {
        let _ = FusionConfig::from_toml_str(&text);
        let _ = toml::from_str::<TrackingConfig>(&text);
    }
}
