//! SE(3) poses in f64. Name values by their frames: `world_from_lidar` maps LiDAR-frame points to
//! the world frame; compose as `a_from_c = a_from_b * b_from_c`.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};

use crate::GeometryError;

/// A rigid transform. nalgebra's isometry: rotation then translation.
pub type Pose = Isometry3<f64>;

/// Roll (about x), pitch (about y), yaw (about z) in radians, with the extrinsic 'xyz' convention
/// of scipy / the Pi3DET code: `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct RollPitchYaw {
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
}

impl RollPitchYaw {
    pub fn of(rotation: &UnitQuaternion<f64>) -> Self {
        let (roll_rad, pitch_rad, yaw_rad) = rotation.euler_angles();
        Self { roll_rad, pitch_rad, yaw_rad }
    }

    pub fn rotation(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_euler_angles(self.roll_rad, self.pitch_rad, self.yaw_rad)
    }
}

/// Builds a pose from a translation and roll/pitch/yaw.
pub trait PoseExt: Sized {
    fn from_xyz_rpy(xyz: [f64; 3], roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> Self;
    /// From a row-major 4×4 homogeneous matrix; checks that it is rigid.
    fn try_from_matrix(m: &[[f64; 4]; 4]) -> Result<Self, GeometryError>;
    fn to_matrix_rows(&self) -> [[f64; 4]; 4];
    fn roll_pitch_yaw(&self) -> RollPitchYaw;
}

impl PoseExt for Pose {
    fn from_xyz_rpy(xyz: [f64; 3], roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> Self {
        Isometry3::from_parts(
            Translation3::new(xyz[0], xyz[1], xyz[2]),
            UnitQuaternion::from_euler_angles(roll_rad, pitch_rad, yaw_rad),
        )
    }

    fn try_from_matrix(m: &[[f64; 4]; 4]) -> Result<Self, GeometryError> {
        let r = Matrix3::from_fn(|i, j| m[i][j]);
        let orthonormal = (r.transpose() * r - Matrix3::identity()).abs().max() < 1e-4 && r.determinant() > 0.0;
        let last_row_ok = m[3] == [0.0, 0.0, 0.0, 1.0];
        let finite = m.iter().flatten().all(|v| v.is_finite());
        if !(orthonormal && last_row_ok && finite) {
            return Err(GeometryError::NotRigid(format!("{m:?}")));
        }
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
        Ok(Isometry3::from_parts(Translation3::new(m[0][3], m[1][3], m[2][3]), rotation))
    }

    fn to_matrix_rows(&self) -> [[f64; 4]; 4] {
        let h: Matrix4<f64> = self.to_homogeneous();
        std::array::from_fn(|i| std::array::from_fn(|j| h[(i, j)]))
    }

    fn roll_pitch_yaw(&self) -> RollPitchYaw {
        RollPitchYaw::of(&self.rotation)
    }
}

/// `level_from_sensor`: the rotation that undoes a sensor's roll and pitch but keeps its yaw
/// (`R_y(pitch) · R_x(roll)`, as Virtual Platform Pose uses it), for a sensor whose attitude in a
/// gravity-aligned frame is `rpy`.
pub fn level_from_sensor(rpy: RollPitchYaw) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(rpy.roll_rad, rpy.pitch_rad, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn euler_matches_scipy_xyz() {
        // scipy: Rotation.from_euler('xyz', [0.1, 0.2, 0.3]).as_matrix()[0] =
        // [0.93629336, -0.27509585, 0.21835066]
        let p = Pose::from_xyz_rpy([0.0; 3], 0.1, 0.2, 0.3);
        let m = p.to_matrix_rows();
        for (a, e) in m[0][..3].iter().zip([0.93629336, -0.27509585, 0.21835066]) {
            assert!((a - e).abs() < 1e-7, "{a} vs {e}");
        }
        let rpy = p.roll_pitch_yaw();
        assert!((rpy.roll_rad - 0.1).abs() < 1e-12 && (rpy.pitch_rad - 0.2).abs() < 1e-12);
    }

    #[test]
    fn matrix_round_trip_and_rejects_non_rigid() {
        let p = Pose::from_xyz_rpy([1.0, -2.0, 3.0], 0.3, -0.2, 2.0);
        let q = Pose::try_from_matrix(&p.to_matrix_rows()).unwrap();
        assert!((p.to_homogeneous() - q.to_homogeneous()).abs().max() < 1e-12);
        let mut bad = p.to_matrix_rows();
        bad[0][0] *= 2.0;
        assert!(Pose::try_from_matrix(&bad).is_err());
        let mut nan = p.to_matrix_rows();
        nan[1][3] = f64::NAN;
        assert!(Pose::try_from_matrix(&nan).is_err());
    }
}
