//! The numpy-aware pickle reader on arbitrary bytes.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pi3det_data::pickle::from_slice(data);
});
