//! Ouster sensor metadata JSON, and the packet format and XYZ table built from what parses.
#![no_main]
use pi3det_sequence::ouster::metadata::SensorMetadata;
use pi3det_sequence::ouster::packet::PacketFormat;
use pi3det_sequence::ouster::xyz::XyzLut;
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(md) = SensorMetadata::parse(std::path::Path::new("fuzz.json"), &String::from_utf8_lossy(data)) {
        let _ = PacketFormat::new(&md);
        let _ = XyzLut::new(&md);
    }
});
