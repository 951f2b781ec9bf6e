//! Helpers of the viewer's integration tests: headless Chromium, the status element, a bare
//! HTTP client and copies of the shared test data.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

pub fn shared(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel)
}

/// Chromium, or `None` after printing why the browser part of a test is skipped.
pub fn chromium() -> Option<PathBuf> {
    // PI3DET_CHROMIUM names the browser (a path that does not exist skips the browser tests).
    let candidates: Vec<PathBuf> = match std::env::var_os("PI3DET_CHROMIUM") {
        Some(p) => vec![PathBuf::from(p)],
        None => ["/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome"].map(PathBuf::from).into(),
    };
    for c in candidates {
        if c.is_file() {
            return Some(c);
        }
    }
    eprintln!("skipped: chromium not found (run scripts/setup-chromium, or set PI3DET_CHROMIUM)");
    None
}

/// Loads `url` in headless Chromium with software WebGL and returns the DOM once the page is
/// idle (`budget_ms` of virtual time), and the wall time the browser took.
pub fn dump_dom(chromium: &Path, url: &str, budget_ms: u32) -> (String, Duration) {
    dump_dom_with(chromium, url, budget_ms, &[])
}

/// [`dump_dom`] with extra browser flags.
pub fn dump_dom_with(chromium: &Path, url: &str, budget_ms: u32, extra: &[&str]) -> (String, Duration) {
    let profile = tempfile::tempdir().unwrap();
    let t = Instant::now();
    let out = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--disable-extensions",
            "--window-size=1280,800",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .args(extra)
        .arg(format!("--virtual-time-budget={budget_ms}"))
        .arg("--dump-dom")
        .arg(url)
        .output()
        .expect("running chromium");
    let took = t.elapsed();
    assert!(out.status.success(), "chromium failed: {}", String::from_utf8_lossy(&out.stderr));
    (String::from_utf8_lossy(&out.stdout).into_owned(), took)
}

/// The attributes of `<div id="status" …>` in a dumped DOM (`data-points` → `points`).
pub fn status(dom: &str) -> BTreeMap<String, String> {
    let start = dom.find("<div id=\"status\"").unwrap_or_else(|| panic!("no status element in:\n{dom:.2000}"));
    let tag = &dom[start..start + dom[start..].find('>').unwrap()];
    let mut out = BTreeMap::new();
    let mut rest = tag;
    while let Some(i) = rest.find(" data-") {
        rest = &rest[i + 6..];
        let eq = rest.find("=\"").unwrap();
        let key = rest[..eq].to_string();
        rest = &rest[eq + 2..];
        let end = rest.find('"').unwrap();
        out.insert(key, rest[..end].replace("&amp;", "&").replace("&quot;", "\""));
        rest = &rest[end + 1..];
    }
    out
}

/// One HTTP/1.0 request (no chunked replies) over a plain socket; returns the status code and body.
pub fn http(addr: SocketAddr, method: &str, path: &str, body: &[u8]) -> (u16, String) {
    http_with(addr, method, path, body, &format!("Host: {addr}\r\nContent-Type: application/json\r\n"))
}

/// [`http`] with the given header lines (each ending in CRLF) instead of Host and Content-Type.
pub fn http_with(addr: SocketAddr, method: &str, path: &str, body: &[u8], headers: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let head =
        format!("{method} {path} HTTP/1.0\r\n{headers}Connection: close\r\nContent-Length: {}\r\n\r\n", body.len());
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    let mut resp = Vec::new();
    s.read_to_end(&mut resp).unwrap();
    let text = String::from_utf8_lossy(&resp).into_owned();
    let code = text.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let body = text.split_once("\r\n\r\n").map(|(_, b)| b.to_string()).unwrap_or_default();
    (code, body)
}

/// Copies a folder tree (test data is edited only in copies).
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), &dst).unwrap();
            // The shared data is read-only; the copies must be writable for the temp dir to go.
            let mut p = std::fs::metadata(&dst).unwrap().permissions();
            #[allow(clippy::permissions_set_readonly_false)]
            p.set_readonly(false);
            std::fs::set_permissions(&dst, p).unwrap();
        }
    }
}

/// File names in a folder, sorted.
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}
