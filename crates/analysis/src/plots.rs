//! Figures as PNG and SVG (plotters), one colour per platform (the paper's red vehicle, blue drone,
//! green quadruped). Text uses DejaVu Sans compiled into the binary (plotters' `ab_glyph` font
//! path), so no system font or fontconfig is needed.
//!
//! - `fig2`: laid out like the paper's Fig. 2 — point elevation upper left, ego motion lower left,
//!   relative pitch against BEV distance on the right.
//! - one figure per statistic: ego motion, ground attitude, elevation, targets (2-D histograms),
//!   boxes per class, objects and points per box, point distributions, and per-sequence rows in
//!   the style of appendix Tables 9–14.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use pi3det_data::Platform;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::analyze::Analysis;
use crate::error::AnalysisError;
use crate::group::GroupStats;
use crate::histogram::{Histogram, Histogram2d, Scale};

type Res = Result<(), String>;
/// Picks one distribution out of a group's statistics.
type Pick = fn(&GroupStats) -> &Histogram;
/// Picks one distribution out of a class's box statistics.
type ClassPick = fn(&crate::boxes::ClassStats) -> &Histogram;

fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// Registers the embedded DejaVu Sans for every family plotters asks for. Idempotent; other crates
/// drawing with plotters in the same binary (the `ab_glyph` feature is unified across the build)
/// can call it too.
pub fn register_embedded_font() -> Result<(), AnalysisError> {
    static DONE: OnceLock<Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        for family in ["sans-serif", "serif", "monospace"] {
            register_font(family, FontStyle::Normal, dejavu::sans::regular()).map_err(|_| "embedded font rejected")?;
            register_font(family, FontStyle::Bold, dejavu::sans::bold()).map_err(|_| "embedded font rejected")?;
        }
        Ok(())
    })
    .clone()
    .map_err(AnalysisError::Invalid)
}

/// The paper's colours: vehicle red, drone blue, quadruped green (unknown grey).
pub fn platform_color(p: Platform) -> RGBColor {
    match p {
        Platform::Vehicle => RGBColor(214, 39, 40),
        Platform::Drone => RGBColor(31, 119, 180),
        Platform::Quadruped => RGBColor(44, 160, 44),
        Platform::Unknown => RGBColor(110, 110, 110),
    }
}

/// One distribution drawn as a line of bin shares.
struct Series<'a> {
    label: String,
    color: RGBColor,
    hist: &'a Histogram,
}

fn fmt(v: f64) -> String {
    if !v.is_finite() {
        "-".into()
    } else if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

/// `platform μ=… σ²=…` legend text.
fn label(p: Platform, h: &Histogram) -> String {
    format!("{p} μ={} σ²={}", fmt(h.moments.mean_or_nan()), fmt(h.moments.variance()))
}

fn transformed(h: &Histogram, v: f64) -> f64 {
    match h.scale {
        Scale::Linear => v,
        Scale::Log10p1 => (1.0 + v.max(0.0)).log10(),
    }
}

fn no_data<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, title: &str) -> Res {
    let (w, h) = area.dim_in_pixel();
    area.draw(&Text::new(
        format!("{title}: no data"),
        (w as i32 / 2 - 60, h as i32 / 2),
        ("sans-serif", 16).into_font(),
    ))
    .map_err(err)
}

