//! Broken files give errors that name the file and say what is wrong; nothing panics, and a
//! header claiming a huge size is refused before anything is allocated for it.

mod common;

use std::path::Path;

use pi3det_data::pickle::{self, NdArray, Value};
use pi3det_data::Dataset;
use pi3det_sequence::synth::{metadata_json, write_sequence, SynthSpec};
use pi3det_sequence::{Sequence, SequenceDataset, SequenceOptions};

fn open_err(dir: &Path) -> String {
    match SequenceDataset::open(dir, SequenceOptions::default()) {
        Ok(ds) => {
            // Opening may succeed when only the data chunks are damaged: reading must then fail.
            let errs: Vec<String> = (0..ds.len()).filter_map(|i| ds.load(i).err().map(|e| e.to_string())).collect();
            errs.into_iter().next().expect("some frame should fail to load")
        }
        Err(e) => e.to_string(),
    }
}

#[test]
fn truncated_hdf5() {
    let dir = tempfile::tempdir().unwrap();
    let seq = write_sequence(dir.path(), &SynthSpec::os1_64("trunc", 3)).unwrap();
    let data = seq.join("trunc_data.h5");
    let bytes = std::fs::read(&data).unwrap();
    for keep in [0, 7, 100, 2048, bytes.len() / 3, bytes.len() / 2, bytes.len() - 1000] {
        std::fs::write(&data, &bytes[..keep]).unwrap();
        let e = open_err(&seq);
        assert!(e.contains("trunc_data.h5"), "truncated to {keep}: {e}");
        eprintln!("truncated to {keep} bytes: {e}");
    }
}

#[test]
fn corrupt_lzf_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let seq = write_sequence(dir.path(), &SynthSpec::os1_64("corrupt", 3)).unwrap();
    let data = seq.join("corrupt_data.h5");
    let clean = std::fs::read(&data).unwrap();
    // hdf5-pure writes the chunks first and the metadata after them: damage inside the chunks.
    let mut failed = 0;
    for (at, byte) in [(clean.len() / 5, 0xff), (clean.len() / 3, 0x00), (clean.len() / 2, 0xe0)] {
        let mut bytes = clean.clone();
        bytes[at..at + 256].fill(byte);
        std::fs::write(&data, &bytes).unwrap();
        let ds = SequenceDataset::open(&seq, SequenceOptions::default()).unwrap();
        for i in 0..ds.len() {
            // Either an error naming the file, or (damage LZF cannot notice) some decoded sweep.
            if let Err(e) = ds.load(i) {
                assert!(e.to_string().contains("corrupt_data.h5"), "{e}");
                failed += 1;
            }
        }
    }
    assert!(failed > 0, "no damaged chunk was noticed");
}

#[test]
fn packet_size_that_does_not_fit_the_metadata() {
    let dir = tempfile::tempdir().unwrap();
    // Packets of 64 beams, metadata of 32.
    let mut spec = SynthSpec::os1_64("wrong_size", 2);
    spec.metadata = Some(metadata_json(&SynthSpec { beams: 32, ..spec.clone() }));
    let seq = write_sequence(dir.path(), &spec).unwrap();
    let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
    assert!(e.contains("wrong_size_data.h5") && e.contains("packets are 12609 bytes") && e.contains("6464"), "{e}");
}

/// Rows may hold the packet alone or followed by ouster-ros' one pad byte; one byte short, or
/// two long, is refused naming the file, the row layout and both sizes.
#[test]
fn rows_one_short_or_two_long() {
    for (pad_delta, got) in [(-1i64, 12607), (2, 12610)] {
        let dir = tempfile::tempdir().unwrap();
        let spec = SynthSpec { row_pad_bytes: 0, ..SynthSpec::os1_64("odd_rows", 2) };
        let seq = write_sequence(dir.path(), &spec).unwrap();
        // Rewrite the data set with rows cut or extended.
        let data = seq.join("odd_rows_data.h5");
        let ds = Sequence::open(&seq, SequenceOptions::default()).unwrap();
        let mut bytes = Vec::new();
        for k in 0..ds.len() {
            for p in ds.read_packets(k).unwrap() {
                let mut p = p.clone();
                p.resize((p.len() as i64 + pad_delta) as usize, 0);
                bytes.extend(p);
            }
        }
        drop(ds);
        rewrite_data(&data, &spec, &bytes, got);
        let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
        assert!(
            e.contains("odd_rows_data.h5")
                && e.contains(&format!("/ouster/data of shape [2, 64, {got}]"))
                && e.contains(&format!("packets are {got} bytes"))
                && e.contains("makes 12608-byte packets")
                && e.contains("(12609 bytes)"),
            "{e}"
        );
    }
}

