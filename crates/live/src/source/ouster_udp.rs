//! Live Ouster lidar packets over UDP, assembled into sweeps.
//!
//! Each datagram must be one lidar packet of the layout the metadata gives, exactly as the
//! sensor sends it (other sizes are counted as `garbage`; the pad byte ouster-ros 0.x stored
//! after each packet in recordings is never on the wire — `replay::sequence_datagrams` strips
//! it when a recording is replayed). A packet belongs to the sweep of its frame id and fills the slot of
//! its first measurement id. The assembly rule:
//! - a sweep is emitted as soon as all its packets have arrived (`complete`);
//! - a packet of another frame id ends the pending sweep: it is emitted if at least
//!   `min_coverage` of its packets arrived (`partial`, missing columns have no points), otherwise
//!   dropped (`dropped_partial`); the same happens after `idle` without packets;
//! - a packet of a sweep already ended (one of the last two), older than the newest packet
//!   seen, is dropped (`late`); one whose slot is filled is dropped (`duplicate`). Half a sweep
//!   of such packets in a row is a new stream instead (a restarted sensor whose clock began
//!   again), taken as it comes;
//! - frame ids are 16-bit: 65535 → 0 is the next sweep (`wraps`); a jump forward counts the
//!   sweeps never seen (`lost_sweeps`); a jump back that is not a wrap is a sensor restart
//!   (`restarts`): the new stream is taken as it comes.

use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use pi3det_data::{Frame, FrameInfo};
use pi3det_sequence::dataset::{sweep_points_cloud, sweep_start_ns};
use pi3det_sequence::ouster::{PacketFormat, SensorMetadata, Sweep, XyzLut};

use super::{Flow, LiveFrame, Source, SourceReport};
use crate::error::{LiveError, Result};

#[derive(Debug, Clone, PartialEq)]
pub struct UdpOptions {
    pub addr: SocketAddr,
    pub metadata: PathBuf,
    /// End the stream after this long without a packet (`None`: run until stopped).
    pub timeout_s: Option<f64>,
    /// Fraction of a sweep's packets needed to emit it when it ends incomplete.
    pub min_coverage: f64,
    /// A pending sweep is ended after this long without packets.
    pub idle: Duration,
}

impl UdpOptions {
    pub fn new(addr: SocketAddr, metadata: PathBuf) -> Self {
        Self { addr, metadata, timeout_s: None, min_coverage: 0.75, idle: Duration::from_millis(150) }
    }
}

/// Reads and checks a sensor metadata file.
pub fn read_metadata(path: &Path) -> Result<SensorMetadata> {
    let text = std::fs::read_to_string(path).map_err(|e| LiveError::io(path, e))?;
    Ok(SensorMetadata::parse(path, &text)?)
}

/// A sweep the assembler finished: its packets (those that arrived, concatenated) and frame id.
#[derive(Debug, Clone, PartialEq)]
pub struct AssembledSweep {
    pub frame_id: u16,
    pub packets: Vec<u8>,
    pub received: usize,
    pub expected: usize,
}

struct Pending {
    frame_id: u16,
    filled: Vec<bool>,
    received: usize,
    packets: Vec<u8>,
}

/// Packets → sweeps by the rule in the module doc; no I/O, so it is tested packet by packet.
pub struct Assembler {
    format: PacketFormat,
    per_sweep: usize,
    min_coverage: f64,
    pending: Option<Pending>,
    /// Frame ids of the sweeps ended last (for telling late packets from new sweeps).
    ended: [Option<u16>; 2],
    /// The newest column timestamp accepted (ns).
    newest_ns: u64,
    /// Late packets in a row.
    late_run: usize,
    pub report: SourceReport,
}

/// Frame ids within this distance of the 16-bit limit count as a wrap, not a restart.
const WRAP_WINDOW: u16 = 64;

impl Assembler {
    pub fn new(md: &SensorMetadata, min_coverage: f64) -> Self {
        let format = PacketFormat::new(md);
        let per_sweep = md.packets_per_frame();
        Self {
            format,
            per_sweep,
            min_coverage,
            pending: None,
            ended: [None; 2],
            newest_ns: 0,
            late_run: 0,
            report: SourceReport::default(),
        }
    }

