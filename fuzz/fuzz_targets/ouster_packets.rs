//! Ouster lidar packets of a valid OS1-64 1024x10 sensor: the first byte picks the stored row
//! size (the packet, the packet and ouster-ros' pad byte, or one byte more, which must be
//! refused), the rest is cut into whole rows, decoded and turned into points.
#![no_main]
use pi3det_sequence::ouster::metadata::SensorMetadata;
use pi3det_sequence::ouster::packet::{PacketFormat, Sweep};
use pi3det_sequence::ouster::xyz::XyzLut;
use std::sync::OnceLock;

struct Sensor {
    format: PacketFormat,
    lut: XyzLut,
}

fn sensor() -> &'static Sensor {
    static S: OnceLock<Sensor> = OnceLock::new();
    S.get_or_init(|| {
        let spec = pi3det_sequence::synth::SynthSpec::os1_64("fuzz", 1);
        let md = SensorMetadata::parse(std::path::Path::new("fuzz.json"), &pi3det_sequence::synth::metadata_json(&spec))
            .expect("synthetic metadata");
        Sensor { format: PacketFormat::new(&md), lut: XyzLut::new(&md) }
    })
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&pick, rows)) = data.split_first() else { return };
    let s = sensor();
    let row_bytes = s.format.packet_bytes() + usize::from(pick % 3);
    match s.format.row_padding(row_bytes) {
        Ok(_) => {
            let mut sweep = Sweep::new(0, 0);
            s.format.decode_rows(rows, row_bytes, &mut sweep);
            let mut points = Vec::new();
            s.lut.points(&sweep, &mut points);
        }
        Err(message) => assert!(pick % 3 == 2 && message.contains("pad byte"), "{message}"),
    }
});
