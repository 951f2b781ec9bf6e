//! Bird's-eye preview of one frame: points coloured by height, label boxes with a heading tick,
//! range rings every 20 m, the sensor at the centre looking up the image, and a one-line caption
//! drawn with a built-in pixel font (no system fonts needed).

use std::path::Path;

use pi3det_data::Frame;
use plotters::prelude::*;

use crate::SimError;

#[derive(Debug, Clone, PartialEq)]
pub struct PreviewOptions {
    pub size_px: u32,
    /// Metres from the sensor to the image edge.
    pub half_extent_m: f64,
}

impl Default for PreviewOptions {
    fn default() -> Self {
        Self { size_px: 1000, half_extent_m: 60.0 }
    }
}

/// A colour ramp from deep blue through cyan, green and yellow to red (`u` in `[0, 1]`).
fn ramp(u: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [48.0, 18.0, 160.0]),
        (0.25, [30.0, 140.0, 240.0]),
        (0.5, [40.0, 220.0, 120.0]),
        (0.75, [250.0, 210.0, 40.0]),
        (1.0, [240.0, 50.0, 30.0]),
    ];
    let u = u.clamp(0.0, 1.0);
    let k = STOPS.iter().position(|s| s.0 >= u).unwrap_or(4).max(1);
    let (a, b) = (STOPS[k - 1], STOPS[k]);
    let w = (u - a.0) / (b.0 - a.0);
    let c = |i: usize| (a.1[i] + w * (b.1[i] - a.1[i])) as u8;
    RGBColor(c(0), c(1), c(2))
}

