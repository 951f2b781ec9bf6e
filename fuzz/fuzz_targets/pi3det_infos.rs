//! Pi3DET info files: pickle → infos → every frame's info.
#![no_main]
use pi3det_data::Dataset;
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(v) = pi3det_data::pickle::from_slice(data) {
        if let Ok(ds) = pi3det_data::pi3det::Pi3detDataset::from_value(std::path::Path::new("fuzz.pkl"), &v) {
            for i in 0..ds.len().min(16) {
                let _ = ds.info(i);
            }
        }
    }
});
