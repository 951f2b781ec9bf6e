//! Lidar packets → one sweep's staggered range / reflectivity images, as the Ouster SDK's
//! `ScanBatcher` fills a `LidarScan`.
//!
//! Layouts (Ouster sensor docs, "Lidar data format"; checked against ouster-sdk 1.0.1's
//! `PacketFormat` sizes and decoding by `tests/fixtures/oracle_xyz.py`):
//! - LEGACY: no packet header; per column a 16-byte header (timestamp u64 ns, measurement id u16,
//!   frame id u16, encoder count u32), 12 bytes per pixel (range u32 whose low 20 bits are mm,
//!   reflectivity u16, signal u16, near-IR u16, 2 unused) and a status u32 (bit 0: valid).
//!   64 beams × 16 columns: 12,608 bytes.
//! - RNG19_RFL8_SIG16_NIR16: a 32-byte packet header, per column a 12-byte header (timestamp
//!   u64, measurement id u16, status u16, bit 0: valid), 12 bytes per pixel (range u32 whose low
//!   19 bits are mm, reflectivity u8, unused u8, signal u16, near-IR u16, 2 unused), a 32-byte
//!   packet footer. 64 beams × 16 columns: 12,544 bytes.
//!
//! All little-endian. Invalid columns, and columns whose measurement id is outside the frame,
//! leave their pixels at range 0 (no point), as the SDK does.

use super::metadata::{SensorMetadata, UdpProfile};

const PIXEL_BYTES: usize = 12;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PacketFormat {
    pub profile: UdpProfile,
    pub columns_per_packet: usize,
    pub pixels_per_column: usize,
    pub columns_per_frame: usize,
    pub packet_header_bytes: usize,
    pub column_header_bytes: usize,
    pub column_footer_bytes: usize,
    pub packet_footer_bytes: usize,
}

/// One sweep in the sensor's staggered image layout: pixel `(u, v)` (beam `u`, measurement id
/// `v`) at `u * w + v`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sweep {
    pub w: usize,
    pub h: usize,
    pub range_mm: Vec<u32>,
    pub reflectivity: Vec<u16>,
    pub column_timestamp_ns: Vec<u64>,
    pub column_valid: Vec<bool>,
    /// Columns skipped because their measurement id was outside the frame.
    pub columns_out_of_range: usize,
}

impl Sweep {
    pub fn new(w: usize, h: usize) -> Self {
        Self {
            w,
            h,
            range_mm: vec![0; w * h],
            reflectivity: vec![0; w * h],
            column_timestamp_ns: vec![0; w],
            column_valid: vec![false; w],
            columns_out_of_range: 0,
        }
    }

    fn clear(&mut self) {
        self.range_mm.fill(0);
        self.reflectivity.fill(0);
        self.column_timestamp_ns.fill(0);
        self.column_valid.fill(false);
        self.columns_out_of_range = 0;
    }
}

fn u16_at(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes([b[o], b[o + 1]])
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}

fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(std::array::from_fn(|i| b[o + i]))
}

/// Bytes ouster-ros 0.x appends to every lidar packet in its message buffers, and so to every
/// row of `/ouster/data` in the recordings made through it (M3ED, the Pi3DET sequence release:
/// `uint8 (N, packets_per_sweep, 12609)` for OS1-64 LEGACY packets of 12,608 bytes). The Ouster
/// SDK reads `row[:packet_bytes]` and so do we; a sensor's UDP datagrams carry no pad.
pub const ROS_PACKET_PAD_BYTES: usize = 1;

impl PacketFormat {
    pub fn new(md: &SensorMetadata) -> Self {
        let (packet_header_bytes, column_header_bytes, column_footer_bytes, packet_footer_bytes) = match md.profile {
            UdpProfile::Legacy => (0, 16, 4, 0),
            UdpProfile::Rng19Rfl8Sig16Nir16 => (32, 12, 0, 32),
        };
        Self {
            profile: md.profile,
            columns_per_packet: md.columns_per_packet,
            pixels_per_column: md.pixels_per_column,
            columns_per_frame: md.columns_per_frame,
            packet_header_bytes,
            column_header_bytes,
            column_footer_bytes,
            packet_footer_bytes,
        }
    }

    pub fn column_bytes(&self) -> usize {
        self.column_header_bytes + PIXEL_BYTES * self.pixels_per_column + self.column_footer_bytes
    }

    pub fn packet_bytes(&self) -> usize {
        self.packet_header_bytes + self.columns_per_packet * self.column_bytes() + self.packet_footer_bytes
    }

    /// The frame id of one packet (LEGACY: the first column's; RNG19: the packet header's), and
    /// the measurement id and timestamp (ns) of its first column. `None` when `packet` is not
    /// one packet long.
    pub fn packet_ids(&self, packet: &[u8]) -> Option<(u16, u16, u64)> {
        if packet.len() != self.packet_bytes() {
            return None;
        }
        let col = self.packet_header_bytes;
        let frame_id = match self.profile {
            UdpProfile::Legacy => u16_at(packet, col + 10),
            UdpProfile::Rng19Rfl8Sig16Nir16 => u16_at(packet, 2),
        };
        Some((frame_id, u16_at(packet, col + 8), u64_at(packet, col)))
    }