/// Distributions of several groups on the same bins, as shares per bin (%).
fn hist_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, title: &str, x_desc: &str, series: &[Series]) -> Res {
    let series: Vec<&Series> = series.iter().filter(|s| s.hist.count() > 0).collect();
    if series.is_empty() {
        return no_data(area, title);
    }
    // Axis from the 0.5–99.5 % quantiles of all series, inside the histogram range.
    let h0 = series[0].hist;
    let lo =
        series.iter().map(|s| transformed(s.hist, s.hist.quantile(0.005).unwrap_or(0.0))).fold(f64::INFINITY, f64::min);
    let hi = series
        .iter()
        .map(|s| transformed(s.hist, s.hist.quantile(0.995).unwrap_or(0.0)))
        .fold(f64::NEG_INFINITY, f64::max);
    let pad = ((hi - lo) * 0.08).max(h0.bin_width() * 2.0);
    let (x0, x1) = ((lo - pad).max(h0.lo), (hi + pad).min(h0.hi));
    let (x0, x1) = if x1 > x0 { (x0, x1) } else { (h0.lo, h0.hi) };
    // Fine histograms (errors: 0.01° bins) are drawn merged to about 150 bins across the axis.
    let group = (((x1 - x0) / h0.bin_width() / 150.0).ceil() as usize).max(1);
    let share = |s: &Series| -> Vec<(f64, f64)> {
        let w = s.hist.bin_width();
        let n = s.hist.count() as f64;
        s.hist
            .counts
            .chunks(group)
            .enumerate()
            .map(|(i, c)| {
                (
                    s.hist.lo + (i * group) as f64 * w + 0.5 * c.len() as f64 * w,
                    100.0 * c.iter().sum::<u64>() as f64 / n,
                )
            })
            .collect()
    };
    let y1 = series.iter().flat_map(|s| share(s).into_iter().map(|p| p.1)).fold(0.0, f64::max).max(1e-6) * 1.15;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(48)
        .build_cartesian_2d(x0..x1, 0.0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(if group > 1 { "share per merged bin (%)" } else { "share per bin (%)" })
        .label_style(("sans-serif", 12))
        .axis_desc_style(("sans-serif", 13))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    for s in &series {
        let color = s.color;
        chart
            .draw_series(LineSeries::new(
                share(s).into_iter().filter(|p| p.0 >= x0 && p.0 <= x1),
                color.stroke_width(2),
            ))
            .map_err(err)?
            .label(s.label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(err)
}

fn platform_series<'a>(a: &'a Analysis, pick: impl Fn(&'a GroupStats) -> &'a Histogram) -> Vec<Series<'a>> {
    a.platforms
        .iter()
        .map(|(p, g)| {
            let hist = pick(g);
            Series { label: label(*p, hist), color: platform_color(*p), hist }
        })
        .collect()
}

/// Relative pitch against distance: sampled targets as dots, per-distance mean as a line.
fn targets_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    let title = "Relative pitch θʳ of targets vs BEV distance ρ";
    if a.platforms.values().all(|g| g.targets.relative_pitch_deg.count() == 0) {
        return no_data(area, title);
    }
    let rho_max =
        a.platforms.values().filter_map(|g| g.targets.distance_m.quantile(0.995)).fold(10.0, f64::max).min(100.0)
            * 1.05;
    let (mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY);
    for g in a.platforms.values() {
        if let (Some(lo), Some(hi)) =
            (g.targets.relative_pitch_deg.quantile(0.002), g.targets.relative_pitch_deg.quantile(0.998))
        {
            t0 = t0.min(lo);
            t1 = t1.max(hi);
        }
    }
    let (t0, t1) = ((t0 - 3.0).max(-90.0), (t1 + 3.0).min(90.0));
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..rho_max, t0..t1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("BEV distance ρ (m)")
        .y_desc("relative pitch θʳ (deg), > 0: above the sensor")
        .label_style(("sans-serif", 12))
        .axis_desc_style(("sans-serif", 13))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    chart.draw_series(LineSeries::new([(0.0, 0.0), (rho_max, 0.0)], BLACK.mix(0.4).stroke_width(1))).map_err(err)?;
    for (p, g) in &a.platforms {
        let color = platform_color(*p);
        if let Some(samples) = a.target_samples.get(p) {
            chart
                .draw_series(samples.items.iter().map(|t| Circle::new((t[0], t[1]), 2, color.mix(0.25).filled())))
                .map_err(err)?;
        }
        let h = &g.targets.pitch_by_distance;
        let means: Vec<(f64, f64)> = h
            .columns
            .iter()
            .enumerate()
            .filter(|(_, m)| m.count >= 3)
            .map(|(i, m)| {
                let (a, b) = h.x_edges(i);
                (0.5 * (a + b), m.mean)
            })
            .collect();
        let t = &g.targets.relative_pitch_deg;
        chart
            .draw_series(LineSeries::new(means, color.stroke_width(3)))
            .map_err(err)?
            .label(format!("{p} θʳ μ={}° σ²={}", fmt(t.moments.mean_or_nan()), fmt(t.moments.variance())))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(err)
}

/// The Fig. 2 layout.
fn fig2<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    root.fill(&WHITE).map_err(err)?;
    let root = root
        .titled("Perspective discrepancies across platforms (layout of Pi3DET Fig. 2)", ("sans-serif", 24))
        .map_err(err)?;
    let (w, _) = root.dim_in_pixel();
    let (left, right) = root.split_horizontally(w * 46 / 100);
    let (_, lh) = left.dim_in_pixel();
    let (top, bottom) = left.split_vertically(lh / 2);
    hist_panel(
        &top,
        "Point elevation relative to the sensor (level frame)",
        "z (m)",
        &platform_series(a, |g| &g.elevation.z_level_m),
    )?;
    // Per platform: poses when it has them for most frames, else the ground fit.
    let pick = |roll: bool| -> Vec<Series> {
        a.platforms
            .iter()
            .map(|(p, g)| {
                let pose = crate::report::attitude_from_pose(g);
                let hist = match (pose, roll) {
                    (true, true) => &g.ego.roll_deg,
                    (true, false) => &g.ego.pitch_deg,
                    (false, true) => &g.ground.roll_deg,
                    (false, false) => &g.ground.pitch_deg,
                };
                let src = if pose { "pose" } else { "ground" };
                Series { label: format!("{} ({src})", label(*p, hist)), color: platform_color(*p), hist }
            })
            .collect()
    };
    let (bw, _) = bottom.dim_in_pixel();
    let (roll, pitch) = bottom.split_horizontally(bw / 2);
    hist_panel(&roll, "Ego motion: roll φ", "roll (deg)", &pick(true))?;
    hist_panel(&pitch, "Ego motion: pitch θ", "pitch (deg)", &pick(false))?;
    targets_panel(&right, a)
}

/// A grid of histogram panels, one per `(title, x label, pick)`.
fn grid<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    a: &Analysis,
    title: &str,
    cols: usize,
    panels: &[(&str, &str, Pick)],
) -> Res {
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(err)?;
    let rows = panels.len().div_ceil(cols);
    for (area, (t, x, pick)) in root.split_evenly((rows, cols)).iter().zip(panels) {
        hist_panel(area, t, x, &platform_series(a, pick))?;
    }
    Ok(())
}

