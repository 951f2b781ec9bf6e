//! A test-time view of a frame: its points mirrored across the x axis (y → −y) and/or turned
//! about the vertical axis through the origin, and the boxes moved with them and back.
//! Test-time augmentation and the annotation ensemble both look at a frame through views.

use serde::Serialize;

use crate::boxes::Box3d;

/// Mirror first (when `flip_y`), then turn by `yaw_rad` about z.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct View {
    pub flip_y: bool,
    pub yaw_rad: f64,
}

impl View {
    /// The frame as it is.
    pub const IDENTITY: Self = Self { flip_y: false, yaw_rad: 0.0 };

    pub fn name(&self) -> String {
        match (self.flip_y, self.yaw_rad) {
            (false, 0.0) => "none".into(),
            (true, 0.0) => "flip".into(),
            (f, y) => format!("{}rot{:+.0}", if f { "flip_" } else { "" }, y.to_degrees()),
        }
    }

    /// A point's (x, y) in this view.
    pub fn apply_xy(self, x: f64, y: f64) -> (f64, f64) {
        let y = if self.flip_y { -y } else { y };
        let (s, c) = self.yaw_rad.sin_cos();
        (c * x - s * y, s * x + c * y)
    }

    /// A box of the original frame in this view.
    pub fn into_view(self, b: &Box3d) -> Box3d {
        let (x, y) = self.apply_xy(b.x, b.y);
        let h = if self.flip_y { -b.heading } else { b.heading };
        Box3d { x, y, heading: h + self.yaw_rad, ..*b }.with_wrapped_heading()
    }

    /// A box seen in this view, back in the original frame.
    pub fn out_of_view(self, b: &Box3d) -> Box3d {
        let (s, c) = (-self.yaw_rad).sin_cos();
        let (x, y) = (c * b.x - s * b.y, s * b.x + c * b.y);
        let h = b.heading - self.yaw_rad;
        let (y, h) = if self.flip_y { (-y, -h) } else { (y, h) };
        Box3d { x, y, heading: h, ..*b }.with_wrapped_heading()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_go_into_a_view_and_back() {
        let b = Box3d::new(10.0, -3.0, -0.8, 4.0, 1.8, 1.5, 0.7);
        for flip_y in [false, true] {
            for yaw_rad in [0.0, 0.26, -1.3] {
                let v = View { flip_y, yaw_rad };
                let back = v.out_of_view(&v.into_view(&b));
                for (p, q) in back.to_array().iter().zip(b.to_array()) {
                    assert!((p - q).abs() < 1e-9, "{v:?}: {back:?}");
                }
                // The box's centre moves as its points do.
                let (x, y) = v.apply_xy(b.x, b.y);
                let seen = v.into_view(&b);
                assert!((seen.x - x).abs() < 1e-12 && (seen.y - y).abs() < 1e-12);
            }
        }
        let f = View { flip_y: true, yaw_rad: 0.0 }.into_view(&b);
        assert!((f.y - 3.0).abs() < 1e-12 && (f.heading + 0.7).abs() < 1e-12, "{f:?}");
    }
}
