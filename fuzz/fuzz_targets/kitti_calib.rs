//! KITTI calibration files.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pi3det_data::kitti::parse_calib(&String::from_utf8_lossy(data), std::path::Path::new("fuzz.txt"));
});
