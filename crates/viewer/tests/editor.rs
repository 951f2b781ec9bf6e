//! `pi3det annotate`'s server: malformed edits get 400 and leave the disk alone, saves write new
//! numbered label sets (never the original files), and an edit made through the page in
//! headless Chromium lands on disk.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;

use common::{chromium, copy_tree, dump_dom, http, names, shared, status};
use pi3det_viewer::{ColorBy, EditServer, Editor, Source};

/// A server on an ephemeral loopback port, stopped on drop.
struct Running {
    server: Arc<EditServer>,
    thread: Option<JoinHandle<()>>,
}

impl Running {
    fn start(data: &Path, det: Option<&Path>) -> Self {
        let src = Source::open(data, det, None).unwrap();
        let editor = Editor::new(src, "edit", 200_000, ColorBy::Height).unwrap();
        let server = Arc::new(EditServer::bind(editor, "127.0.0.1:0", false).unwrap());
        let s = server.clone();
        let thread = Some(std::thread::spawn(move || s.run()));
        Self { server, thread }
    }
    fn addr(&self) -> std::net::SocketAddr {
        self.server.addr()
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.server.unblock();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A writable copy of the Pi3DET sample (six KITTI frames in the Pi3DET layout).
fn sample_copy(dir: &Path) -> PathBuf {
    let data = dir.join("pi3det_sample");
    copy_tree(&shared("pi3det_sample"), &data);
    data
}

fn close(a: [f64; 7], b: [f64; 7]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-4)
}

#[test]
fn malformed_edits_get_400_and_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let data = sample_copy(dir.path());
    let before = names(&data);
    let server = Running::start(&data, None);
    let a = server.addr();
    assert!(a.ip().is_loopback());

    let (code, page) = http(a, "GET", "/", b"");
    assert_eq!(code, 200);
    assert!(page.contains("\"mode\":\"edit\"") && page.contains("window.pi3det"));
    let (code, labels) = http(a, "GET", "/api/labels", b"");
    assert_eq!(code, 200);
    let labels: serde_json::Value = serde_json::from_str(&labels).unwrap();
    assert_eq!(labels["frames"].as_array().unwrap().len(), 6);
    let (code, pts) = http(a, "GET", "/api/points/0", b"");
    assert_eq!(code, 200);
    assert_eq!(serde_json::from_str::<serde_json::Value>(&pts).unwrap()["n"], 115384);
    assert_eq!(http(a, "GET", "/api/points/6", b"").0, 404);
    assert_eq!(http(a, "GET", "/nothing", b"").0, 404);
    assert_eq!(http(a, "GET", "/api/save", b"").0, 405);

