//! Drawing box edges and labels on an RGB image: anti-aliasing is not needed for a check, so lines
//! are Bresenham (clipped to the image first, so far-off pixels cost nothing) and text is DejaVu
//! Sans rasterised by ab_glyph from the embedded font (no system fonts).

use ab_glyph::{point, Font, FontRef, PxScale, ScaleFont};
use image::{Rgb, RgbImage};

use super::wireframe::{clip_to_rect, BoxView};

pub const GT_COLOUR: Rgb<u8> = Rgb([40, 220, 60]);
pub const DET_COLOUR: Rgb<u8> = Rgb([255, 90, 20]);
const TEXT_COLOUR: Rgb<u8> = Rgb([255, 255, 255]);
const TEXT_PX: f32 = 16.0;

/// The embedded font.
pub fn font() -> FontRef<'static> {
    FontRef::try_from_slice(dejavu::sans::regular()).expect("the dejavu crate ships a valid TTF")
}

/// A blank canvas for cameras whose image is missing.
pub fn canvas(width: u32, height: u32) -> RgbImage {
    RgbImage::from_pixel(width, height, Rgb([32, 32, 32]))
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u64) < img.width() as u64 && (y as u64) < img.height() as u64 {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// A `thickness`-pixel line.
pub fn draw_segment(img: &mut RgbImage, a: [f64; 2], b: [f64; 2], c: Rgb<u8>, thickness: u32) {
    let Some((a, b)) = clip_to_rect(a, b, img.width() as f64 - 1.0, img.height() as f64 - 1.0) else { return };
    let (mut x, mut y) = (a[0].round() as i64, a[1].round() as i64);
    let (x1, y1) = (b[0].round() as i64, b[1].round() as i64);
    let (dx, dy) = ((x1 - x).abs(), -(y1 - y).abs());
    let (sx, sy) = (if x < x1 { 1 } else { -1 }, if y < y1 { 1 } else { -1 });
    let mut err = dx + dy;
    let half = thickness as i64 / 2;
    loop {
        for oy in -half..=(thickness as i64 - 1 - half) {
            for ox in -half..=(thickness as i64 - 1 - half) {
                put(img, x + ox, y + oy, c);
            }
        }
        if x == x1 && y == y1 {
            break;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x += sx;
        }
        if e2 <= dx {
            err += dx;
            y += sy;
        }
    }
}

pub fn draw_box(img: &mut RgbImage, view: &BoxView, c: Rgb<u8>) {
    for (a, b) in view.segments() {
        draw_segment(img, a, b, c, 2);
    }
}

/// Text with a filled background of `bg`, its top-left corner at `(x, y)` (moved inside the image).
pub fn draw_label(img: &mut RgbImage, font: &FontRef<'_>, x: f64, y: f64, text: &str, bg: Rgb<u8>) {
    let scaled = font.as_scaled(PxScale::from(TEXT_PX));
    let width: f32 = text.chars().map(|ch| scaled.h_advance(scaled.glyph_id(ch))).sum();
    let height = scaled.height();
    let x = (x as f32).clamp(0.0, (img.width() as f32 - width - 4.0).max(0.0));
    let y = (y as f32).clamp(0.0, (img.height() as f32 - height - 2.0).max(0.0));
    for py in y as i64..(y + height + 2.0) as i64 {
        for px in x as i64..(x + width + 4.0) as i64 {
            put(img, px, py, bg);
        }
    }
    let mut caret = x + 2.0;
    for ch in text.chars() {
        let mut glyph = scaled.scaled_glyph(ch);
        glyph.position = point(caret, y + 1.0 + scaled.ascent());
        caret += scaled.h_advance(glyph.id);
        let Some(outline) = font.outline_glyph(glyph) else { continue };
        let bounds = outline.px_bounds();
        outline.draw(|gx, gy, coverage| {
            let (px, py) = (bounds.min.x as i64 + gx as i64, bounds.min.y as i64 + gy as i64);
            if px < 0 || py < 0 || px >= img.width() as i64 || py >= img.height() as i64 {
                return;
            }
            let p = img.get_pixel_mut(px as u32, py as u32);
            for k in 0..3 {
                let v = p.0[k] as f32 * (1.0 - coverage) + TEXT_COLOUR.0[k] as f32 * coverage;
                p.0[k] = v.round().clamp(0.0, 255.0) as u8;
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_far_outside_cost_nothing_and_inside_lines_are_drawn() {
        let mut img = canvas(100, 50);
        draw_segment(&mut img, [-1e9, -1e9], [-1e8, 5e8], GT_COLOUR, 2);
        assert!(img.pixels().all(|p| *p == Rgb([32, 32, 32])));
        draw_segment(&mut img, [-1e6, 25.0], [1e6, 25.0], GT_COLOUR, 1);
        assert_eq!(img.get_pixel(0, 25), &GT_COLOUR);
        assert_eq!(img.get_pixel(99, 25), &GT_COLOUR);
    }

    #[test]
    fn text_is_rasterised() {
        let mut img = canvas(200, 40);
        draw_label(&mut img, &font(), 5.0, 5.0, "Car 0.93", DET_COLOUR);
        assert!(img.pixels().any(|p| *p == TEXT_COLOUR || p.0[1] > 200), "no text pixels");
        // Placed inside the image even when asked for a spot off its edge.
        let mut img = canvas(200, 40);
        draw_label(&mut img, &font(), 500.0, 500.0, "x", DET_COLOUR);
        assert_eq!(img.get_pixel(0, 0), &Rgb([32, 32, 32]));
        assert!(img.pixels().any(|p| *p == DET_COLOUR));
    }
}
