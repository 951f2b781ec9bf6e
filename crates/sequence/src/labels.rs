//! `ps_labels/final_ps_dict.pkl`: the release's pseudo-labels, a dict keyed by the 5-digit frame
//! index → `{"gt_boxes": (N, 9)}` with rows `x, y, z, dx, dy, dz, yaw, label, score`; the class is
//! `['Vehicle', 'Pedestrian', 'Pedestrian'][|label| − 1]` and a negative label marks a box to
//! ignore.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use pi3det_data::pickle::{self, Value};
use pi3det_data::{Object, Platform};
use pi3det_geometry::{Box3d, Pose};

use crate::error::{Result, SequenceError};

/// Class names by `|label| − 1`, as the release defines them.
pub const CLASS_NAMES: [&str; 3] = ["Vehicle", "Pedestrian", "Pedestrian"];

/// Ignored boxes (negative label) are kept as objects named `ignored_<Class>`: no evaluator or
/// trainer in pi3det knows that name, so they are neither positives nor negatives, and the class
/// survives a round trip through the released layout.
pub const IGNORED_PREFIX: &str = "ignored_";

/// One pseudo-label row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PseudoBox {
    pub box3d: [f64; 7],
    pub label: i64,
    pub score: f64,
}

/// Which frame the boxes of `final_ps_dict.pkl` are in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LabelFrame {
    /// As the public Pi3DET M3ED sequence loader reads them: the vehicle's boxes are in the
    /// LiDAR frame; the quadruped's and the drone's in the levelled "virtual" frame of that
    /// frame's pose (roll and pitch removed; quadruped boxes 1.3 m lower, drone boxes at the
    /// sensor height minus 1.7 m), brought back to the LiDAR frame here. Needs the poses.
    #[default]
    Release,
    /// The boxes as stored, taken to be in the LiDAR frame.
    Lidar,
}

impl std::str::FromStr for LabelFrame {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "release" => Ok(Self::Release),
            "lidar" => Ok(Self::Lidar),
            _ => Err(format!("unknown label frame {s:?} (release, lidar)")),
        }
    }
}

/// Reads the dict; rows are checked (9 finite values, label ±1..3, non-negative sizes).
pub fn read(path: &Path) -> Result<BTreeMap<usize, Vec<PseudoBox>>> {
    let value = pickle::from_path(path).map_err(|e| SequenceError::invalid(path, e.to_string()))?;
    let bad = |m: String| SequenceError::invalid(path, m);
    let dict = value.as_dict().ok_or_else(|| bad(format!("expected a dict of frames, found {}", value.type_name())))?;
    let mut out = BTreeMap::new();
    for (key, frame) in dict {
        let key_s = match key {
            Value::Str(s) => s.clone(),
            Value::Int(i) => i.to_string(),
            other => {
                return Err(bad(format!("frame key should be a string like '00012', found {}", other.type_name())))
            }
        };
        let index: usize =
            key_s.trim().parse().map_err(|_| bad(format!("frame key {key_s:?} is not a frame number")))?;
        let what = format!("frame {key_s}");
        let boxes = frame.get("gt_boxes").ok_or_else(|| bad(format!("{what}: no 'gt_boxes'")))?;
        let arr = boxes.as_array().ok_or_else(|| bad(format!("{what}: 'gt_boxes' should be a numpy array")))?;
        let rows = match arr.shape() {
            [0] | [0, _] => Vec::new(),
            [_, 9] => arr.to_f64_rows().ok_or_else(|| bad(format!("{what}: 'gt_boxes' should be numeric")))?,
            s => return Err(bad(format!("{what}: 'gt_boxes' has shape {s:?}, expected (N, 9)"))),
        };
        let mut parsed = Vec::with_capacity(rows.len());
        for (k, r) in rows.iter().enumerate() {
            let b: [f64; 7] = std::array::from_fn(|j| r[j]);
            Box3d::try_from_array(b).map_err(|e| bad(format!("{what}: box {k}: {e}")))?;
            let label = r[7];
            if !(label.fract() == 0.0 && (1.0..=3.0).contains(&label.abs())) {
                return Err(bad(format!("{what}: box {k}: label {label} is not ±1, ±2 or ±3")));
            }
            parsed.push(PseudoBox { box3d: b, label: label as i64, score: r[8] });
        }
        out.insert(index, parsed);
    }
    Ok(out)
}

/// `n → virtual` of the public loader: roll and pitch of `world_from_lidar` (scipy 'xyz'), and for
/// the drone a lift to the sensor's height above the first frame minus 1.7 m.
fn virtual_from_lidar(world_from_lidar: &Pose, drone: bool) -> Pose {
    let (roll, pitch, _) = world_from_lidar.rotation.euler_angles();
    let level = UnitQuaternion::from_euler_angles(roll, pitch, 0.0);
    let lift = if drone { world_from_lidar.translation.z - 1.7 } else { 0.0 };
    Isometry3::from_parts(Translation3::new(0.0, 0.0, lift), level)
}

/// The objects of one frame in the LiDAR frame.
pub fn objects(
    boxes: &[PseudoBox],
    platform: Platform,
    sequence: &str,
    world_from_lidar: Option<&Pose>,
    frame: LabelFrame,
) -> Result<Vec<Object>, String> {
    let lidar_from_virtual = match (frame, platform) {
        (LabelFrame::Lidar, _) | (_, Platform::Vehicle) | (_, Platform::Unknown) => None,
        // The loader's one exception: this sequence's boxes are only shifted.
        (LabelFrame::Release, _) if sequence == "srt_under_bridge_2" => Some((1.3, Pose::identity())),
        (LabelFrame::Release, p) => {
            let pose = world_from_lidar.ok_or("boxes of a drone or quadruped sequence are in the levelled frame of each pose, and there is no pose file (use the lidar label frame to take them as stored)")?;
            let drone = p == Platform::Drone;
            Some((if drone { 0.0 } else { 1.3 }, virtual_from_lidar(pose, drone).inverse()))
        }
    };
    Ok(boxes
        .iter()
        .map(|b| {
            let mut a = b.box3d;
            if let Some((dz, t)) = &lidar_from_virtual {
                a[2] += dz;
                let c = t.transform_point(&nalgebra::Point3::new(a[0], a[1], a[2]));
                a[..3].copy_from_slice(&[c.x, c.y, c.z]);
                // The loader adds the transform's yaw to the heading (and keeps the box upright).
                a[6] += t.rotation.euler_angles().2;
            }
            let class = CLASS_NAMES[(b.label.unsigned_abs() - 1) as usize];
            let name = if b.label < 0 { format!("{IGNORED_PREFIX}{class}") } else { class.to_string() };
            let mut o = Object::new(name, Box3d::from_array(a));
            o.score = Some(b.score);
            o
        })
        .collect())
}