    let good = r#"{"name":"Car","box":[1,2,-1,4,1.8,1.5,0.1]}"#;
    let frame = |objects: &str| format!(r#"{{"frames":[{{"frame_id":"0000000","objects":[{objects}]}}]}}"#);
    let bad = [
        ("not JSON", "{frames: nope".to_string()),
        ("unknown frame", r#"{"frames":[{"frame_id":"424242","objects":[]}]}"#.to_string()),
        ("non-finite number", frame(r#"{"name":"Car","box":[1e999,2,-1,4,1.8,1.5,0.1]}"#)),
        ("null number", frame(r#"{"name":"Car","box":[null,2,-1,4,1.8,1.5,0.1]}"#)),
        ("negative size", frame(r#"{"name":"Car","box":[1,2,-1,-4,1.8,1.5,0.1]}"#)),
        ("unknown field", frame(r#"{"name":"Car","box":[1,2,-1,4,1.8,1.5,0.1],"colour":"red"}"#)),
        ("unknown top-level field", r#"{"frames":[],"undo":true}"#.to_string()),
        ("six numbers", frame(r#"{"name":"Car","box":[1,2,-1,4,1.8,1.5]}"#)),
        ("empty class", frame(r#"{"name":" ","box":[1,2,-1,4,1.8,1.5,0.1]}"#)),
        ("frame twice", format!(r#"{{"frames":[{0},{0}]}}"#, r#"{"frame_id":"0000000","objects":[]}"#)),
    ];
    for (what, body) in bad {
        let (code, reply) = http(a, "POST", "/api/save", body.as_bytes());
        assert_eq!(code, 400, "{what}: {reply}");
        assert!(serde_json::from_str::<serde_json::Value>(&reply).unwrap()["error"].is_string(), "{what}: {reply}");
        assert_eq!(names(&data), before, "{what} wrote something");
    }
    // Requests another web site could make from the annotator's browser.
    let body = frame(good);
    let cross = [
        (415, format!("Host: {a}\r\nContent-Type: text/plain\r\n")),
        (415, format!("Host: {a}\r\n")),
        (403, format!("Host: {a}\r\nContent-Type: application/json\r\nOrigin: http://evil.example\r\n")),
        (403, "Host: evil.example:8080\r\nContent-Type: application/json\r\n".to_string()),
    ];
    for (want, headers) in cross {
        let (code, reply) = common::http_with(a, "POST", "/api/save", body.as_bytes(), &headers);
        assert_eq!(code, want, "{headers:?}: {reply}");
        assert_eq!(names(&data), before);
    }
    let same_origin = format!("Host: {a}\r\nContent-Type: application/json; charset=utf-8\r\nOrigin: http://{a}\r\n");
    assert_eq!(common::http_with(a, "POST", "/api/save", b"[", &same_origin).0, 400, "checked, then malformed");
    // A good request after the bad ones still saves, and from the untouched labels.
    let (code, reply) = http(a, "POST", "/api/save", frame(good).as_bytes());
    assert_eq!(code, 200, "{reply}");
    let saved: serde_json::Value = serde_json::from_str(&reply).unwrap();
    assert_eq!(saved["version"], 1);
    let ds = pi3det_data::open(&data.join("pi3det_infos_train.edit-001.pkl")).unwrap();
    assert_eq!(ds.info(0).unwrap().objects.len(), 1);
}

#[test]
fn saves_are_new_numbered_label_sets_beside_untouched_originals() {
    let dir = tempfile::tempdir().unwrap();
    let data = sample_copy(dir.path());
    let info = data.join("pi3det_infos_train.pkl");
    let original = std::fs::read(&info).unwrap();
    let orig = pi3det_data::open(&data).unwrap();
    let server = Running::start(&data, None);
    let a = server.addr();
    let body = r#"{"frames":[{"frame_id":"0000001","objects":[{"name":"Van","box":[10,-2,-0.8,4.5,1.9,2.0,1.2]}]}]}"#;
    for version in 1..=2 {
        let (code, reply) = http(a, "POST", "/api/save", body.as_bytes());
        assert_eq!(code, 200, "{reply}");
        let j: serde_json::Value = serde_json::from_str(&reply).unwrap();
        assert_eq!(j["version"], version);
    }
    let n = names(&data);
    for f in [
        "pi3det_infos_train.edit-001.pkl",
        "pi3det_infos_train.edit-002.pkl",
        "labels.edit-001.jsonl",
        "labels.edit-002.jsonl",
    ] {
        assert!(n.contains(&f.to_string()), "{f} not in {n:?}");
    }
    assert_eq!(std::fs::read(&info).unwrap(), original, "the original info file is byte-identical");
    // The folder still opens as the original six frames; the label set opens by its path.
    assert_eq!(pi3det_data::open(&data).unwrap().len(), 6);
    let edited = pi3det_data::open(&data.join("pi3det_infos_train.edit-002.pkl")).unwrap();
    assert_eq!(edited.len(), 6);
    for i in 0..6 {
        let (e, o) = (edited.info(i).unwrap(), orig.info(i).unwrap());
        assert_eq!((&e.id, &e.points_path), (&o.id, &o.points_path), "frame {i} points at the same .bin");
        if i == 1 {
            assert_eq!(e.objects.len(), 1);
            assert_eq!(e.objects[0].name, "Van");
            assert!(close(e.objects[0].box3d.to_array(), [10., -2., -0.8, 4.5, 1.9, 2.0, 1.2]));
        } else {
            assert_eq!(e.objects, o.objects, "frame {i} unchanged");
        }
    }
    assert_eq!(edited.load(0).unwrap().points, orig.load(0).unwrap().points);
    let jsonl = pi3det_eval::Detections::read(&data.join("labels.edit-002.jsonl")).unwrap();
    assert_eq!(jsonl.frames.len(), 6);
    assert_eq!(jsonl.frames["0000001"][0].name, "Van");
    // Editing the label set again continues its numbering.
    drop(server);
    let again = Running::start(&data.join("pi3det_infos_train.edit-002.pkl"), None);
    let (code, reply) = http(again.addr(), "POST", "/api/save", br#"{"frames":[]}"#);
    assert_eq!(code, 200, "{reply}");
    assert!(data.join("pi3det_infos_train.edit-003.pkl").is_file());
}

#[test]
fn kitti_edits_from_detections_are_written_as_json_lines() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("training");
    copy_tree(&shared("kitti/training"), &data);
    let label = std::fs::read(data.join("label_2/000001.txt")).unwrap();
    let det = dir.path().join("det.jsonl");
    std::fs::write(
        &det,
        r#"{"frame_id": "000001", "names": ["Car"], "scores": [0.7], "boxes_lidar": [[12, 1, -0.9, 4, 1.7, 1.5, 0]]}"#,
    )
    .unwrap();
    let server = Running::start(&data, Some(&det));
    let (_, labels) = http(server.addr(), "GET", "/api/labels", b"");
    let labels: serde_json::Value = serde_json::from_str(&labels).unwrap();
    assert_eq!(labels["frames"][1]["objects"][0]["score"], 0.7, "editing starts from --det");
    assert_eq!(labels["frames"][0]["objects"].as_array().unwrap().len(), 0);
    let body = r#"{"frames":[{"frame_id":"000001","objects":[{"name":"Car","box":[12.5,1,-0.9,4,1.7,1.5,0.05],"score":0.7}]}]}"#;
    let (code, reply) = http(server.addr(), "POST", "/api/save", body.as_bytes());
    assert_eq!(code, 200, "{reply}");
    let d = pi3det_eval::Detections::read(&data.join("labels.edit-001.jsonl")).unwrap();
    assert_eq!(d.frames.len(), 6);
    assert_eq!(d.frames["000001"][0].lidar.unwrap().x, 12.5);
    assert_eq!(std::fs::read(data.join("label_2/000001.txt")).unwrap(), label);
    assert!(!names(&data).iter().any(|n| n.ends_with(".pkl")));
}

#[test]
fn refuses_non_loopback_without_allow_remote() {
    let src = Source::open(&shared("pi3det_sample"), None, Some("0")).unwrap();
    let editor = Editor::new(src, "edit", 1000, ColorBy::Height).unwrap();
    let e = EditServer::bind(editor, "0.0.0.0:0", false).err().unwrap().to_string();
    assert!(e.contains("--allow-remote"), "{e}");
    let src = Source::open(&shared("pi3det_sample"), None, Some("0")).unwrap();
    assert!(Editor::new(src, "../evil", 1000, ColorBy::Height).is_err(), "label-set names go into file names");
}

fn percent_encode(s: &str) -> String {
    s.bytes().map(|b| if b.is_ascii_alphanumeric() { (b as char).to_string() } else { format!("%{b:02X}") }).collect()
}

#[test]
fn an_edit_made_in_the_browser_is_saved_as_a_new_label_set() {
    let Some(chromium) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let data = sample_copy(dir.path());
    let info = data.join("pi3det_infos_train.pkl");
    let original = std::fs::read(&info).unwrap();
    let orig = pi3det_data::open(&data).unwrap();
    let server = Running::start(&data, None);
    // Move, rotate, relabel, add, copy to the next frame, add-undo-redo-delete: the page's own
    // edit path (window.pi3det.applyEdit / undo / redo / save).
    let ops = serde_json::json!([
        {"op": "nudge", "frame": 0, "index": 0, "fields": {"x": 1.0, "heading": 0.1, "dz": 0.2}},
        {"op": "class", "frame": 0, "index": 0, "name": "Van"},
        {"op": "add", "frame": 0, "object": {"name": "Cyclist", "box": [5, 5, -1, 1.8, 0.6, 1.7, 0.3]}},
        {"op": "copy_next", "frame": 0, "index": 0},
        {"op": "add", "frame": 0, "object": {"name": "Junk", "box": [0, 0, 0, 1, 1, 1, 0]}},
        {"op": "undo"},
        {"op": "redo"},
        {"op": "delete", "frame": 0, "index": 2},
    ]);
    let url = format!("http://{}/?save=1&ops={}", server.addr(), percent_encode(&ops.to_string()));
    let (dom, took) = dump_dom(&chromium, &url, 30_000);
    let s = status(&dom);
    assert_eq!(s.get("selftest").map(String::as_str), Some("done"), "{s:?}");
    assert_eq!(s["saved"], "1", "{s:?}");
    assert_eq!(s["points"], "115384");
    eprintln!("editor page: loaded, edited and saved in {:.2} s of headless Chromium", took.as_secs_f64());

    assert_eq!(std::fs::read(&info).unwrap(), original, "the original info file is byte-identical");
    let edited = pi3det_data::open(&data.join("pi3det_infos_train.edit-001.pkl")).unwrap();
    let o0 = &orig.info(0).unwrap().objects[0];
    let f0 = edited.info(0).unwrap().objects;
    assert_eq!(f0.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["Van", "Cyclist"]);
    let mut want = o0.box3d.to_array();
    want[0] += 1.0;
    want[6] += 0.1;
    want[5] += 0.2;
    assert!(close(f0[0].box3d.to_array(), want), "{:?} vs {want:?}", f0[0].box3d);
    assert_eq!(f0[0].num_points, None, "a moved box is no longer counted");
    assert!(close(f0[1].box3d.to_array(), [5., 5., -1., 1.8, 0.6, 1.7, 0.3]));
    let (f1, o1) = (edited.info(1).unwrap().objects, orig.info(1).unwrap().objects);
    assert_eq!(f1.len(), o1.len() + 1);
    assert_eq!(&f1[..o1.len()], &o1[..]);
    assert_eq!(f1[o1.len()].name, "Van");
    assert!(close(f1[o1.len()].box3d.to_array(), want));
    for i in 2..6 {
        assert_eq!(edited.info(i).unwrap().objects, orig.info(i).unwrap().objects);
    }
    let jsonl = pi3det_eval::Detections::read(&data.join("labels.edit-001.jsonl")).unwrap();
    assert_eq!(jsonl.frames["0000000"].len(), 2);
}

/// The keyboard shortcuts drive the same edits: move, rotate, resize, add + undo, copy to the
/// next frame.
#[test]
fn keyboard_shortcuts_edit_the_selected_box() {
    let Some(chromium) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let data = sample_copy(dir.path());
    let orig = pi3det_data::open(&data).unwrap();
    let server = Running::start(&data, None);
    let ops = serde_json::json!([
        {"op": "select", "index": 0},
        {"op": "key", "code": "KeyW"},
        {"op": "key", "code": "KeyW", "shift": true},
        {"op": "key", "code": "KeyQ"},
        {"op": "key", "code": "BracketRight"},
        {"op": "key", "code": "KeyR"},
        {"op": "key", "code": "KeyN"},
        {"op": "key", "code": "KeyZ", "ctrl": true},
        {"op": "key", "code": "KeyC"},
    ]);
    let url = format!("http://{}/?save=1&ops={}", server.addr(), percent_encode(&ops.to_string()));
    let (dom, _) = dump_dom(&chromium, &url, 30_000);
    let s = status(&dom);
    assert_eq!(
        (s.get("selftest").map(String::as_str), s.get("saved").map(String::as_str)),
        (Some("done"), Some("1")),
        "{s:?}"
    );
    let edited = pi3det_data::open(&data.join("pi3det_infos_train.edit-001.pkl")).unwrap();
    let f0 = edited.info(0).unwrap().objects;
    assert_eq!(f0.len(), 1, "N added a box, Ctrl+Z took it back");
    let mut want = orig.info(0).unwrap().objects[0].box3d.to_array();
    want[0] += 1.1;
    want[2] += 0.1;
    want[3] += 0.1;
    want[6] += std::f64::consts::PI / 180.0;
    assert!(close(f0[0].box3d.to_array(), want), "{:?} vs {want:?}", f0[0].box3d);
    let f1 = edited.info(1).unwrap().objects;
    assert_eq!(f1.len(), orig.info(1).unwrap().objects.len() + 1, "C copied the box to the next frame");
    assert!(close(f1.last().unwrap().box3d.to_array(), want));
}
