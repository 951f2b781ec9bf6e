//! Ouster lidar packets of a valid OS1-64 1024x10 sensor: arbitrary bytes cut into whole packets,
//! decoded and turned into points.
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
    let s = sensor();
    let n = data.len() / s.format.packet_bytes() * s.format.packet_bytes();
    let mut sweep = Sweep::new(0, 0);
    s.format.decode(&data[..n], &mut sweep);
    let mut points = Vec::new();
    s.lut.points(&sweep, &mut points);
});