fn ego_motion<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    grid(
        root,
        a,
        "Ego motion from poses (roll, pitch, yaw and frame-to-frame jitter)",
        3,
        &[
            ("roll", "deg", |g| &g.ego.roll_deg),
            ("pitch", "deg", |g| &g.ego.pitch_deg),
            ("yaw", "deg", |g| &g.ego.yaw_deg),
            ("roll jitter", "deg per frame", |g| &g.ego.roll_jitter_deg),
            ("pitch jitter", "deg per frame", |g| &g.ego.pitch_jitter_deg),
            ("yaw jitter", "deg per frame", |g| &g.ego.yaw_jitter_deg),
        ],
    )
}

fn ground<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    grid(
        root,
        a,
        "Pose-free attitude from the ground plane (errors against the pose where there is one)",
        4,
        &[
            ("ground roll", "deg", |g| &g.ground.roll_deg),
            ("ground pitch", "deg", |g| &g.ground.pitch_deg),
            ("sensor height above ground", "m", |g| &g.ground.height_m),
            ("inlier ratio", "", |g| &g.ground.inlier_ratio),
            ("|roll error| per frame", "deg", |g| &g.ground.abs_roll_error_deg),
            ("|pitch error| per frame", "deg", |g| &g.ground.abs_pitch_error_deg),
            ("|roll error| smoothed", "deg", |g| &g.ground.smoothed_abs_roll_error_deg),
            ("|pitch error| smoothed", "deg", |g| &g.ground.smoothed_abs_pitch_error_deg),
        ],
    )
}

