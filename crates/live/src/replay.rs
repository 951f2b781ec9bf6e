//! A loopback replayer of synthetic Ouster packet streams with the faults of a real network:
//! lost, reordered, duplicated and truncated packets, garbage datagrams, a frame-id wrap and a
//! sensor restart. Used by the live tests and `pi3det bench live`. It also sends recorded
//! sweeps of the sequence release ([`sequence_datagrams`]): their rows carry ouster-ros' pad byte
//! after every packet, which a sensor never sends, so the datagrams leave it out.

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use pi3det_data::PointCloud;
use pi3det_sequence::ouster::{PacketFormat, UdpProfile, XyzLut};
use pi3det_sequence::synth::{sweep_packets, sweep_packets_with, SynthSpec};
use pi3det_sequence::{Sequence, SequenceError};

/// Probabilities per packet.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Faults {
    pub loss: f64,
    pub reorder: f64,
    pub duplicate: f64,
    pub truncate: f64,
    /// A garbage datagram (random bytes, random length) after a packet.
    pub garbage: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ReplayPlan {
    pub sweeps: usize,
    /// The first sweep's frame id (near 65535 to test the wrap).
    pub first_frame_id: u16,
    /// From this sweep on the sensor "restarts": frame ids begin again at 0.
    pub restart_at: Option<usize>,
    pub faults: Faults,
    pub seed: u64,
}

/// splitmix64: enough randomness for faults, no dependency.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    pub fn chance(&mut self, p: f64) -> bool {
        let u = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        p > 0.0 && u < p
    }
}

/// The frame id of sweep `k` under `plan`.
pub fn frame_id(plan: &ReplayPlan, k: usize) -> u16 {
    match plan.restart_at {
        Some(r) if k >= r => (k - r) as u16,
        _ => plan.first_frame_id.wrapping_add(k as u16),
    }
}

/// The datagrams of each sweep, faults applied, in sending order (a reordered packet may move
/// into the next sweep's list).
pub fn datagrams(spec: &SynthSpec, plan: &ReplayPlan) -> Vec<Vec<Vec<u8>>> {
    let mut rng = Rng::new(plan.seed);
    let mut content = Rng::new(plan.seed ^ 0x5eed);
    let packets_per_sweep = spec.columns.div_ceil(16);
    let mut out: Vec<Vec<Vec<u8>>> = Vec::with_capacity(plan.sweeps);
    let mut carry: Option<Vec<u8>> = None;
    for k in 0..plan.sweeps {
        let t0 = 1_000_000_000 + k as u64 * 100_000_000;
        let bytes = sweep_packets(spec, usize::from(frame_id(plan, k)), t0, &mut || content.next_u64());
        let mut sweep = Vec::new();
        for p in bytes.chunks_exact(bytes.len() / packets_per_sweep) {
            let f = &plan.faults;
            if rng.chance(f.loss) {
                continue;
            }
            let mut p = p.to_vec();
            if rng.chance(f.truncate) {
                p.truncate((rng.next_u64() as usize) % p.len());
            }
            if rng.chance(f.reorder) && carry.is_none() {
                carry = Some(p);
                continue;
            }
            sweep.push(p.clone());
            if let Some(c) = carry.take() {
                sweep.push(c);
            }
            if rng.chance(f.duplicate) {
                sweep.push(p);
            }
            if rng.chance(f.garbage) {
                let n = 1 + (rng.next_u64() as usize) % 2000;
                sweep.push((0..n).map(|_| rng.next_u64() as u8).collect());
            }
        }
        out.push(sweep);
    }
    if let (Some(c), Some(last)) = (carry, out.last_mut()) {
        last.push(c);
    }
    out
}

/// The datagrams of recorded sweeps `frames` of a sequence, as the sensor sent them (one packet
/// each, the stored pad bytes removed), in the shape [`send`] takes.
pub fn sequence_datagrams(seq: &Sequence, frames: std::ops::Range<usize>) -> Result<Vec<Vec<Vec<u8>>>, SequenceError> {
    frames.map(|k| seq.read_packets(k)).collect()
}

/// Sends sweeps to `to` at `rate_hz`, each sweep's datagrams spread over its period as a sensor
/// does (a burst would overflow the receiver's socket buffer). Returns datagrams sent.
pub fn send(sweeps: &[Vec<Vec<u8>>], to: SocketAddr, rate_hz: f64) -> std::io::Result<usize> {
    let socket = UdpSocket::bind(if to.is_ipv4() { "127.0.0.1:0" } else { "[::1]:0" })?;
    let period = Duration::from_secs_f64(1.0 / rate_hz.max(1e-3));
    let start = Instant::now();
    let mut sent = 0;
    for (k, sweep) in sweeps.iter().enumerate() {
        let n = sweep.len().max(1) as u32;
        for (j, d) in sweep.iter().enumerate() {
            let due = start + period * k as u32 + period * j as u32 / n;
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            socket.send_to(d, to)?;
            sent += 1;
        }
    }
    Ok(sent)
}

/// A point cloud (sensor frame; x, y, z and intensity in [0, 1] if it has one) as one sweep's
/// packets of `spec`: each point goes to the pixel whose return it is nearest
/// ([`XyzLut::pixel_of`]); where two share a pixel the nearer one stays, points no beam sees
/// (over 0.5° from every beam) are left out. Returns the packets and the points encoded.
pub fn encode_cloud(spec: &SynthSpec, lut: &XyzLut, cloud: &PointCloud, frame_id: u16, t0_ns: u64) -> (Vec<u8>, usize) {
    let (h, w) = (spec.beams, spec.columns);
    let mut grid = vec![(0u32, 0u16); h * w];
    let has_intensity = cloud.stride() >= 4;
    for p in cloud.iter() {
        let xyz = [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
        if let Some((u, v, r)) = lut.pixel_of(xyz, 0.5) {
            let cell = &mut grid[u * w + v];
            if cell.0 == 0 || r < cell.0 {
                let refl = if has_intensity { (p[3].clamp(0.0, 1.0) * 255.0).round() as u16 } else { 0 };
                *cell = (r, refl);
            }
        }
    }
    let encoded = grid.iter().filter(|c| c.0 > 0).count();
    (sweep_packets_with(spec, usize::from(frame_id), t0_ns, &mut |u, m| grid[u * w + m]), encoded)
}

/// Rewrites the frame id and timestamps of one sweep's packets (to send a recorded sweep
/// again as a later one).
pub fn relabel(format: &PacketFormat, packets: &mut [u8], frame_id: u16, t0_ns: u64) {
    let col = format.column_bytes();
    let w = format.columns_per_frame.max(1) as u64;
    for packet in packets.chunks_exact_mut(format.packet_bytes()) {
        if format.profile == UdpProfile::Rng19Rfl8Sig16Nir16 {
            packet[2..4].copy_from_slice(&frame_id.to_le_bytes());
        }
        let body = format.packet_header_bytes..packet.len() - format.packet_footer_bytes;
        for c in packet[body].chunks_exact_mut(col) {
            let m = u64::from(u16::from_le_bytes([c[8], c[9]]));
            c[..8].copy_from_slice(&(t0_ns + m * (100_000_000 / w)).to_le_bytes());
            if format.profile == UdpProfile::Legacy {
                c[10..12].copy_from_slice(&frame_id.to_le_bytes());
            }
        }
    }
}
