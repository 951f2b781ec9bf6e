//! Where sweeps come from. A source pushes each sweep to the runner as it is complete
//! ([`Source::run`]); live sources never wait for inference (the runner's queue drops the oldest
//! sweep instead), recorded ones may ([`Source::is_live`]).
//!
//! Addresses (`pi3det run --source …`):
//! - `ouster-udp://HOST:PORT?metadata=FILE[&timeout_s=S][&min_coverage=F]`: lidar packets
//!   on a UDP port, the sensor's metadata JSON for the layout ([`ouster_udp`]);
//! - `mcap://BAG.mcap[?topic=/points][&rate=HZ]`: `sensor_msgs/msg/PointCloud2` messages of a
//!   ROS 2 bag ([`mcap_bag`]); a bare `*.mcap` path works too;
//! - `dataset://DIR[?split=val][&rate=HZ]` or a bare folder: frames of any dataset `pi3det`
//!   reads ([`dataset`]).
//!
//! `rate` paces a recorded source like a sensor (that many sweeps per second, dropped when
//! inference falls behind, as live); without it every sweep is processed, in order.

pub mod dataset;
pub mod mcap_bag;
pub mod ouster_udp;
pub mod pointcloud2;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use pi3det_data::Frame;

use crate::error::{LiveError, Result};

/// One sweep, with when it was complete on this machine (the start of its latency).
#[derive(Debug, Clone)]
pub struct LiveFrame {
    pub frame: Frame,
    /// The sweep's own time (sensor or recording clock), ns.
    pub stamp_ns: u64,
    pub arrived: Instant,
}

/// What the receiver of a sweep wants next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Continue,
    Stop,
}

/// What a source counted (packets, drops, …), reported at the end of a run.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct SourceReport {
    pub sweeps: u64,
    pub counters: BTreeMap<String, u64>,
}

impl SourceReport {
    pub fn add(&mut self, name: &str, n: u64) {
        *self.counters.entry(name.to_string()).or_default() += n;
    }

    pub fn get(&self, name: &str) -> u64 {
        self.counters.get(name).copied().unwrap_or(0)
    }
}

impl std::fmt::Display for SourceReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} sweeps", self.sweeps)?;
        for (k, v) in &self.counters {
            if *v > 0 {
                write!(f, ", {k} {v}")?;
            }
        }
        Ok(())
    }
}

pub trait Source: Send {
    /// What is being read, for messages.
    fn describe(&self) -> String;
    /// Whether the data arrives whether or not we are ready (sweeps are then dropped, not
    /// waited for, when inference falls behind).
    fn is_live(&self) -> bool;
    /// Produces sweeps until the stream ends, `emit` answers [`Flow::Stop`] or `stop` is set
    /// (checked at least every few hundred milliseconds, with or without data).
    fn run(&mut self, emit: &mut dyn FnMut(LiveFrame) -> Flow, stop: &AtomicBool) -> Result<SourceReport>;
}

/// A parsed `--source` address.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceSpec {
    OusterUdp(ouster_udp::UdpOptions),
    Mcap { path: PathBuf, topic: Option<String>, rate_hz: Option<f64> },
    Dataset { path: PathBuf, split: Option<String>, rate_hz: Option<f64> },
}

/// `scheme://rest?k=v&…` → (scheme, rest, query). No scheme: `("", whole, {})`.
pub(crate) fn split_uri(uri: &str) -> Result<(&str, &str, BTreeMap<String, String>)> {
    let (scheme, rest) = match uri.split_once("://") {
        Some((s, r)) => (s, r),
        None => return Ok(("", uri, BTreeMap::new())),
    };
    let (body, query) = rest.split_once('?').unwrap_or((rest, ""));
    let mut params = BTreeMap::new();
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').ok_or_else(|| LiveError::uri(uri, format!("'{pair}' is not key=value")))?;
        if params.insert(k.to_string(), v.to_string()).is_some() {
            return Err(LiveError::uri(uri, format!("'{k}' given twice")));
        }
    }
    Ok((scheme, body, params))
}

/// Takes `key` from `params` as a finite number > 0 (or ≥ 0 with `allow_zero`).
pub(crate) fn take_number(
    uri: &str,
    params: &mut BTreeMap<String, String>,
    key: &str,
    allow_zero: bool,
) -> Result<Option<f64>> {
    let Some(v) = params.remove(key) else { return Ok(None) };
    match v.parse::<f64>() {
        Ok(x) if x.is_finite() && (x > 0.0 || (allow_zero && x == 0.0)) => Ok(Some(x)),
        _ => Err(LiveError::uri(uri, format!("{key}={v}: expected a positive number"))),
    }
}

pub(crate) fn refuse_unknown(uri: &str, params: &BTreeMap<String, String>, known: &[&str]) -> Result<()> {
    match params.keys().next() {
        Some(k) => Err(LiveError::uri(uri, format!("unknown parameter '{k}' (known: {})", known.join(", ")))),
        None => Ok(()),
    }
}

impl std::str::FromStr for SourceSpec {
    type Err = LiveError;

