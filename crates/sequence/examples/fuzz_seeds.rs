//! Seeds for the `hdf5` and `ouster_packets` fuzz targets (fuzz/), written by `scripts/fuzz`:
//! small synthetic sequences in the release's layout (each packet followed by ouster-ros' pad
//! byte) and with exact-size rows, and single packet rows in both layouts.
//!
//! `cargo run -p pi3det-sequence --example fuzz_seeds -- fuzz/corpus`

use std::path::PathBuf;

use pi3det_sequence::ouster::{PacketFormat, SensorMetadata, UdpProfile};
use pi3det_sequence::synth::{metadata_json, sweep_packets, write_sequence, SynthSpec};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let corpus = PathBuf::from(std::env::args().nth(1).ok_or("usage: fuzz_seeds CORPUS_DIR")?);
    let (h5, packets) = (corpus.join("hdf5"), corpus.join("ouster_packets"));
    std::fs::create_dir_all(&h5)?;
    std::fs::create_dir_all(&packets)?;
    let tmp = std::env::temp_dir().join(format!("pi3det-fuzz-seeds-{}", std::process::id()));
    for pad in [1, 0] {
        for profile in [UdpProfile::Legacy, UdpProfile::Rng19Rfl8Sig16Nir16] {
            // Small enough for the fuzzers' 64 kB inputs.
            let name = format!("seed_{profile:?}_pad{pad}").to_lowercase();
            let spec = SynthSpec { beams: 16, columns: 64, row_pad_bytes: pad, profile, ..SynthSpec::os1_64(&name, 1) };
            let seq = write_sequence(&tmp, &spec)?;
            std::fs::copy(seq.join(format!("{name}_data.h5")), h5.join(format!("{name}_data.h5")))?;
            std::fs::copy(seq.join(format!("{name}_pose.h5")), h5.join(format!("{name}_pose.h5")))?;
        }
        // The target's sensor (an OS1-64, LEGACY): its first byte picks the row's pad.
        let spec = SynthSpec::os1_64("fuzz", 1);
        let md = SensorMetadata::parse(std::path::Path::new("fuzz.json"), &metadata_json(&spec))?;
        let format = PacketFormat::new(&md);
        let mut state = 7u64;
        let sweep = sweep_packets(&spec, 0, 0, &mut || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            state
        });
        let mut seed = vec![pad as u8];
        for packet in sweep.chunks_exact(format.packet_bytes()).take(2) {
            seed.extend_from_slice(packet);
            seed.extend(std::iter::repeat_n(0u8, pad));
        }
        std::fs::write(packets.join(format!("two_rows_pad{pad}")), seed)?;
    }
    let _ = std::fs::remove_dir_all(&tmp);
    println!("fuzz seeds written to {}", corpus.display());
    Ok(())
}
