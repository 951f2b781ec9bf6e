//! `.bin` point files: the first byte picks the channel count, the rest is the file.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&k, rest)) = data.split_first() else { return };
    let names = ["x", "y", "z", "intensity", "ring", "t", "a", "b"];
    let channels = &names[..usize::from(k) % names.len()];
    let _ = pi3det_data::points::parse_bin(rest, channels, std::path::Path::new("fuzz.bin"));
});
