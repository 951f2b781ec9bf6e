//! `pi3det annotate`'s HTTP side: the viewer page in edit mode, points and labels on request,
//! and saving corrected labels as a new label set. One request at a time (one annotator), on
//! loopback unless asked otherwise.

use std::io::Read;
use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::Mutex;

use serde::Deserialize;

use crate::error::ViewerError;
use crate::labels::{LabelSetWriter, SavedSet};
use crate::page::render;
use crate::scene::{ColorBy, LabelBox, Scene, SceneFrame, Source};

/// Save requests larger than this are refused (a label set is kilobytes to a few megabytes).
const MAX_BODY: u64 = 64 << 20;

/// A save request: the corrected objects of some frames (frames left out keep their labels).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SaveRequest {
    pub frames: Vec<FrameEdit>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameEdit {
    pub frame_id: String,
    pub objects: Vec<LabelBox>,
}

/// What [`Editor::handle`] looks at in a request.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Request {
    pub method: String,
    pub url: String,
    pub content_type: Option<String>,
    pub origin: Option<String>,
    pub host: Option<String>,
}

impl Request {
    /// A JSON request as the page sends it.
    pub fn json(method: &str, url: &str) -> Self {
        Self {
            method: method.into(),
            url: url.into(),
            content_type: Some("application/json".into()),
            ..Self::default()
        }
    }
}

fn is_loopback_host(host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(""),
        None => host.rsplit_once(':').map_or(host, |(h, _)| h),
    };
    name.eq_ignore_ascii_case("localhost") || name.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// Another web site open in the same browser could otherwise post edits to the loopback
/// server: a JSON content type forces the browser's CORS preflight (which this server never
/// grants), and an Origin, when sent, must be the page's own.
fn refuse_cross_site(req: &Request) -> Option<Reply> {
    let json =
        req.content_type.as_deref().is_some_and(|c| c.trim().to_ascii_lowercase().starts_with("application/json"));
    if !json {
        return Some(Reply::error(415, "edits must be sent as Content-Type: application/json"));
    }
    if let (Some(origin), Some(host)) = (&req.origin, &req.host) {
        if origin != &format!("http://{host}") {
            return Some(Reply::error(403, format!("request from another origin ({origin})")));
        }
    }
    None
}

/// An HTTP answer before it is sent.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    pub status: u16,
    pub content_type: &'static str,
    pub body: Vec<u8>,
}

impl Reply {
    fn json(status: u16, v: &serde_json::Value) -> Self {
        Self { status, content_type: "application/json", body: v.to_string().into_bytes() }
    }
    fn error(status: u16, message: impl Into<String>) -> Self {
        Self::json(status, &serde_json::json!({ "error": message.into() }))
    }
}

/// The editing state: the dataset, the labels being corrected and where saves go.
pub struct Editor {
    src: Source,
    writer: LabelSetWriter,
    max_points: usize,
    color: ColorBy,
    /// Current labels of every dataset frame (from the ground truth, or from `--det`).
    labels: Vec<Vec<LabelBox>>,
    set: String,
    /// Refuse requests whose Host is not a loopback name (unless serving with --allow-remote).
    loopback_only: bool,
}

impl Editor {
    pub fn new(src: Source, set: &str, max_points: usize, color: ColorBy) -> Result<Self, ViewerError> {
        let writer = LabelSetWriter::new(&src, set)?;
        let labels = if src.has_dets { src.dets.clone() } else { (0..src.infos.len()).map(|i| src.gt(i)).collect() };
        Ok(Self { src, writer, max_points, color, labels, set: set.to_string(), loopback_only: true })
    }

    pub fn writer(&self) -> &LabelSetWriter {
        &self.writer
    }

    /// The page: frame list and reference boxes (the ground truth when editing detections);
    /// points and editable labels are fetched.
    pub fn page(&self) -> String {
        let frames = self
            .src
            .shown
            .clone()
            .map(|i| SceneFrame {
                index: i,
                id: self.src.infos[i].id.clone(),
                points: None,
                gt: if self.src.has_dets { self.src.gt(i) } else { Vec::new() },
                det: Vec::new(),
            })
            .collect();
        render(&Scene { title: self.src.title(), mode: "edit", color: self.color, frames })
    }

    fn labels_json(&self) -> serde_json::Value {
        let frames: Vec<_> = self
            .src
            .shown
            .clone()
            .map(|i| serde_json::json!({ "frame_id": self.src.infos[i].id, "objects": self.labels[i] }))
            .collect();
        serde_json::json!({ "label_set": self.set, "frames": frames })
    }

    /// Answers one request; never panics on what the client sends.
    pub fn handle(&mut self, req: &Request, body: &[u8]) -> Reply {
        let path = req.url.split('?').next().unwrap_or("");
        if self.loopback_only && !req.host.as_deref().is_none_or(is_loopback_host) {
            // A DNS-rebound name pointing at 127.0.0.1 would otherwise pass as same-origin.
            return Reply::error(403, format!("Host {:?} is not a loopback name", req.host.as_deref().unwrap_or("")));
        }
        if req.method == "POST" {
            if let Some(refusal) = refuse_cross_site(req) {
                return refusal;
            }
        }
        match (req.method.as_str(), path) {
            ("GET", "/" | "/index.html") => {
                Reply { status: 200, content_type: "text/html; charset=utf-8", body: self.page().into_bytes() }
            }
            ("GET", "/api/labels") => Reply::json(200, &self.labels_json()),
            ("GET", p) if p.starts_with("/api/points/") => {
                let idx = p["/api/points/".len()..].parse::<usize>().ok().filter(|i| self.src.shown.contains(i));
                let Some(i) = idx else { return Reply::error(404, format!("no shown frame {p:?}")) };
                match self.src.points(i, self.max_points) {
                    Ok(pts) => Reply::json(200, &serde_json::to_value(pts).unwrap_or_default()),
                    Err(e) => Reply::error(500, e.to_string()),
                }
            }
            ("POST", "/api/save") => match self.save(body) {
                Ok(saved) => Reply::json(200, &serde_json::to_value(saved).unwrap_or_default()),
                Err((status, m)) => Reply::error(status, m),
            },
            (_, "/" | "/index.html" | "/api/labels" | "/api/save") => Reply::error(405, "method not allowed"),
            _ => Reply::error(404, format!("not found: {path}")),
        }
    }