    pub fn packet_bytes(&self) -> usize {
        self.format.packet_bytes()
    }

    pub fn format(&self) -> &PacketFormat {
        &self.format
    }

    /// Feeds one datagram; returns the sweep it completed or ended, if any (at most one: a
    /// packet ends the pending sweep, or completes its own, never both).
    pub fn push(&mut self, datagram: &[u8]) -> Option<AssembledSweep> {
        self.report.add("packets", 1);
        let Some((frame_id, m, ts)) = self.format.packet_ids(datagram) else {
            self.report.add("garbage", 1);
            return None;
        };
        let cpp = self.format.columns_per_packet;
        let slot = m as usize / cpp.max(1);
        if !(m as usize).is_multiple_of(cpp.max(1)) || slot >= self.per_sweep {
            self.report.add("garbage", 1);
            return None;
        }
        let mut out = None;
        let pending_id = self.pending.as_ref().map(|p| p.frame_id);
        if pending_id != Some(frame_id) {
            if self.ended.contains(&Some(frame_id)) && ts <= self.newest_ns {
                self.late_run += 1;
                if self.late_run <= self.per_sweep / 2 {
                    self.report.add("late", 1);
                    return None;
                }
                // Not late: a new stream reusing recent ids (a restart with a fresh clock).
                self.ended = [None; 2];
                self.newest_ns = 0;
            }
            match pending_id {
                Some(id) => {
                    self.count_jump(id, frame_id);
                    out = self.end_pending();
                }
                None => {
                    if let Some(last) = self.ended[0] {
                        self.count_jump(last, frame_id);
                    }
                }
            }
        }
        self.late_run = 0;
        self.newest_ns = self.newest_ns.max(ts);
        let bytes = self.format.packet_bytes();
        let per_sweep = self.per_sweep;
        let p = self.pending.get_or_insert_with(|| Pending {
            frame_id,
            filled: vec![false; per_sweep],
            received: 0,
            packets: Vec::with_capacity(per_sweep * bytes),
        });
        if p.filled[slot] {
            self.report.add("duplicate", 1);
            return out;
        }
        p.filled[slot] = true;
        p.received += 1;
        p.packets.extend_from_slice(datagram);
        if p.received == self.per_sweep {
            debug_assert!(out.is_none());
            self.report.add("complete", 1);
            return self.finish_pending();
        }
        out
    }

    fn count_jump(&mut self, from: u16, to: u16) {
        let next = from.wrapping_add(1);
        if to == next {
            if to == 0 {
                self.report.add("wraps", 1);
            }
        } else if to > from {
            self.report.add("lost_sweeps", u64::from(to - from - 1));
        } else if from >= u16::MAX - WRAP_WINDOW && to < WRAP_WINDOW {
            self.report.add("wraps", 1);
            self.report.add("lost_sweeps", u64::from(to.wrapping_sub(next)));
        } else {
            self.report.add("restarts", 1);
        }
    }

    fn finish_pending(&mut self) -> Option<AssembledSweep> {
        let p = self.pending.take()?;
        self.ended = [Some(p.frame_id), self.ended[0]];
        Some(AssembledSweep {
            frame_id: p.frame_id,
            packets: p.packets,
            received: p.received,
            expected: self.per_sweep,
        })
    }

    /// Ends the pending sweep early (another frame began, or the stream went quiet): emitted
    /// when it has `min_coverage` of its packets, else dropped.
    pub fn end_pending(&mut self) -> Option<AssembledSweep> {
        let p = self.pending.as_ref()?;
        if p.received as f64 >= self.min_coverage * self.per_sweep as f64 && p.received > 0 {
            self.report.add("partial", 1);
            self.finish_pending()
        } else {
            self.report.add("dropped_partial", 1);
            self.finish_pending();
            None
        }
    }
}

