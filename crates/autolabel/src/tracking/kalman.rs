//! Constant-velocity Kalman filter of one track (AB3DMOT's model, as SimpleTrack's `kf` uses it):
//! state `[x, y, z, heading, dx, dy, dz, vx, vy, vz]`, the box observed directly. Time steps
//! come from the frames' timestamps, so dropped frames predict further.

use nalgebra::{SMatrix, SVector};
use pi3det_geometry::boxes::wrap_angle;
use pi3det_geometry::Box3d;

type State = SVector<f64, 10>;
type Cov = SMatrix<f64, 10, 10>;
type Obs = SVector<f64, 7>;

#[derive(Debug, Clone)]
pub struct BoxFilter {
    x: State,
    p: Cov,
    q: Cov,
    r: SMatrix<f64, 7, 7>,
}

impl BoxFilter {
    /// A filter at `b`, still; velocities start uncertain (AB3DMOT's initial covariance).
    pub fn new(b: &Box3d) -> Self {
        let mut x = State::zeros();
        x.fixed_rows_mut::<7>(0).copy_from(&obs(b));
        let mut p = Cov::identity() * 10.0;
        for k in 7..10 {
            p[(k, k)] = 1000.0;
        }
        let mut q = Cov::identity();
        for k in 7..10 {
            q[(k, k)] = 0.01;
        }
        Self { x, p, q, r: SMatrix::identity() }
    }

    /// Moves the state `dt_s` seconds ahead.
    pub fn predict(&mut self, dt_s: f64) {
        let f = transition(dt_s);
        self.x = f * self.x;
        self.p = f * self.p * f.transpose() + self.q * dt_s.max(1e-3) * 10.0;
        self.x[3] = wrap_angle(self.x[3]);
    }

    /// Corrects with an observed box. A heading off by more than 90° is taken as the same box
    /// seen facing the other way (detectors often confuse front and back).
    pub fn update(&mut self, b: &Box3d) {
        let mut z = obs(b);
        let mut d = wrap_angle(z[3] - self.x[3]);
        if d.abs() > std::f64::consts::FRAC_PI_2 {
            d = wrap_angle(d + std::f64::consts::PI);
        }
        z[3] = self.x[3] + d;
        let h = SMatrix::<f64, 7, 10>::identity();
        let s = h * self.p * h.transpose() + self.r;
        let Some(s_inv) = s.try_inverse() else { return };
        let k = self.p * h.transpose() * s_inv;
        self.x += k * (z - h * self.x);
        self.p = (Cov::identity() - k * h) * self.p;
        self.x[3] = wrap_angle(self.x[3]);
    }

    pub fn state_box(&self) -> Box3d {
        let x = &self.x;
        Box3d { x: x[0], y: x[1], z: x[2], heading: x[3], dx: x[4].max(0.05), dy: x[5].max(0.05), dz: x[6].max(0.05) }
    }

    /// Velocity in m/s (world frame).
    pub fn velocity(&self) -> [f64; 3] {
        [self.x[7], self.x[8], self.x[9]]
    }
}

fn obs(b: &Box3d) -> Obs {
    Obs::from_column_slice(&[b.x, b.y, b.z, b.heading, b.dx, b.dy, b.dz])
}

fn transition(dt_s: f64) -> Cov {
    let mut f = Cov::identity();
    for k in 0..3 {
        f[(k, k + 7)] = dt_s;
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn learns_a_constant_velocity() {
        let b = |t: f64| Box3d { x: 2.0 * t, y: 1.0, z: 0.0, dx: 4.0, dy: 1.8, dz: 1.5, heading: 0.0 };
        let mut f = BoxFilter::new(&b(0.0));
        for k in 1..20 {
            f.predict(0.1);
            f.update(&b(0.1 * k as f64));
        }
        assert!((f.velocity()[0] - 2.0).abs() < 0.05, "{:?}", f.velocity());
        f.predict(0.5);
        assert!((f.state_box().x - 2.0 * 2.4).abs() < 0.1);
    }

    #[test]
    fn a_flipped_heading_is_the_same_box() {
        let a = Box3d { x: 0.0, y: 0.0, z: 0.0, dx: 4.0, dy: 1.8, dz: 1.5, heading: 0.1 };
        let mut f = BoxFilter::new(&a);
        f.predict(0.1);
        f.update(&Box3d { heading: 0.1 + std::f64::consts::PI, ..a });
        assert!((f.state_box().heading - 0.1).abs() < 1e-9);
    }
}
