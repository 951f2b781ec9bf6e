//! The TOML configurations torch-free crates read: simulator, box fusion, tracking.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    if let Ok(cfg) = pi3det_sim::SimConfig::from_toml_str(&text) {
        let _ = cfg.validate();
    }
    let _ = pi3det_autolabel::fusion::FusionConfig::from_toml_str(&text);
    if let Ok(cfg) = toml::from_str::<pi3det_autolabel::tracking::TrackingConfig>(&text) {
        let _ = cfg.validate();
    }
});
