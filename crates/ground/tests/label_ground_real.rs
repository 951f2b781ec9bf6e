//! The label check on the real sets of `../shared/data`: KITTI's cars stand on the ground around
//! them; the Argoverse 1 frames, written by a public Argoverse → KITTI converter, carry cars
//! whose bottoms float about half a car's height above it (the converter wrote box centres where
//! KITTI expects bottom centres). `pi3det bench real` reports this per set.

use std::path::PathBuf;

use pi3det_ground::{LabelGroundCheck, LocalGround};

fn check(set: &str) -> LabelGroundCheck {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(set);
    assert!(root.exists(), "real test data missing: {} (expected ../shared/data beside the repo)", root.display());
    let ds = pi3det_data::open(&root).unwrap_or_else(|e| panic!("{}: {e}", root.display()));
    let mut check = LabelGroundCheck::default();
    for i in 0..ds.len() {
        let frame = ds.load(i).unwrap();
        let points: Vec<[f32; 4]> =
            frame.points.to_xyzi().as_slice().chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect();
        let boxes = frame.info.objects.iter().filter(|o| o.name.eq_ignore_ascii_case("Car")).map(|o| &o.box3d);
        check.add_frame(&points, boxes, &LocalGround::default());
    }
    check
}

#[test]
fn kitti_labels_stand_on_the_ground_and_the_converted_argoverse_labels_float() {
    let kitti = check("kitti_extra/training");
    let m = kitti.median_m().expect("enough KITTI boxes near the sensor");
    assert!(!kitti.floating() && m.abs() < 0.15, "KITTI: median bottom − ground {m:.2} m");
    eprintln!("KITTI: {m:.3} m over {} boxes ({} skipped)", kitti.offsets_m.len(), kitti.skipped);
    let argo = check("argoverse1/training");
    let m = argo.median_m().expect("enough Argoverse boxes near the sensor");
    eprintln!("Argoverse: {m:.3} m over {} boxes ({} skipped)", argo.offsets_m.len(), argo.skipped);
    assert!(argo.floating() && (0.5..1.1).contains(&m), "Argoverse: median bottom − ground {m:.2} m");
    // Read as box centres, they stand on it: the converter's mistake, named.
    assert!(argo.reads_as_centres() && !kitti.reads_as_centres(), "{:?}", argo.median_as_centres_m());
}
