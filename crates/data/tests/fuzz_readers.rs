//! Bounded fuzzing of every reader of this crate (property tests, run in CI): arbitrary bytes and
//! mutations of real files — the numpy pickle reader, Pi3DET and nuScenes infos, KITTI labels and
//! calibration, `.bin` points. The property is the ground rule for bad input: an error, never a
//! panic, and no allocation a header merely claims (a pickle declaring 10¹² elements). Longer runs:
//! the `cargo fuzz` targets in `fuzz/`.

use std::path::Path;

use pi3det_data::kitti::{parse_calib, parse_labels};
use pi3det_data::nuscenes::{looks_like_mmdet3d, NuscenesDataset};
use pi3det_data::pi3det::Pi3detDataset;
use pi3det_data::points::parse_bin;
use pi3det_data::{pickle, Dataset};
use proptest::prelude::*;

fn shared(rel: &str) -> Vec<u8> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e} (the shared test data)", p.display()))
}

/// One edit of a byte string: overwrite, insert, delete, or cut the tail.
#[derive(Debug, Clone)]
enum Edit {
    Set(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Truncate(usize),
}

fn edits() -> impl Strategy<Value = Vec<Edit>> {
    let edit = prop_oneof![
        4 => (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Edit::Set(i, b)),
        2 => (any::<usize>(), prop::collection::vec(any::<u8>(), 1..9)).prop_map(|(i, b)| Edit::Insert(i, b)),
        2 => (any::<usize>(), 1usize..16).prop_map(|(i, n)| Edit::Delete(i, n)),
        1 => any::<usize>().prop_map(Edit::Truncate),
    ];
    prop::collection::vec(edit, 1..8)
}

fn apply(seed: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for e in edits {
        let n = b.len().max(1);
        match e {
            Edit::Set(i, v) if !b.is_empty() => b[i % n] = *v,
            Edit::Insert(i, v) => {
                let at = i % (b.len() + 1);
                b.splice(at..at, v.iter().copied());
            }
            Edit::Delete(i, k) if !b.is_empty() => {
                let at = i % n;
                b.drain(at..(at + k).min(b.len()));
            }
            Edit::Truncate(i) => b.truncate(i % n),
            _ => {}
        }
    }
    b
}

/// Everything a reader offers on a dataset read from `value`, so a bad field anywhere is reached.
fn read_all(ds: &dyn Dataset) {
    for i in 0..ds.len().min(8) {
        let _ = ds.info(i);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn pickle_of_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        let _ = pickle::from_slice(&bytes);
        // With a valid protocol header, more of the reader is reached.
        let mut framed = vec![0x80, 4];
        framed.extend(&bytes);
        let _ = pickle::from_slice(&framed);
    }

    #[test]
    fn pi3det_infos_mutated(e in edits()) {
        let bytes = apply(&shared("pi3det_sample/pi3det_infos_train.pkl"), &e);
        if let Ok(v) = pickle::from_slice(&bytes) {
            if let Ok(ds) = Pi3detDataset::from_value(Path::new("fuzz/pi3det_infos_train.pkl"), &v) {
                read_all(&ds);
            }
        }
    }

    #[test]
    fn kitti_labels_mutated(e in edits(), frame in 0usize..6) {
        let seed = shared(&format!("kitti/training/label_2/{frame:06}.txt"));
        let text = String::from_utf8_lossy(&apply(&seed, &e)).into_owned();
        let _ = parse_labels(&text, Path::new("fuzz.txt"));
    }

    #[test]
    fn kitti_labels_arbitrary(text in "\\PC{0,200}") {
        let _ = parse_labels(&text, Path::new("fuzz.txt"));
    }

    #[test]
    fn kitti_calib_mutated(e in edits(), frame in 0usize..6) {
        let seed = shared(&format!("kitti/training/calib/{frame:06}.txt"));
        let text = String::from_utf8_lossy(&apply(&seed, &e)).into_owned();
        let _ = parse_calib(&text, Path::new("fuzz.txt"));
    }

    #[test]
    fn bin_points_of_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..512), stride in 0usize..7) {
        let names = ["x", "y", "z", "intensity", "ring", "t"];
        let channels: Vec<&str> = (0..stride).map(|k| names[k % names.len()]).collect();
        if let Ok(r) = parse_bin(&bytes, &channels, Path::new("fuzz.bin")) {
            prop_assert_eq!(r.cloud.len() + r.dropped_non_finite, bytes.len() / (4 * stride));
            prop_assert!(r.cloud.xyz_f64().all(|p| p.iter().all(|v| v.is_finite())));
        }
    }
}

proptest! {
    // The nuScenes info file is 59 kB: fewer cases.
    #![proptest_config(ProptestConfig { cases: 300, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn nuscenes_infos_mutated(e in edits()) {
        let bytes = apply(&shared("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl"), &e);
        if let Ok(v) = pickle::from_slice(&bytes) {
            if looks_like_mmdet3d(&v) {
                let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/nuscenes_demo/x.pkl");
                if let Ok(ds) = NuscenesDataset::from_value(&dir, &v, None) {
                    read_all(&ds);
                }
            }
        }
    }
}

/// Headers claiming far more data than the file holds are errors, not allocations.
#[test]
fn declared_sizes_are_not_trusted() {
    // BINBYTES8 / BINUNICODE8 of 10¹² bytes with three present.
    for op in [0x8eu8, 0x8d] {
        let mut b = vec![0x80, 4, op];
        b.extend(1_000_000_000_000u64.to_le_bytes());
        b.extend(b"abc");
        let e = pickle::from_slice(&b).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
    }
    // LONG4 and a BINUNICODE of 4 GiB − 1.
    for op in [0x8bu8, 0x58] {
        let mut b = vec![0x80, 4, op];
        b.extend(u32::MAX.to_le_bytes());
        assert!(pickle::from_slice(&b).is_err());
    }
}
