//! Random Platform Jitter (Pi3DET paper §4.1; reference §2): emulates the roll/pitch jitter of
//! drones and quadrupeds on source (vehicle) frames. Roll and pitch are drawn independently from
//! U(−a, a) (a = 5° by default); `R = R_y(pitch) · R_x(roll)` rotates the points and the box
//! centres; box sizes are kept and boxes stay upright, the heading getting the yaw part of `R`
//! (Euler 'xyz'; zero for this composition, so headings are preserved as the paper states).
//! The drawn angles are recorded in [`Sample::platform_jitter`] for the rotation loss of PA.

use pi3det_geometry::RollPitchYaw;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomPlatformJitterConfig {
    /// Maximum |roll| and |pitch| in degrees.
    pub max_deg: f64,
}

impl Default for RandomPlatformJitterConfig {
    fn default() -> Self {
        Self { max_deg: 5.0 }
    }
}

pub struct RandomPlatformJitter(pub RandomPlatformJitterConfig);

impl RandomPlatformJitter {
    /// Applies the jitter of the given roll and pitch (rad), rotating about the sensor origin
    /// `(0, 0, sensor_z)`.
    pub fn jitter(s: &mut Sample, roll: f64, pitch: f64) {
        // R = Rz(0) · Ry(pitch) · Rx(roll) (nalgebra's euler angles are extrinsic x, y, z).
        let q = nalgebra::UnitQuaternion::from_euler_angles(roll, pitch, 0.0);
        let m = q.to_rotation_matrix();
        let r = m.matrix();
        let rf: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)] as f32));
        let z0 = s.sensor_z as f32;
        for p in &mut s.points {
            let (x, y, z) = (p[0], p[1], p[2] - z0);
            p[0] = rf[0][0] * x + rf[0][1] * y + rf[0][2] * z;
            p[1] = rf[1][0] * x + rf[1][1] * y + rf[1][2] * z;
            p[2] = rf[2][0] * x + rf[2][1] * y + rf[2][2] * z + z0;
        }
        let yaw = RollPitchYaw::of(&q).yaw_rad;
        let sz = s.sensor_z;
        for b in s.all_boxes_mut() {
            let c = q * nalgebra::Point3::new(b.x, b.y, b.z - sz);
            b.x = c.x;
            b.y = c.y;
            b.z = c.z + sz;
            b.heading += yaw;
        }
        s.platform_jitter = Some([roll, pitch]);
    }
}

impl Augment for RandomPlatformJitter {
    fn name(&self) -> &'static str {
        "random_platform_jitter"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let a = self.0.max_deg.to_radians();
        let (roll, pitch) = if a > 0.0 { (rng.random_range(-a..a), rng.random_range(-a..a)) } else { (0.0, 0.0) };
        Self::jitter(s, roll, pitch);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn rotates_points_and_centres_keeps_sizes_and_heading() {
        let s0 = sample();
        let mut s = s0.clone();
        RandomPlatformJitter(RandomPlatformJitterConfig::default()).apply(&mut s, &mut rng(11));
        let [roll, pitch] = s.platform_jitter.unwrap();
        assert!(roll.abs() <= 5f64.to_radians() && pitch.abs() <= 5f64.to_radians());
        for (a, b) in s.boxes.iter().zip(&s0.boxes) {
            assert_eq!((a.dx, a.dy, a.dz, a.heading), (b.dx, b.dy, b.dz, b.heading));
            // Centres moved by the rotation: distance from the sensor kept.
            let r0 = (b.x * b.x + b.y * b.y + b.z * b.z).sqrt();
            let r1 = (a.x * a.x + a.y * a.y + a.z * a.z).sqrt();
            assert!((r0 - r1).abs() < 1e-9);
        }
        // Pitch only: a point ahead on the x axis moves down for a positive pitch (R_y).
        let mut t = Sample { points: vec![[10.0, 0.0, 0.0, 0.0]], ..Default::default() };
        RandomPlatformJitter::jitter(&mut t, 0.0, 2f64.to_radians());
        assert!((t.points[0][2] as f64 + 10.0 * 2f64.to_radians().sin()).abs() < 1e-5);
        // Roll only: a point on the y axis moves up for a positive roll (R_x).
        let mut t = Sample { points: vec![[0.0, 10.0, 0.0, 0.0]], ..Default::default() };
        RandomPlatformJitter::jitter(&mut t, 3f64.to_radians(), 0.0);
        assert!((t.points[0][2] as f64 - 10.0 * 3f64.to_radians().sin()).abs() < 1e-5);
        // The pivot is the sensor: with the frame shifted up by 1.9 m, the sensor's own position
        // stays put and a point level with it moves as before.
        let mut t =
            Sample { points: vec![[0.0, 0.0, 1.9, 0.0], [10.0, 0.0, 1.9, 0.0]], sensor_z: 1.9, ..Default::default() };
        RandomPlatformJitter::jitter(&mut t, 0.0, 2f64.to_radians());
        assert!((t.points[0][2] - 1.9).abs() < 1e-6 && t.points[0][0].abs() < 1e-6);
        assert!((t.points[1][2] as f64 - 1.9 + 10.0 * 2f64.to_radians().sin()).abs() < 1e-5);
    }
}