    fn from_str(uri: &str) -> Result<Self> {
        let (scheme, body, mut params) = split_uri(uri)?;
        match scheme {
            "ouster-udp" => {
                let addr: SocketAddr = body
                    .parse()
                    .map_err(|_| LiveError::uri(uri, format!("'{body}' is not HOST:PORT (an IP address)")))?;
                let metadata = params
                    .remove("metadata")
                    .ok_or_else(|| LiveError::uri(uri, "needs ?metadata=FILE (the sensor's metadata JSON)"))?;
                let mut o = ouster_udp::UdpOptions::new(addr, PathBuf::from(metadata));
                if let Some(t) = take_number(uri, &mut params, "timeout_s", false)? {
                    o.timeout_s = Some(t);
                }
                if let Some(c) = take_number(uri, &mut params, "min_coverage", true)? {
                    if c > 1.0 {
                        return Err(LiveError::uri(uri, "min_coverage is a fraction of the sweep's packets (0–1)"));
                    }
                    o.min_coverage = c;
                }
                refuse_unknown(uri, &params, &["metadata", "timeout_s", "min_coverage"])?;
                Ok(Self::OusterUdp(o))
            }
            "mcap" => {
                let topic = params.remove("topic");
                let rate_hz = take_number(uri, &mut params, "rate", false)?;
                refuse_unknown(uri, &params, &["topic", "rate"])?;
                Ok(Self::Mcap { path: PathBuf::from(body), topic, rate_hz })
            }
            "dataset" => {
                let split = params.remove("split");
                let rate_hz = take_number(uri, &mut params, "rate", false)?;
                refuse_unknown(uri, &params, &["split", "rate"])?;
                Ok(Self::Dataset { path: PathBuf::from(body), split, rate_hz })
            }
            "" if body.ends_with(".mcap") => Ok(Self::Mcap { path: PathBuf::from(body), topic: None, rate_hz: None }),
            "" => Ok(Self::Dataset { path: PathBuf::from(body), split: None, rate_hz: None }),
            other => Err(LiveError::uri(uri, format!("unknown source '{other}://' (ouster-udp, mcap, dataset)"))),
        }
    }
}

/// Opens a UDP or MCAP source. Dataset sources are opened by the caller (it knows how to open
/// a split: [`dataset::DatasetSource::new`]).
pub fn open_source(spec: &SourceSpec) -> Result<Box<dyn Source>> {
    match spec {
        SourceSpec::OusterUdp(o) => Ok(Box::new(ouster_udp::UdpSource::open(o)?)),
        SourceSpec::Mcap { path, topic, rate_hz } => {
            Ok(Box::new(mcap_bag::McapSource::open(path, topic.as_deref(), *rate_hz)?))
        }
        SourceSpec::Dataset { path, .. } => Err(LiveError::uri(
            path.display().to_string(),
            "dataset sources are opened with DatasetSource::new (they need the caller's split)",
        )),
    }
}

/// Sleeps until `start + k / rate_hz` (pacing a recorded source).
pub(crate) fn pace(start: Instant, k: u64, rate_hz: Option<f64>) {
    if let Some(r) = rate_hz {
        let due = start + std::time::Duration::from_secs_f64(k as f64 / r);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        let s: SourceSpec = "ouster-udp://127.0.0.1:7502?metadata=m.json&timeout_s=2".parse().unwrap();
        match s {
            SourceSpec::OusterUdp(o) => {
                assert_eq!(o.addr.port(), 7502);
                assert_eq!(o.metadata, PathBuf::from("m.json"));
                assert_eq!(o.timeout_s, Some(2.0));
            }
            other => panic!("{other:?}"),
        }
        let s: SourceSpec = "mcap://bag.mcap?topic=/points&rate=10".parse().unwrap();
        assert_eq!(s, SourceSpec::Mcap { path: "bag.mcap".into(), topic: Some("/points".into()), rate_hz: Some(10.0) });
        let s: SourceSpec = "runs/x/bag.mcap".parse().unwrap();
        assert!(matches!(s, SourceSpec::Mcap { topic: None, .. }));
        let s: SourceSpec = "data/vehicle".parse().unwrap();
        assert!(matches!(s, SourceSpec::Dataset { split: None, rate_hz: None, .. }));
    }

    #[test]
    fn bad_addresses_say_what_is_wrong() {
        for (uri, needle) in [
            ("ouster-udp://localhost:7502?metadata=m.json", "HOST:PORT"),
            ("ouster-udp://127.0.0.1:7502", "metadata"),
            ("ouster-udp://127.0.0.1:7502?metadata=m&min_coverage=2", "fraction"),
            ("mcap://b.mcap?rate=-1", "positive"),
            ("mcap://b.mcap?topics=/x", "unknown parameter 'topics'"),
            ("mcap://b.mcap?topic", "key=value"),
            ("kafka://x", "unknown source"),
        ] {
            let e = uri.parse::<SourceSpec>().unwrap_err().to_string();
            assert!(e.contains(needle), "{uri}: {e}");
        }
    }
}
