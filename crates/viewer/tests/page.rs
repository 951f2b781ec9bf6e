//! `pi3det view`'s page: written from real KITTI and nuScenes frames, opened in headless
//! Chromium, which must report drawing as many points and boxes as Rust embedded.

mod common;

use std::path::Path;

use common::{chromium, dump_dom, shared, status};
use pi3det_viewer::{write_page, ColorBy, Source, ViewerError};

/// Writes a page and checks what the browser reports for its first frame.
fn check_in_browser(data: &Path, det: Option<&Path>, frames: Option<&str>, what: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene.html");
    let src = Source::open(data, det, frames).unwrap();
    let scene = write_page(&src, 200_000, ColorBy::Height, &out, false).unwrap();
    let (points, boxes) = scene.counts(0).unwrap();
    let size = std::fs::metadata(&out).unwrap().len();
    assert!(points > 0 && boxes > 0, "{what}: {points} points, {boxes} boxes");
    let Some(chromium) = chromium() else { return };
    let (dom, took) = dump_dom(&chromium, &format!("file://{}", out.display()), 20_000);
    let s = status(&dom);
    assert_eq!(s.get("state").map(String::as_str), Some("ok"), "{what}: {s:?}");
    assert_eq!(s["points"], points.to_string(), "{what}");
    assert_eq!(s["boxes"], boxes.to_string(), "{what}");
    assert_eq!(s["frames"], scene.frames.len().to_string(), "{what}");
    let nonblank: usize = s["nonblank"].parse().unwrap();
    assert!(nonblank > 1000, "{what}: only {nonblank} pixels drawn");
    eprintln!(
        "{what}: {points} points, {boxes} boxes, page {:.2} MB; headless Chromium {:.2} s wall, drawn at {} ms after navigation",
        size as f64 / 1e6,
        took.as_secs_f64(),
        s["ms"]
    );
}

#[test]
fn kitti_page_draws_every_point_and_box() {
    let data = shared("kitti/training");
    // Detections on two frames: ground truth moved by half a metre, with scores.
    let src = Source::open(&data, None, None).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let det = dir.path().join("det.jsonl");
    let mut lines = String::new();
    for i in 0..2 {
        let mut objs = src.infos[i].objects.clone();
        for o in &mut objs {
            o.box3d.x += 0.5;
            o.score = Some(0.8);
        }
        lines +=
            &serde_json::to_string(&pi3det_eval::JsonlFrame::from_objects(src.infos[i].id.clone(), &objs)).unwrap();
        lines.push('\n');
    }
    std::fs::write(&det, lines).unwrap();
    check_in_browser(&data, Some(&det), Some("0..2"), "KITTI 000000 (with detections)");
    check_in_browser(&data, None, Some("1"), "KITTI 000001");
}

/// A click on a box selects it and shows its fields (the mouse's code path, from `?pick=1`).
#[test]
fn clicking_a_box_shows_its_fields() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene.html");
    let src = Source::open(&shared("kitti/training"), None, Some("1")).unwrap();
    write_page(&src, 200_000, ColorBy::Height, &out, false).unwrap();
    let Some(chromium) = chromium() else { return };
    for camera in ["orbit", "bev", "follow"] {
        let (dom, _) = dump_dom(&chromium, &format!("file://{}?pick=1&camera={camera}", out.display()), 20_000);
        let s = status(&dom);
        assert_eq!(s.get("picked").map(String::as_str), Some("gt:0"), "{camera}: {s:?}");
        let o = &src.infos[1].objects[0];
        let panel = &s["panel"];
        assert!(panel.contains(&o.name) && panel.contains(&format!("{:.3}", o.box3d.x)), "{camera}: {panel}");
        for f in ["x", "dz", "heading"] {
            assert!(panel.contains(f), "{camera}: {panel}");
        }
    }
}

#[test]
fn nuscenes_page_draws_every_point_and_box() {
    let pkl = shared("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl");
    check_in_browser(&pkl, None, None, "nuScenes demo");
}

/// Without WebGL2 the page says so in its status element instead of staying blank.
#[test]
fn without_webgl_the_page_reports_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene.html");
    let src = Source::open(&shared("pi3det_sample"), None, Some("0")).unwrap();
    write_page(&src, 1000, ColorBy::Height, &out, false).unwrap();
    let Some(chromium) = chromium() else { return };
    let url = format!("file://{}", out.display());
    let (dom, _) = common::dump_dom_with(&chromium, &url, 5_000, &["--disable-webgl", "--disable-webgl2"]);
    let s = status(&dom);
    assert_eq!(s.get("state").map(String::as_str), Some("error"), "{s:?}");
    assert!(s["error"].contains("WebGL2"), "{s:?}");
}

#[test]
fn refuses_to_overwrite_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene.html");
    std::fs::write(&out, "keep me").unwrap();
    let src = Source::open(&shared("pi3det_sample"), None, Some("0")).unwrap();
    let e = write_page(&src, 1000, ColorBy::Intensity, &out, false).unwrap_err();
    assert!(matches!(e, ViewerError::Exists { .. }), "{e}");
    assert!(e.to_string().contains("scene.html") && e.to_string().contains("--overwrite"), "{e}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "keep me");
    write_page(&src, 1000, ColorBy::Intensity, &out, true).unwrap();
    let html = std::fs::read_to_string(&out).unwrap();
    assert!(html.contains("\"color\":\"intensity\"") && html.contains("\"n\":1000"));
    assert!(!html.contains("http://") && !html.contains("https://"), "the page loads nothing from the network");
}

#[test]
fn bad_input_names_the_file_or_frame() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nowhere");
    let e = Source::open(&missing, None, None).err().unwrap().to_string();
    assert!(e.contains("nowhere"), "{e}");
    let data = shared("pi3det_sample");
    let e = Source::open(&data, None, Some("4..10")).err().unwrap().to_string();
    assert!(e.contains("pi3det_sample") && e.contains("6 frames"), "{e}");
    let det = dir.path().join("det.jsonl");
    std::fs::write(&det, "{\"frame_id\": \"999999\", \"names\": [], \"scores\": [], \"boxes_lidar\": []}\n").unwrap();
    let e = Source::open(&data, Some(&det), None).err().unwrap().to_string();
    assert!(e.contains("det.jsonl") && e.contains("999999"), "{e}");
    let e = Source::open(&data, Some(&dir.path().join("no.jsonl")), None).err().unwrap().to_string();
    assert!(e.contains("no.jsonl"), "{e}");
}