/// Receive buffer asked for (the kernel caps it at `net.core.rmem_max`; Ouster recommends raising
/// that on the host): about ten OS1-64 sweeps.
const RECV_BUFFER_BYTES: usize = 8 << 20;

fn bind(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    use socket2::{Domain, Protocol, Socket, Type};
    let s = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))?;
    if let Err(e) = s.set_recv_buffer_size(RECV_BUFFER_BYTES) {
        tracing::warn!("ouster-udp://{addr}: cannot enlarge the receive buffer ({e}); bursts may lose packets");
    }
    match s.recv_buffer_size() {
        Ok(n) if n < 1 << 20 => tracing::warn!(
            "ouster-udp://{addr}: receive buffer {n} bytes (capped by net.core.rmem_max): a stall of the receiving thread may lose packets"
        ),
        _ => {}
    }
    s.bind(&addr.into())?;
    Ok(s.into())
}

/// Listens on a UDP port; sweeps are decoded on this thread as they complete.
pub struct UdpSource {
    options: UdpOptions,
    socket: UdpSocket,
    assembler: Assembler,
    lut: XyzLut,
    sweep: Sweep,
}

impl UdpSource {
    pub fn open(options: &UdpOptions) -> Result<Self> {
        let md = read_metadata(&options.metadata)?;
        let socket = bind(options.addr)
            .map_err(|e| LiveError::uri(format!("ouster-udp://{}", options.addr), format!("cannot listen: {e}")))?;
        Ok(Self {
            assembler: Assembler::new(&md, options.min_coverage),
            lut: XyzLut::new(&md),
            sweep: Sweep::default(),
            socket,
            options: options.clone(),
        })
    }

    /// The address actually bound (port 0 picks a free one).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.local_addr().ok()
    }

    fn decode_frame(&mut self, s: &AssembledSweep, n: u64) -> Result<LiveFrame> {
        self.assembler.format().decode(&s.packets, &mut self.sweep);
        let points = sweep_points_cloud(&self.lut, &self.sweep)?;
        let stamp_ns = sweep_start_ns(&self.sweep).unwrap_or(0);
        let mut info = FrameInfo::new(format!("{n:06}"), PathBuf::new());
        info.sequence = Some(format!("ouster-udp-{}", self.options.addr));
        info.timestamp_s = Some(stamp_ns as f64 * 1e-9);
        info.point_channels = points.channels().to_vec();
        Ok(LiveFrame { frame: Frame { info, points }, stamp_ns, arrived: Instant::now() })
    }
}

impl Source for UdpSource {
    fn describe(&self) -> String {
        format!("ouster-udp://{} ({})", self.options.addr, self.options.metadata.display())
    }

    fn is_live(&self) -> bool {
        true
    }

    fn run(&mut self, emit: &mut dyn FnMut(LiveFrame) -> Flow, stop: &AtomicBool) -> Result<SourceReport> {
        let mut buf = vec![0u8; 65_536];
        self.socket
            .set_read_timeout(Some(self.options.idle))
            .map_err(|e| LiveError::uri(self.describe(), e.to_string()))?;
        let mut last_packet = Instant::now();
        let mut n = 0u64;
        while !stop.load(Ordering::Relaxed) {
            let (done, finished) = match self.socket.recv_from(&mut buf) {
                Ok((len, _)) => {
                    last_packet = Instant::now();
                    (self.assembler.push(&buf[..len]), false)
                }
                Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                    let quiet = last_packet.elapsed();
                    let timed_out = self.options.timeout_s.is_some_and(|t| quiet.as_secs_f64() >= t);
                    let ended =
                        if quiet >= self.options.idle || timed_out { self.assembler.end_pending() } else { None };
                    (ended, timed_out)
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => (None, false),
                Err(e) => return Err(LiveError::uri(self.describe(), format!("receive failed: {e}"))),
            };
            if let Some(s) = done {
                let frame = self.decode_frame(&s, n)?;
                n += 1;
                if emit(frame) == Flow::Stop {
                    break;
                }
            }
            if finished {
                break;
            }
        }
        let mut report = self.assembler.report.clone();
        report.sweeps = n;
        Ok(report)
    }
}