/// Writes `/ouster/data` (and the metadata) of `spec` again with rows of `row_bytes`.
fn rewrite_data(path: &Path, spec: &SynthSpec, bytes: &[u8], row_bytes: u64) {
    let packets = spec.columns.div_ceil(16) as u64;
    let mut b = hdf5_pure::FileBuilder::new();
    let mut g = b.create_group("ouster");
    g.create_dataset("data")
        .with_u8_data(bytes)
        .with_shape(&[spec.frames as u64, packets, row_bytes])
        .with_chunks(&[1, packets, row_bytes])
        .with_lzf();
    g.create_dataset("metadata").with_strings(&[&metadata_json(spec)]).unwrap();
    b.add_group(g.finish());
    b.write(path).unwrap();
}

#[test]
fn metadata_without_beam_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::os1_64("no_beams", 2);
    let mut md: serde_json::Value = serde_json::from_str(&metadata_json(&spec)).unwrap();
    md.as_object_mut().unwrap().remove("beam_intrinsics");
    spec.metadata = Some(md.to_string());
    let seq = write_sequence(dir.path(), &spec).unwrap();
    let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
    assert!(e.contains("no_beams_data.h5") && e.contains("missing beam intrinsics"), "{e}");
    spec.metadata = Some("{\"lidar_mode\": ".into());
    let seq = write_sequence(dir.path(), &spec).unwrap();
    let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
    assert!(e.contains("no_beams_data.h5") && e.contains("not JSON"), "{e}");
}

#[test]
fn pose_file_shorter_than_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let spec = SynthSpec { pose_frames: Some(2), ..SynthSpec::os1_64("short_pose", 3) };
    let seq = write_sequence(dir.path(), &spec).unwrap();
    let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
    assert!(e.contains("short_pose_pose.h5") && e.contains("has 2 frames but the data has 3"), "{e}");
    // --truncate reads the frames both have, as the public loader does.
    let s = Sequence::open(&seq, SequenceOptions { truncate: true, ..Default::default() }).unwrap();
    assert_eq!(s.len(), 2);
}

#[test]
fn malformed_pseudo_label_rows() {
    let dir = tempfile::tempdir().unwrap();
    let seq = write_sequence(dir.path(), &SynthSpec::os1_64("bad_box", 2)).unwrap();
    let pkl = seq.join("ps_labels/final_ps_dict.pkl");
    let write = |arr: NdArray| {
        let v = Value::Dict(vec![(Value::Str("00001".into()), Value::dict([("gt_boxes", Value::Array(arr))]))]);
        pickle::to_path(&pkl, &v, true).unwrap();
    };
    let cases: [(NdArray, &str); 4] = [
        (NdArray::new(vec![1, 8], vec![1.0f32; 8]).unwrap(), "shape [1, 8], expected (N, 9)"),
        (NdArray::new(vec![1, 9], vec![1.0, 2.0, 0.0, 4.0, 2.0, 1.5, 0.0, 7.0, 0.9f32]).unwrap(), "label 7"),
        (NdArray::new(vec![1, 9], vec![1.0, 2.0, 0.0, -4.0, 2.0, 1.5, 0.0, 1.0, 0.9f32]).unwrap(), "negative size"),
        (NdArray::new(vec![1, 9], vec![f32::NAN, 2.0, 0.0, 4.0, 2.0, 1.5, 0.0, 1.0, 0.9]).unwrap(), "non-finite"),
    ];
    for (arr, want) in cases {
        write(arr);
        let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
        assert!(e.contains("final_ps_dict.pkl") && e.contains("frame 00001") && e.contains(want), "{e}");
    }
    std::fs::write(&pkl, b"\x80\x04\x95garbage").unwrap();
    let e = Sequence::open(&seq, SequenceOptions::default()).err().unwrap().to_string();
    assert!(e.contains("final_ps_dict.pkl"), "{e}");
}