fn elevation<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    grid(
        root,
        a,
        "Point elevation",
        2,
        &[
            ("z in the level frame (sensor at 0)", "m", |g| &g.elevation.z_level_m),
            ("z in the sensor frame", "m", |g| &g.points.z_m),
        ],
    )
}

fn points<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    grid(
        root,
        a,
        "Point distributions (sensor frame)",
        3,
        &[
            ("x", "m", |g| &g.points.x_m),
            ("y", "m", |g| &g.points.y_m),
            ("z", "m", |g| &g.points.z_m),
            ("intensity", "[0, 1]", |g| &g.points.intensity),
            ("points per frame", "", |g| &g.points.points_per_frame),
        ],
    )
}

fn objects<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    grid(
        root,
        a,
        "Objects per frame and points per box",
        3,
        &[
            ("objects per frame", "", |g| &g.boxes.objects_per_frame),
            ("points per box", "log10(1 + points)", |g| &g.boxes.points_per_box),
            ("target distance", "m", |g| &g.targets.distance_m),
        ],
    )
}

/// Classes by box count, most frequent first.
fn top_classes(a: &Analysis, n: usize) -> Vec<String> {
    let mut c: Vec<(u64, String)> = a.total.boxes.classes.iter().map(|(k, v)| (v.count(), k.clone())).collect();
    c.sort_by(|x, y| y.0.cmp(&x.0).then(x.1.cmp(&y.1)));
    c.into_iter().take(n).map(|x| x.1).collect()
}

fn boxes<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled("Box sizes and points per box per class", ("sans-serif", 22)).map_err(err)?;
    let classes = top_classes(a, 4);
    if classes.is_empty() {
        return no_data(&root, "boxes");
    }
    let cells = root.split_evenly((classes.len(), 4));
    for (r, class) in classes.iter().enumerate() {
        let stats: [(&str, &str, ClassPick); 4] = [
            ("length", "m", |c| &c.length_m),
            ("width", "m", |c| &c.width_m),
            ("height", "m", |c| &c.height_m),
            ("points per box", "log10(1 + points)", |c| &c.points_per_box),
        ];
        for (k, (name, unit, pick)) in stats.iter().enumerate() {
            let series: Vec<Series> = a
                .platforms
                .iter()
                .filter_map(|(p, g)| g.boxes.classes.get(class).map(|c| (p, pick(c))))
                .map(|(p, h)| Series { label: label(*p, h), color: platform_color(*p), hist: h })
                .collect();
            hist_panel(&cells[r * 4 + k], &format!("{class}: {name}"), unit, &series)?;
        }
    }
    Ok(())
}

/// 2-D histogram of relative pitch against distance, one panel per platform (log colour scale).
fn heatmap<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, title: &str, h: &Histogram2d, color: RGBColor) -> Res {
    let max = h.counts.iter().copied().max().unwrap_or(0);
    if max == 0 {
        return no_data(area, title);
    }
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(44)
        .build_cartesian_2d(h.x_lo..h.x_hi, h.y_lo..h.y_hi)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("ρ (m)")
        .y_desc("θʳ (deg)")
        .label_style(("sans-serif", 11))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    let lmax = (max as f64).ln_1p();
    let cells = (0..h.nx).flat_map(|ix| (0..h.ny).map(move |iy| (ix, iy))).filter(|&(ix, iy)| h.count(ix, iy) > 0);
    chart
        .draw_series(cells.map(|(ix, iy)| {
            let (x0, x1) = h.x_edges(ix);
            let (y0, y1) = h.y_edges(iy);
            let t = (h.count(ix, iy) as f64).ln_1p() / lmax;
            Rectangle::new([(x0, y0), (x1, y1)], color.mix(0.15 + 0.85 * t).filled())
        }))
        .map_err(err)?;
    Ok(())
}

fn targets<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis) -> Res {
    root.fill(&WHITE).map_err(err)?;
    let root = root
        .titled("Targets: relative pitch vs BEV distance (top: sensor frame, bottom: levelled)", ("sans-serif", 20))
        .map_err(err)?;
    let n = a.platforms.len().max(1);
    let cells = root.split_evenly((2, n));
    for (k, (p, g)) in a.platforms.iter().enumerate() {
        heatmap(&cells[k], &format!("{p} (sensor frame)"), &g.targets.pitch_by_distance, platform_color(*p))?;
        heatmap(&cells[n + k], &format!("{p} (levelled)"), &g.targets_level.pitch_by_distance, platform_color(*p))?;
    }
    Ok(())
}