    /// Checks the whole request, writes the new label set, and only then takes the edits.
    fn save(&mut self, body: &[u8]) -> Result<SavedSet, (u16, String)> {
        let req: SaveRequest = serde_json::from_slice(body).map_err(|e| (400, format!("bad save request: {e}")))?;
        let mut labels = self.labels.clone();
        let mut seen = std::collections::HashSet::new();
        for f in &req.frames {
            let Some(i) = self.src.infos.iter().position(|x| x.id == f.frame_id) else {
                return Err((400, format!("unknown frame {:?}", f.frame_id)));
            };
            if !seen.insert(i) {
                return Err((400, format!("frame {:?} given twice", f.frame_id)));
            }
            for (k, o) in f.objects.iter().enumerate() {
                o.to_object().map_err(|m| (400, format!("frame {} object {k}: {m}", f.frame_id)))?;
            }
            labels[i] = f.objects.clone();
        }
        let infos: Vec<_> = self
            .src
            .infos
            .iter()
            .zip(&labels)
            .map(|(info, objs)| {
                let mut info = info.clone();
                // Checked above or loaded from checked data.
                info.objects = objs.iter().filter_map(|o| o.to_object().ok()).collect();
                info
            })
            .collect();
        let saved = self.writer.save(&infos).map_err(|e| (500, e.to_string()))?;
        tracing::info!("saved label set {} version {}: {:?}", self.set, saved.version, saved.files);
        self.labels = labels;
        Ok(saved)
    }
}

/// The editor behind a tiny_http server.
pub struct EditServer {
    http: tiny_http::Server,
    addr: SocketAddr,
    editor: Mutex<Editor>,
}

/// Resolves `listen`; a non-loopback address needs `allow_remote` (the editor has no login).
pub fn resolve_listen(listen: &str, allow_remote: bool) -> Result<SocketAddr, ViewerError> {
    let err = |m: String| ViewerError::Listen { addr: listen.to_string(), message: m };
    let addrs: Vec<SocketAddr> = listen.to_socket_addrs().map_err(|e| err(e.to_string()))?.collect();
    let addr = *addrs.first().ok_or_else(|| err("resolves to no address".into()))?;
    if !allow_remote && !addrs.iter().all(|a| a.ip().is_loopback()) {
        return Err(err(
            "not a loopback address; anyone who can reach it could edit the labels (pass --allow-remote to accept)"
                .into(),
        ));
    }
    Ok(addr)
}

impl EditServer {
    pub fn bind(mut editor: Editor, listen: &str, allow_remote: bool) -> Result<Self, ViewerError> {
        let addr = resolve_listen(listen, allow_remote)?;
        editor.loopback_only = !allow_remote;
        let http = tiny_http::Server::http(addr)
            .map_err(|e| ViewerError::Listen { addr: listen.to_string(), message: e.to_string() })?;
        let addr = http.server_addr().to_ip().unwrap_or(addr);
        Ok(Self { http, addr, editor: Mutex::new(editor) })
    }

    /// The bound address (the actual port when asked for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Serves until [`EditServer::unblock`].
    pub fn run(&self) {
        for mut req in self.http.incoming_requests() {
            let mut body = Vec::new();
            let reply = match req.as_reader().take(MAX_BODY + 1).read_to_end(&mut body) {
                Err(e) => Reply::error(400, format!("reading the request: {e}")),
                Ok(_) if body.len() as u64 > MAX_BODY => Reply::error(413, "request too large"),
                Ok(_) => {
                    let header = |name: &'static str| {
                        req.headers().iter().find(|h| h.field.equiv(name)).map(|h| h.value.as_str().to_string())
                    };
                    let r = Request {
                        method: req.method().as_str().to_string(),
                        url: req.url().to_string(),
                        content_type: header("Content-Type"),
                        origin: header("Origin"),
                        host: header("Host"),
                    };
                    let mut ed = self.editor.lock().unwrap_or_else(|p| p.into_inner());
                    ed.handle(&r, &body)
                }
            };
            let header = |k: &str, v: &str| tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()).ok();
            let mut resp = tiny_http::Response::from_data(reply.body).with_status_code(reply.status);
            for h in
                [header("Content-Type", reply.content_type), header("Cache-Control", "no-store")].into_iter().flatten()
            {
                resp.add_header(h);
            }
            if let Err(e) = req.respond(resp) {
                tracing::warn!("answering a request: {e}");
            }
        }
    }

    pub fn unblock(&self) {
        self.http.unblock();
    }
}

#[cfg(test)]
mod tests {
    use super::is_loopback_host;

    #[test]
    fn loopback_hosts() {
        for h in ["127.0.0.1:8080", "localhost:1", "LOCALHOST", "[::1]:80", "127.3.4.5"] {
            assert!(is_loopback_host(h), "{h}");
        }
        for h in ["evil.example:8080", "10.0.0.1:80", "[2001:db8::1]:80", ""] {
            assert!(!is_loopback_host(h), "{h}");
        }
    }
}
