//! Range → XYZ exactly as the Ouster SDK's `XYZLut` (`make_xyz_lut` + `cartesian`) computes it,
//! and destaggering (`destagger`).
//!
//! For pixel `(u, v)` (beam `u`, measurement id `v` of `w`): encoder angle `θe = 2π − 2πv/w`,
//! beam azimuth `θa = −azimuth_deg[u]`, altitude `φ = altitude_deg[u]`;
//! direction `d = (cos(θe+θa)·cos φ, sin(θe+θa)·cos φ, sin φ)`; with `b = beam_to_lidar`'s
//! translation (mm) and `n = |(b_x, b_z)|` (just `b_x` when `b_z` is 0), the beam origin offset
//! `o = (cos θe·b_x − d_x·n, sin θe·b_x − d_y·n, −d_z·n + b_z)`; both go through
//! `lidar_to_sensor_transform` (`R·d`, `R·o + t`) and are scaled by 1 mm. A point is `d·r + o` —
//! per coordinate, where `d·r` is exactly 0 the SDK keeps 0 (so range 0 gives the origin), and
//! we do the same. Results are in metres in the sensor frame (the SDK's default, no extrinsics).

use super::metadata::SensorMetadata;
use super::packet::Sweep;

const RANGE_UNIT_M: f64 = 0.001;

#[derive(Debug, Clone, PartialEq)]
pub struct XyzLut {
    w: usize,
    h: usize,
    direction: Vec<[f64; 3]>,
    offset: Vec<[f64; 3]>,
    shifts: Vec<usize>,
}

/// One returned point of a sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepPoint {
    /// Metres, sensor frame.
    pub xyz: [f64; 3],
    pub reflectivity: u16,
    /// The column's timestamp from the packet (ns, sensor clock).
    pub timestamp_ns: u64,
    pub beam: u16,
}

impl XyzLut {
    pub fn new(md: &SensorMetadata) -> Self {
        let (w, h) = (md.columns_per_frame, md.pixels_per_column);
        let b = &md.beam_to_lidar;
        let (bx, bz) = (b[0][3], b[2][3]);
        let n = if bz != 0.0 { (bx * bx + bz * bz).sqrt() } else { bx };
        let t = &md.lidar_to_sensor;
        let rot =
            |v: [f64; 3]| -> [f64; 3] { std::array::from_fn(|i| t[i][0] * v[0] + t[i][1] * v[1] + t[i][2] * v[2]) };
        let mut direction = Vec::with_capacity(w * h);
        let mut offset = Vec::with_capacity(w * h);
        let step = std::f64::consts::PI * 2.0 / w as f64;
        for u in 0..h {
            let az = -md.beam_azimuth_deg[u] * std::f64::consts::PI / 180.0;
            let alt = md.beam_altitude_deg[u] * std::f64::consts::PI / 180.0;
            for v in 0..w {
                let enc = 2.0 * std::f64::consts::PI - v as f64 * step;
                let d = [(enc + az).cos() * alt.cos(), (enc + az).sin() * alt.cos(), alt.sin()];
                let o = [enc.cos() * bx - d[0] * n, enc.sin() * bx - d[1] * n, -d[2] * n + bz];
                let (d, o) = (rot(d), rot(o));
                direction.push(d.map(|x| x * RANGE_UNIT_M));
                offset.push(std::array::from_fn(|i| (o[i] + t[i][3]) * RANGE_UNIT_M));
            }
        }
        let shifts = md.pixel_shift_by_row.iter().map(|&s| s.rem_euclid(w as i64) as usize).collect();
        Self { w, h, direction, offset, shifts }
    }

    /// XYZ (m) of staggered pixel `(u, v)` at `range_mm`.
    pub fn xyz(&self, u: usize, v: usize, range_mm: u32) -> [f64; 3] {
        let i = u * self.w + v;
        let r = range_mm as f64;
        std::array::from_fn(|c| {
            let p = self.direction[i][c] * r;
            if p == 0.0 {
                p
            } else {
                p + self.offset[i][c]
            }
        })
    }

    /// The sweep's points with range > 0, in the destaggered image's row-major order (beam by
    /// beam, then by azimuth column as `destagger` lays them out), appended to `out`.
    pub fn points(&self, sweep: &Sweep, out: &mut Vec<SweepPoint>) {
        self.for_each_point(sweep, |p| out.push(p));
    }

