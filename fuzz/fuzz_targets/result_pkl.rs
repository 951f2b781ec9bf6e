//! OpenPCDet `result.pkl` detections.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(v) = pi3det_data::pickle::from_slice(data) {
        let _ = pi3det_eval::Detections::from_result_value(&v, std::path::Path::new("fuzz.pkl"));
    }
});
