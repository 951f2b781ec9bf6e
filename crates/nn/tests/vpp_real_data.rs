//! Virtual Platform Pose on the real Pi3DET-layout frames in `../shared/data/pi3det_sample` (six
//! KITTI scans written in the released layout, which carries no poses): every frame is levelled
//! from its own ground plane, and the labelled objects end up standing on the source's ground level.

use std::path::Path;
use std::sync::Arc;

use pi3det_nn::data_loader::{open_split, Subset};
use pi3det_nn::preprocess::vpp::{VirtualPlatformPose, VppConfig};
use pi3det_nn::preprocess::{to_lidar, FrameTransform};
use pi3det_nn::DetectorConfig;

#[test]
fn pose_free_vpp_levels_real_frames_and_puts_objects_on_the_source_ground() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/pi3det_sample");
    let ds = open_split(&root, Some("train")).unwrap();
    assert!(ds.info(0).unwrap().world_from_lidar.is_none(), "the released layout has no poses");
    let subset = Subset::all(ds);
    // KITTI's Velodyne is 1.73 m above the road.
    let (h, n) = pi3det_nn::preprocess::vpp::median_sensor_height(&subset, 64).unwrap();
    assert_eq!(n, subset.len());
    assert!((h - 1.73).abs() < 0.15, "median sensor height {h}");
    // As a target seen from a 1.2 m source sensor: ground at shift_z − 1.2 = 0.7 m.
    let cfg = DetectorConfig { shift_z: 1.9, ..DetectorConfig::default() };
    let vpp = Arc::new(VirtualPlatformPose::new(&VppConfig::default(), cfg.shift_z, 1.2));
    let mut bottoms = Vec::new();
    for &i in &subset.indices {
        let frame = subset.dataset.load(i).unwrap();
        let pose = vpp.detector_from_lidar(&frame);
        let rpy = pi3det_geometry::PoseExt::roll_pitch_yaw(&pose);
        assert!(rpy.roll_rad.abs() < 3f64.to_radians() && rpy.pitch_rad.abs() < 3f64.to_radians(), "{rpy:?}");
        for o in frame.info.objects.iter().filter(|o| o.box3d.x.hypot(o.box3d.y) < 40.0) {
            let b = o.box3d.transformed(&pose);
            bottoms.push(b.z - b.dz / 2.0);
            let back = to_lidar(&b, &pose);
            assert!((back.x - o.box3d.x).abs() < 1e-6 && (back.z - o.box3d.z).abs() < 1e-6);
        }
    }
    let c = vpp.counts();
    assert_eq!((c.frames, c.from_ground, c.from_pose, c.no_ground), (subset.len(), subset.len(), 0, 0));
    assert!(bottoms.len() >= 5, "{} objects", bottoms.len());
    bottoms.sort_by(f64::total_cmp);
    let median = bottoms[bottoms.len() / 2];
    assert!((median - 0.7).abs() < 0.2, "object bottoms at {bottoms:?}");
}
