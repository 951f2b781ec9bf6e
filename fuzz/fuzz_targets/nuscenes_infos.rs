//! mmdet3d nuScenes info files: pickle → infos → every frame's info (cameras included).
#![no_main]
use pi3det_data::Dataset;
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(v) = pi3det_data::pickle::from_slice(data) {
        if pi3det_data::nuscenes::looks_like_mmdet3d(&v) {
            let path = std::path::Path::new("fuzz/nuscenes_infos.pkl");
            if let Ok(ds) = pi3det_data::nuscenes::NuscenesDataset::from_value(path, &v, None) {
                for i in 0..ds.len().min(16) {
                    let _ = ds.info(i);
                }
            }
        }
    }
});