    /// [`points`](Self::points) without collecting them.
    pub fn for_each_point(&self, sweep: &Sweep, mut f: impl FnMut(SweepPoint)) {
        let w = self.w;
        for u in 0..self.h.min(sweep.h) {
            let shift = self.shifts[u];
            let row = &sweep.range_mm[u * w..(u + 1) * w];
            for vd in 0..w {
                // destagger: output column (v + shift) mod w holds staggered column v.
                let v = (vd + w - shift) % w;
                let r = row[v];
                if r == 0 {
                    continue;
                }
                f(SweepPoint {
                    xyz: self.xyz(u, v, r),
                    reflectivity: sweep.reflectivity[u * w + v],
                    timestamp_ns: sweep.column_timestamp_ns[v],
                    beam: u as u16,
                });
            }
        }
    }

    /// The staggered pixel `(beam, measurement id)` and range (mm) whose return is nearest to
    /// `p` (sensor frame, m): [`xyz`](Self::xyz) inverted, to encode points as packets (replays,
    /// benchmarks). The beam is the one nearest in elevation; `None` when `p` is more than
    /// `max_elevation_gap_deg` from every beam, at the origin, or beyond the 20-bit range.
    pub fn pixel_of(&self, p: [f64; 3], max_elevation_gap_deg: f64) -> Option<(usize, usize, u32)> {
        let (w, h) = (self.w, self.h);
        if w == 0 || h == 0 {
            return None;
        }
        let elevation = |d: [f64; 3]| d[2].atan2(d[0].hypot(d[1]));
        let azimuth = |d: [f64; 3]| d[1].atan2(d[0]);
        let step = std::f64::consts::TAU / w as f64;
        let locate = |q: [f64; 3], max_gap_deg: f64| -> Option<(usize, usize)> {
            let e = elevation(q);
            let (u, gap) =
                (0..h).map(|u| (u, (elevation(self.direction[u * w]) - e).abs())).min_by(|a, b| a.1.total_cmp(&b.1))?;
            if gap.to_degrees() > max_gap_deg {
                return None;
            }
            // Column azimuths fall by one step per measurement id from column 0's.
            let turn = (azimuth(self.direction[u * w]) - azimuth(q)).rem_euclid(std::f64::consts::TAU);
            Some((u, ((turn / step).round() as usize) % w))
        };
        // The beam origin sits off the axis: locate, subtract that pixel's offset, locate again.
        // (The gap is checked on the corrected point: up close the offset moves it by degrees.)
        let (mut u, mut v) = locate(p, 180.0)?;
        for k in 0..3 {
            let o = self.offset[u * w + v];
            let gap = if k == 2 { max_elevation_gap_deg } else { 180.0 };
            (u, v) = locate([p[0] - o[0], p[1] - o[1], p[2] - o[2]], gap)?;
        }
        let o = self.offset[u * w + v];
        let d = self.direction[u * w + v];
        let along: f64 = (0..3).map(|c| (p[c] - o[c]) * d[c]).sum::<f64>() / (0..3).map(|c| d[c] * d[c]).sum::<f64>();
        let range = along.round();
        (range >= 1.0 && range <= f64::from(0x000f_ffff)).then_some((u, v, range as u32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{metadata_json, SynthSpec};
    use std::path::Path;

    #[test]
    fn pixel_of_inverts_xyz() {
        let md = SensorMetadata::parse(Path::new("m.json"), &metadata_json(&SynthSpec::os1_64("t", 1))).unwrap();
        let lut = XyzLut::new(&md);
        let mut seed = 7u64;
        for _ in 0..5000 {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let (u, v) = ((seed >> 33) as usize % lut.h, (seed >> 13) as usize % lut.w);
            let r = 1000 + (seed >> 40) as u32 % 100_000;
            let p = lut.xyz(u, v, r);
            assert_eq!(lut.pixel_of(p, 0.5), Some((u, v, r)), "pixel ({u}, {v}) at {r} mm");
        }
        assert_eq!(lut.pixel_of([0.0, 0.0, 50.0], 0.5), None, "straight up: no beam");
    }
}