/// The same failures on files written by h5py (the Python fixture), and a data set whose header
/// claims 2^31-byte packets (never written, so the file is small).
#[test]
fn h5py_written_bad_files() {
    let Some(py) = common::python() else { return };
    let cases = [
        ("packet-size", "packets are 12605 bytes"),
        ("no-intrinsics", "missing beam intrinsics"),
        ("short-pose", "has 2 frames but the data has 3"),
        ("bad-box", "shape [4, 8]"),
        ("huge", "packets are 2147483648 bytes"),
        ("huge-rows", "exceed the 256 MiB read limit"),
        ("huge-chunks", "chunks of shape [700, 32, 12609] exceed the 256 MiB read limit"),
    ];
    for (kind, want) in cases {
        let dir = tempfile::tempdir().unwrap();
        common::make_sequences(&py, dir.path(), Some(kind));
        let e = open_err(&dir.path().join("processed"));
        let name = format!("bad_{}", kind.replace('-', "_"));
        assert!(e.contains(&name) && e.contains(want), "{kind}: {e}");
        eprintln!("{kind}: {e}");
    }
    // h5py writes the metadata first and the chunks after it: cutting the file damages sweeps.
    let dir = tempfile::tempdir().unwrap();
    common::make_sequences(&py, dir.path(), None);
    let seq = dir.path().join("processed/Car/urban_day/car_urban_day_penno_small_loop");
    let data = seq.join("car_urban_day_penno_small_loop_data.h5");
    let bytes = std::fs::read(&data).unwrap();
    for keep in [bytes.len() / 2, bytes.len() - 100] {
        std::fs::write(&data, &bytes[..keep]).unwrap();
        let e = open_err(&seq);
        assert!(e.contains("car_urban_day_penno_small_loop_data.h5"), "{e}");
        eprintln!("h5py file truncated to {keep} bytes: {e}");
    }
}

/// Random byte damage anywhere in a small sequence's files (more of it in the HDF5 metadata,
/// which hdf5-pure writes after the chunks): opening and loading give results or errors naming a
/// file of the sequence, never a panic.
#[test]
fn random_byte_damage_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let spec = SynthSpec { beams: 16, columns: 128, ..SynthSpec::os1_64("damaged", 2) };
    let seq = write_sequence(dir.path(), &spec).unwrap();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for (file, trials) in [("damaged_data.h5", 300), ("damaged_pose.h5", 150), ("ps_labels/final_ps_dict.pkl", 150)] {
        let path = seq.join(file);
        let clean = std::fs::read(&path).unwrap();
        let (mut errors, mut panics) = (0, Vec::new());
        for trial in 0..trials {
            let mut bytes = clean.clone();
            let tail = clean.len() * 4 / 5;
            for _ in 0..1 + next() % 8 {
                let at = if next() % 4 == 0 {
                    next() as usize % clean.len()
                } else {
                    tail + next() as usize % (clean.len() - tail)
                };
                bytes[at] = next() as u8;
            }
            std::fs::write(&path, &bytes).unwrap();
            let result = std::panic::catch_unwind(|| {
                let ds = SequenceDataset::open(&seq, SequenceOptions::default())?;
                (0..ds.len()).try_for_each(|i| ds.load(i).map(|_| ()).map_err(pi3det_sequence::SequenceError::from))
            });
            match result {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    assert!(e.to_string().contains("damaged"), "{e}");
                    errors += 1;
                }
                Err(_) => panics.push(trial),
            }
        }
        std::fs::write(&path, &clean).unwrap();
        eprintln!("{file}: {trials} damaged copies, {errors} errors, {} panics", panics.len());
        assert!(panics.is_empty(), "{file}: panicked on trials {panics:?}");
    }
}