/// Renders `frame` to a PNG at `path`. `caption` is drawn at the top (upper case letters, digits
/// and `.:-/%()=` only; anything else is a space).
pub fn render_bev(frame: &Frame, caption: &str, opts: &PreviewOptions, path: &Path) -> Result<(), SimError> {
    let err = |e: &dyn std::fmt::Display| SimError::Preview { path: path.to_path_buf(), message: e.to_string() };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| SimError::Io { path: dir.to_path_buf(), source })?;
    }
    let size = opts.size_px.max(64);
    let centre = f64::from(size) / 2.0;
    let scale = centre / opts.half_extent_m;
    // x forward is up, y left is left.
    let to_px =
        |x: f64, y: f64| -> (i32, i32) { ((centre - y * scale).round() as i32, (centre - x * scale).round() as i32) };
    let root = BitMapBackend::new(path, (size, size)).into_drawing_area();
    root.fill(&RGBColor(10, 10, 14)).map_err(|e| err(&e))?;
    let ring = RGBColor(55, 55, 62);
    let mut r_m = 20.0;
    while r_m <= opts.half_extent_m * 1.45 {
        root.draw(&Circle::new(to_px(0.0, 0.0), (r_m * scale) as i32, ring.stroke_width(1))).map_err(|e| err(&e))?;
        r_m += 20.0;
    }
    // Points, low first so that high structure stays visible, as 2×2 dots. Colour by height
    // above the ground (the frame's 2nd height percentile) over 6 m, so ground, cars and people
    // separate whatever the platform's height; anything higher is red.
    // Heights are levelled with the frame's pose when it has one, so a tilted drone's ground is
    // one colour; positions stay in the sensor frame, where the boxes are.
    let level = frame
        .info
        .world_from_lidar
        .map(|p| pi3det_geometry::level_from_sensor(pi3det_geometry::PoseExt::roll_pitch_yaw(&p)));
    let mut pts: Vec<[f64; 3]> = frame
        .points
        .xyz_f64()
        .map(|p| match level {
            Some(q) => [p[0], p[1], (q * nalgebra::Vector3::new(p[0], p[1], p[2])).z],
            None => p,
        })
        .collect();
    pts.sort_by(|a, b| a[2].total_cmp(&b[2]));
    if !pts.is_empty() {
        let lo = pts[pts.len() * 2 / 100][2];
        for p in &pts {
            let (px, py) = to_px(p[0], p[1]);
            if px >= 0 && py >= 0 && px + 1 < size as i32 && py + 1 < size as i32 {
                let c = ramp((p[2] - lo + 0.2) / 6.0);
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    root.draw_pixel((px + dx, py + dy), &c).map_err(|e| err(&e))?;
                }
            }
        }
    }
    for o in &frame.info.objects {
        let colour =
            if o.name.eq_ignore_ascii_case("pedestrian") { RGBColor(255, 60, 220) } else { RGBColor(255, 255, 255) };
        let mut corners: Vec<(i32, i32)> = o.box3d.bev_corners().iter().map(|c| to_px(c[0], c[1])).collect();
        corners.push(corners[0]);
        root.draw(&PathElement::new(corners, colour.stroke_width(1))).map_err(|e| err(&e))?;
        let (s, c) = o.box3d.heading.sin_cos();
        let front = (o.box3d.x + 0.5 * o.box3d.dx * c, o.box3d.y + 0.5 * o.box3d.dx * s);
        root.draw(&PathElement::new(
            vec![to_px(o.box3d.x, o.box3d.y), to_px(front.0, front.1)],
            colour.stroke_width(1),
        ))
        .map_err(|e| err(&e))?;
    }
    // The sensor: a small triangle pointing forward.
    let (cx, cy) = to_px(0.0, 0.0);
    root.draw(&Polygon::new(vec![(cx, cy - 10), (cx - 6, cy + 6), (cx + 6, cy + 6)], RGBColor(255, 80, 80).filled()))
        .map_err(|e| err(&e))?;
    let caption_w = (caption.chars().count() as i32 * 18 + 14).min(size as i32);
    root.draw(&Rectangle::new([(0, 0), (caption_w, 44)], RGBColor(0, 0, 0).filled())).map_err(|e| err(&e))?;
    draw_text(&root, caption, 12, 12, 3, &RGBColor(235, 235, 235)).map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// 5×7 pixel glyphs, one byte per row (low 5 bits, MSB left).
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        'A' => [14, 17, 17, 31, 17, 17, 17],
        'B' => [30, 17, 17, 30, 17, 17, 30],
        'C' => [14, 17, 16, 16, 16, 17, 14],
        'D' => [30, 17, 17, 17, 17, 17, 30],
        'E' => [31, 16, 16, 30, 16, 16, 31],
        'F' => [31, 16, 16, 30, 16, 16, 16],
        'G' => [14, 17, 16, 23, 17, 17, 15],
        'H' => [17, 17, 17, 31, 17, 17, 17],
        'I' => [14, 4, 4, 4, 4, 4, 14],
        'J' => [7, 2, 2, 2, 2, 18, 12],
        'K' => [17, 18, 20, 24, 20, 18, 17],
        'L' => [16, 16, 16, 16, 16, 16, 31],
        'M' => [17, 27, 21, 21, 17, 17, 17],
        'N' => [17, 17, 25, 21, 19, 17, 17],
        'O' => [14, 17, 17, 17, 17, 17, 14],
        'P' => [30, 17, 17, 30, 16, 16, 16],
        'Q' => [14, 17, 17, 17, 21, 18, 13],
        'R' => [30, 17, 17, 30, 20, 18, 17],
        'S' => [15, 16, 16, 14, 1, 1, 30],
        'T' => [31, 4, 4, 4, 4, 4, 4],
        'U' => [17, 17, 17, 17, 17, 17, 14],
        'V' => [17, 17, 17, 17, 17, 10, 4],
        'W' => [17, 17, 17, 21, 21, 21, 10],
        'X' => [17, 17, 10, 4, 10, 17, 17],
        'Y' => [17, 17, 10, 4, 4, 4, 4],
        'Z' => [31, 1, 2, 4, 8, 16, 31],
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        ':' => [0, 12, 12, 0, 12, 12, 0],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        '/' => [1, 1, 2, 4, 8, 16, 16],
        '%' => [24, 25, 2, 4, 8, 19, 3],
        '(' => [2, 4, 8, 8, 8, 4, 2],
        ')' => [8, 4, 2, 2, 2, 4, 8],
        '=' => [0, 0, 31, 0, 31, 0, 0],
        _ => [0; 7],
    }
}

fn draw_text<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    text: &str,
    x: i32,
    y: i32,
    px: i32,
    colour: &RGBColor,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    for (k, ch) in text.chars().enumerate() {
        let rows = glyph(ch);
        let gx = x + k as i32 * 6 * px;
        for (r, bits) in rows.iter().enumerate() {
            for col in 0..5 {
                if bits & (1 << (4 - col)) != 0 {
                    let (x0, y0) = (gx + col * px, y + r as i32 * px);
                    area.draw(&Rectangle::new([(x0, y0), (x0 + px - 1, y0 + px - 1)], colour.filled()))?;
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::{FrameInfo, Object, PointCloud};
    use pi3det_geometry::Box3d;

    #[test]
    fn writes_a_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        let mut info = FrameInfo::new("0", "x.bin".into());
        info.objects.push(Object::new("Car", Box3d::new(10.0, 3.0, -1.0, 4.5, 1.9, 1.5, 0.4)));
        let pts: Vec<[f32; 4]> =
            (0..500).map(|k| [k as f32 * 0.1, (k % 17) as f32 - 8.0, (k % 5) as f32 * 0.3 - 1.5, 0.3]).collect();
        let frame = Frame { info, points: PointCloud::from_xyzi(&pts) };
        render_bev(&frame, "TEST 0001", &PreviewOptions { size_px: 200, half_extent_m: 30.0 }, &path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
    }
}