/// Appendix Tables 9–14 style: one row per sequence.
fn sequences<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, a: &Analysis, max_rows: usize) -> Res {
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled("Per-sequence distributions (appendix Tables 9–14)", ("sans-serif", 22)).map_err(err)?;
    let seqs: Vec<_> = a.sequences.iter().take(max_rows).collect();
    let cols: [(&str, Pick); 6] = [
        ("x (m)", |g| &g.points.x_m),
        ("y (m)", |g| &g.points.y_m),
        ("z (m)", |g| &g.points.z_m),
        ("intensity", |g| &g.points.intensity),
        ("objects per frame", |g| &g.boxes.objects_per_frame),
        ("log10(1 + points per box)", |g| &g.boxes.points_per_box),
    ];
    let cells = root.split_evenly((seqs.len().max(1), cols.len()));
    for (r, (key, s)) in seqs.iter().enumerate() {
        for (c, (name, pick)) in cols.iter().enumerate() {
            let h = pick(&s.stats);
            let series = [Series {
                label: format!("μ={} σ²={}", fmt(h.moments.mean_or_nan()), fmt(h.moments.variance())),
                color: platform_color(s.platform),
                hist: h,
            }];
            // The sequence name once per row keeps the captions from running into each other.
            let title = if c == 0 { format!("{key}: {name}") } else { name.to_string() };
            hist_panel(&cells[r * cols.len() + c], &title, "", &series)?;
        }
    }
    Ok(())
}

/// Renders a figure function to `<dir>/<stem>.png` and `.svg`.
macro_rules! render {
    ($dir:expr, $stem:expr, $size:expr, $out:expr, |$root:ident| $body:expr) => {{
        let png = $dir.join(format!("{}.png", $stem));
        {
            let $root = BitMapBackend::new(&png, $size).into_drawing_area();
            $body.map_err(|m| AnalysisError::plot(&png, m))?;
            $root.present().map_err(|e| AnalysisError::plot(&png, e))?;
        }
        let svg = $dir.join(format!("{}.svg", $stem));
        {
            let $root = SVGBackend::new(&svg, $size).into_drawing_area();
            $body.map_err(|m| AnalysisError::plot(&svg, m))?;
            $root.present().map_err(|e| AnalysisError::plot(&svg, e))?;
        }
        $out.push(png);
        $out.push(svg);
    }};
}

/// Draws every figure into `dir` (PNG and SVG); returns the files written.
pub fn write_figures(a: &Analysis, dir: &Path) -> Result<Vec<PathBuf>, AnalysisError> {
    register_embedded_font()?;
    std::fs::create_dir_all(dir).map_err(|e| AnalysisError::io(dir, e))?;
    let mut out = Vec::new();
    render!(dir, "fig2", (1800, 1000), out, |root| fig2(&root, a));
    render!(dir, "ego_motion", (1500, 820), out, |root| ego_motion(&root, a));
    render!(dir, "ground_attitude", (1800, 820), out, |root| ground(&root, a));
    render!(dir, "elevation", (1400, 560), out, |root| elevation(&root, a));
    render!(dir, "targets", (520 * a.platforms.len().max(1) as u32, 900), out, |root| targets(&root, a));
    let rows = top_classes(a, 4).len().max(1) as u32;
    render!(dir, "boxes", (1600, 60 + 300 * rows), out, |root| boxes(&root, a));
    render!(dir, "objects", (1500, 460), out, |root| objects(&root, a));
    render!(dir, "points", (1500, 820), out, |root| points(&root, a));
    if !a.sequences.is_empty() {
        const MAX_ROWS: usize = 30;
        let n = a.sequences.len().min(MAX_ROWS) as u32;
        render!(dir, "sequences", (1900, 60 + 200 * n), out, |root| sequences(&root, a, MAX_ROWS));
    }
    Ok(out)
}
