//! Bounded fuzzing of the detection readers (property tests, run in CI): JSON lines, OpenPCDet
//! `result.pkl` and KITTI result lines, from arbitrary input and from mutations of valid files.
//! An error, never a panic. Longer runs: the `cargo fuzz` targets in `fuzz/`.

use std::path::Path;

use pi3det_data::pickle;
use pi3det_eval::Detections;
use proptest::prelude::*;

const JSONL: &str = r#"{"frame_id": "000123", "names": ["Car", "Pedestrian"], "scores": [0.91, 0.45], "boxes_lidar": [[10.2, -3.1, -0.8, 4.1, 1.8, 1.6, 0.12], [6.0, 2.2, -0.9, 0.7, 0.6, 1.7, 1.5]], "bbox": [[1, 2, 3, 4], [5, 6, 7, 8]], "alpha": [0.1, 0.2], "track_ids": [3, 4]}
{"frame_id": "000124", "names": [], "scores": [], "boxes_lidar": []}
"#;

fn result_pkl() -> Vec<u8> {
    // A result.pkl as OpenPCDet writes it, through our writer.
    let dets = Detections::parse_jsonl(JSONL, Path::new("seed.jsonl")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<pickle::Value> = dets
        .frames
        .iter()
        .map(|(id, d)| {
            let boxes: Vec<f32> = d.iter().flat_map(|d| d.lidar.unwrap().to_array().map(|v| v as f32)).collect();
            pickle::Value::dict([
                ("frame_id", pickle::Value::from(id.as_str())),
                ("name", pickle::NdArray::from_vec(d.iter().map(|d| d.name.clone()).collect::<Vec<_>>()).into()),
                ("score", pickle::NdArray::from_vec(d.iter().map(|d| d.score as f32).collect::<Vec<_>>()).into()),
                ("boxes_lidar", pickle::NdArray::new(vec![d.len(), 7], boxes).unwrap().into()),
            ])
        })
        .collect();
    let p = dir.path().join("result.pkl");
    pickle::to_path(&p, &pickle::Value::List(frames), true).unwrap();
    std::fs::read(p).unwrap()
}

fn mutate(seed: &[u8], edits: &[(usize, u8, u8)]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for &(i, v, kind) in edits {
        if b.is_empty() {
            break;
        }
        let at = i % b.len();
        match kind % 3 {
            0 => b[at] = v,
            1 => b.insert(at, v),
            _ => {
                b.remove(at);
            }
        }
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn jsonl_mutated(e in prop::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..10)) {
        let text = String::from_utf8_lossy(&mutate(JSONL.as_bytes(), &e)).into_owned();
        if let Ok(d) = Detections::parse_jsonl(&text, Path::new("fuzz.jsonl")) {
            for det in d.frames.values().flatten() {
                prop_assert!(det.score.is_finite());
            }
        }
    }

    #[test]
    fn jsonl_arbitrary(text in "\\PC{0,300}") {
        let _ = Detections::parse_jsonl(&text, Path::new("fuzz.jsonl"));
    }

    #[test]
    fn result_pkl_mutated(e in prop::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..10)) {
        thread_local!(static SEED: Vec<u8> = result_pkl());
        let bytes = SEED.with(|s| mutate(s, &e));
        if let Ok(v) = pickle::from_slice(&bytes) {
            let _ = Detections::from_result_value(&v, Path::new("fuzz.pkl"));
        }
    }
}