    /// The pad bytes after each packet in rows of `row_bytes` (a stored sweep's rows, or an
    /// Ouster message buffer): 0 when the row is exactly one packet, [`ROS_PACKET_PAD_BYTES`]
    /// when it carries the pad byte ouster-ros 0.x appends. Any other length is refused with a
    /// message giving both sizes: a row shorter than the packet cannot hold it, and a longer one
    /// means the metadata describes another packet layout (profile, beams, columns per packet)
    /// than the recording's, which a looser rule would decode into plausible-looking garbage.
    pub fn row_padding(&self, row_bytes: usize) -> Result<usize, String> {
        let packet = self.packet_bytes();
        match row_bytes.checked_sub(packet) {
            Some(pad) if pad == 0 || pad == ROS_PACKET_PAD_BYTES => Ok(pad),
            _ => Err(format!(
                "packets are {row_bytes} bytes, but the metadata's {:?} format ({} pixels × {} columns per packet) makes {packet}-byte packets; \
                 a row may hold the packet alone ({packet} bytes) or followed by the {ROS_PACKET_PAD_BYTES} pad byte ouster-ros 0.x writes ({} bytes)",
                self.profile,
                self.pixels_per_column,
                self.columns_per_packet,
                packet + ROS_PACKET_PAD_BYTES
            )),
        }
    }

    /// Decodes `packets` (concatenated, each [`packet_bytes`](Self::packet_bytes) long) into
    /// `sweep`, which is reset first. The caller checks the packet size against the file once.
    pub fn decode(&self, packets: &[u8], sweep: &mut Sweep) {
        self.decode_rows(packets, self.packet_bytes(), sweep);
    }

    /// Decodes rows of `row_bytes` each, every one a packet from its first byte followed by pad
    /// bytes that are ignored (see [`row_padding`](Self::row_padding)), into `sweep`, which is
    /// reset first. A trailing part shorter than a row is ignored.
    pub fn decode_rows(&self, rows: &[u8], row_bytes: usize, sweep: &mut Sweep) {
        let (w, h) = (self.columns_per_frame, self.pixels_per_column);
        if sweep.w != w || sweep.h != h {
            *sweep = Sweep::new(w, h);
        } else {
            sweep.clear();
        }
        let (range_mask, legacy) = match self.profile {
            UdpProfile::Legacy => (0x000f_ffff, true),
            UdpProfile::Rng19Rfl8Sig16Nir16 => (0x0007_ffff, false),
        };
        let col_bytes = self.column_bytes();
        let packet_bytes = self.packet_bytes();
        if row_bytes < packet_bytes {
            return;
        }
        for row in rows.chunks_exact(row_bytes) {
            let packet = &row[..packet_bytes];
            let columns = &packet[self.packet_header_bytes..packet_bytes - self.packet_footer_bytes];
            for col in columns.chunks_exact(col_bytes) {
                let ts = u64_at(col, 0);
                let m = u16_at(col, 8) as usize;
                let status = if legacy { u32_at(col, col_bytes - 4) } else { u16_at(col, 10) as u32 };
                if status & 1 == 0 {
                    continue;
                }
                if m >= w {
                    sweep.columns_out_of_range += 1;
                    continue;
                }
                sweep.column_timestamp_ns[m] = ts;
                sweep.column_valid[m] = true;
                let pixels = &col[self.column_header_bytes..self.column_header_bytes + PIXEL_BYTES * h];
                for (u, px) in pixels.chunks_exact(PIXEL_BYTES).enumerate() {
                    let i = u * w + m;
                    sweep.range_mm[i] = u32_at(px, 0) & range_mask;
                    sweep.reflectivity[i] = if legacy { u16_at(px, 4) } else { px[4] as u16 };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn md(profile: UdpProfile) -> SensorMetadata {
        SensorMetadata {
            prod_line: None,
            profile,
            columns_per_frame: 32,
            columns_per_packet: 16,
            pixels_per_column: 2,
            pixel_shift_by_row: vec![0, 0],
            beam_altitude_deg: vec![1.0, -1.0],
            beam_azimuth_deg: vec![0.0, 0.0],
            beam_to_lidar: [[0.0; 4]; 4],
            lidar_to_sensor: [[0.0; 4]; 4],
            fps: None,
            reflectivity_calibrated: None,
        }
    }

    #[test]
    fn sizes_match_the_sdk() {
        // ouster-sdk 1.0.1 PacketFormat(info).lidar_packet_size for OS-1-64, 16 columns.
        let mut m = md(UdpProfile::Legacy);
        m.pixels_per_column = 64;
        assert_eq!(PacketFormat::new(&m).packet_bytes(), 12608);
        m.profile = UdpProfile::Rng19Rfl8Sig16Nir16;
        assert_eq!(PacketFormat::new(&m).packet_bytes(), 12544);
    }

    #[test]
    fn legacy_column_fields() {
        let f = PacketFormat::new(&md(UdpProfile::Legacy));
        let mut bytes = Vec::new();
        for p in 0..2u16 {
            for c in 0..16u16 {
                let m = p * 16 + c;
                bytes.extend_from_slice(&(1000 + m as u64).to_le_bytes());
                bytes.extend_from_slice(&m.to_le_bytes());
                bytes.extend_from_slice(&7u16.to_le_bytes());
                bytes.extend_from_slice(&0u32.to_le_bytes());
                for u in 0..2u32 {
                    // Bits above the 20-bit range are flags and must be masked off.
                    bytes.extend_from_slice(&((0xf << 20) | (m as u32 * 10 + u)).to_le_bytes());
                    bytes.extend_from_slice(&(200u16 + u as u16).to_le_bytes());
                    bytes.extend_from_slice(&[0u8; 6]);
                }
                bytes.extend_from_slice(&(if m == 5 { 0u32 } else { u32::MAX }).to_le_bytes());
            }
        }
        let mut s = Sweep::default();
        f.decode(&bytes, &mut s);
        assert_eq!(s.range_mm[3], 30);
        assert_eq!(s.range_mm[32 + 3], 31);
        assert_eq!(s.reflectivity[32 + 3], 201);
        assert_eq!(s.column_timestamp_ns[31], 1031);
        assert!(!s.column_valid[5] && s.range_mm[5] == 0);
    }
}
