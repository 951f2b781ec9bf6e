//! Detections as JSON lines (or one JSON array).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pi3det_eval::Detections::parse_jsonl(&String::from_utf8_lossy(data), std::path::Path::new("fuzz.jsonl"));
});
