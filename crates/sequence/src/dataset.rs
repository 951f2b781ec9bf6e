//! A sequence folder, or a `processed/` tree of them, as a lazy [`Dataset`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use pi3det_data::{DataError, Dataset, Format, Frame, FrameInfo, Object, Platform, PointCloud};
use pi3det_geometry::{Pose, PoseExt};

use crate::error::{Result, SequenceError};
use crate::hdf5::{H5Dataset, H5File};
use crate::labels::{self, LabelFrame};
use crate::ouster::packet::Sweep;
use crate::ouster::xyz::SweepPoint;
use crate::ouster::{PacketFormat, SensorMetadata, XyzLut};

/// Channels of a loaded frame: `time` is seconds since the sweep's first valid column (from the
/// packets' column timestamps), `ring` the beam index (0 = the top beam).
pub const CHANNELS: [&str; 6] = ["x", "y", "z", "intensity", "time", "ring"];

/// Reflectivity → intensity: the released layout stores intensity in [0, 1]; we divide the
/// calibrated reflectivity (0–255) by 255, clamping larger values. (The public loader divides by
/// each sweep's maximum, which makes the scale change from frame to frame.)
pub fn intensity(reflectivity: u16) -> f32 {
    f32::from(reflectivity.min(255)) / 255.0
}

#[derive(Debug, Clone, Copy, Default)]
pub struct SequenceOptions {
    /// Use the frames all files have (as the public loader does) instead of refusing a pose file
    /// or `/ouster/ts_start` with fewer frames than the data.
    pub truncate: bool,
    pub label_frame: LabelFrame,
}

/// One sequence folder: `*data*.h5`, `*pose*.h5`, `ps_labels/final_ps_dict.pkl`.
pub struct Sequence {
    pub dir: PathBuf,
    pub name: String,
    pub platform: Platform,
    pub data_path: PathBuf,
    pub pose_path: Option<PathBuf>,
    pub labels_path: Option<PathBuf>,
    pub metadata: SensorMetadata,
    pub format: PacketFormat,
    /// Handles on `/ouster/data`: one streaming handle serialises its reads, so each
    /// concurrent load borrows its own (opened on first need, then reused).
    spare_handles: Mutex<Vec<H5Dataset>>,
    packets_per_sweep: usize,
    /// Pad bytes after each packet in a row (0, or the ouster-ros pad).
    row_pad_bytes: usize,
    lut: OnceLock<XyzLut>,
    ts_start_us: Option<Vec<i64>>,
    poses: Option<Vec<Pose>>,
    objects: Vec<Vec<Object>>,
    frames: usize,
}

/// Folders at or below `root` (up to `processed/<Platform>/<condition>/<sequence>`) holding a
/// `*data*.h5`, sorted.
pub fn find_sequences(root: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, depth: usize, out: &mut Vec<PathBuf>) {
        if data_files(dir).is_ok_and(|f| !f.is_empty()) {
            out.push(dir.to_path_buf());
            return;
        }
        if depth == 0 {
            return;
        }
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        let mut dirs: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect();
        dirs.sort();
        for d in dirs {
            walk(&d, depth - 1, out);
        }
    }
    let mut out = Vec::new();
    walk(root, 4, &mut out);
    out
}

fn h5_files(dir: &Path, needle: &str) -> std::io::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "h5"))
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.contains(needle)))
        .collect();
    v.sort();
    Ok(v)
}

fn data_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    h5_files(dir, "data")
}

/// The one file of `candidates`, preferring `<sequence>_<kind>.h5` when there are several.
fn pick(dir: &Path, name: &str, kind: &str, candidates: Vec<PathBuf>) -> Result<Option<PathBuf>> {
    if candidates.len() <= 1 {
        return Ok(candidates.into_iter().next());
    }
    let exact = dir.join(format!("{name}_{kind}.h5"));
    if candidates.contains(&exact) {
        return Ok(Some(exact));
    }
    let names: Vec<_> = candidates.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy()).collect();
    Err(SequenceError::invalid(dir, format!("several *{kind}*.h5 files ({}); expected one", names.join(", "))))
}

/// The platform from the folder names (`processed/<Platform>/...`, Car / Falcon / Spot), else
/// from the sequence name's first word (M3ED names start with car_, falcon_, spot_).
fn platform_of(dir: &Path, name: &str) -> Platform {
    dir.ancestors()
        .skip(1)
        .take(3)
        .filter_map(|a| a.file_name().and_then(|n| n.to_str()))
        .map(Platform::parse)
        .find(|p| *p != Platform::Unknown)
        .unwrap_or_else(|| Platform::parse(name.split('_').next().unwrap_or("")))
}

impl Sequence {
    pub fn open(dir: &Path, options: SequenceOptions) -> Result<Self> {
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let io = |e: std::io::Error| SequenceError::invalid(dir, format!("cannot list the folder: {e}"));
        let data_path = pick(dir, &name, "data", data_files(dir).map_err(io)?)?
            .ok_or_else(|| SequenceError::invalid(dir, "no *data*.h5 file"))?;
        let pose_path = pick(dir, &name, "pose", h5_files(dir, "pose").map_err(io)?)?;
        let labels_path = Some(dir.join("ps_labels/final_ps_dict.pkl")).filter(|p| p.is_file());
        let platform = platform_of(dir, &name);

        let file = H5File::open(&data_path)?;
        let metadata = SensorMetadata::parse(&data_path, &file.dataset("/ouster/metadata")?.read_text()?)?;
        let format = PacketFormat::new(&metadata);
        let data = file.dataset("/ouster/data")?;
        let (mut frames, packets_per_sweep, stored_packet_bytes) = match *data.shape() {
            [n, p, b] => (n as usize, p as usize, b as usize),
            ref s => {
                return Err(SequenceError::invalid(
                    &data_path,
                    format!("/ouster/data has shape {s:?}, expected (sweeps, packets, packet bytes)"),
                ))
            }
        };
        let row_pad_bytes = format.row_padding(stored_packet_bytes).map_err(|m| {
            SequenceError::invalid(&data_path, format!("/ouster/data of shape {:?}: {m}", data.shape()))
        })?;
        data.row_bytes()?;
        data.check_chunks()?;
        let short = |what: &str, path: &Path, n: usize, frames: usize| {
            SequenceError::invalid(
                path,
                format!("{what} has {n} frames but the data has {frames} (pass truncate / --truncate to read the first {n})"),
            )
        };
        let ts_start_us = match file.dataset("/ouster/ts_start") {
            Ok(ts) => Some(ts.read_i64()?),
            Err(_) => None,
        };
        if let Some(ts) = &ts_start_us {
            if ts.len() < frames {
                if !options.truncate {
                    return Err(short("/ouster/ts_start", &data_path, ts.len(), frames));
                }
                frames = ts.len();
            }
        }
        let poses = match &pose_path {
            None => None,
            Some(p) => {
                let poses = read_poses(p)?;
                if poses.len() < frames {
                    if !options.truncate {
                        return Err(short("/Ln_T_L0", p, poses.len(), frames));
                    }
                    frames = poses.len();
                }
                Some(poses)
            }
        };
        let stored = match &labels_path {
            Some(p) => labels::read(p)?,
            None => BTreeMap::new(),
        };
        let unlabelled = (0..frames).filter(|k| !stored.contains_key(k)).count();
        if labels_path.is_some() && unlabelled > 0 {
            tracing::warn!(
                "{}: {unlabelled} of {frames} frames have no pseudo-labels (read as frames without boxes)",
                dir.display()
            );
        }
        let mut objects = Vec::with_capacity(frames);
        for k in 0..frames {
            let boxes = stored.get(&k).map(Vec::as_slice).unwrap_or(&[]);
            let pose = poses.as_ref().map(|p| &p[k]);
            let o = labels::objects(boxes, platform, &name, pose, options.label_frame).map_err(|m| {
                SequenceError::invalid(labels_path.as_deref().unwrap_or(dir), format!("frame {k:05}: {m}"))
            })?;
            objects.push(o);
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            name,
            platform,
            data_path,
            pose_path,
            labels_path,
            metadata,
            format,
            spare_handles: Mutex::new(vec![data]),
            packets_per_sweep,
            row_pad_bytes,
            lut: OnceLock::new(),
            ts_start_us,
            poses,
            objects,
            frames,
        })
    }

    pub fn len(&self) -> usize {
        self.frames
    }

    pub fn is_empty(&self) -> bool {
        self.frames == 0
    }

    pub fn lut(&self) -> &XyzLut {
        self.lut.get_or_init(|| XyzLut::new(&self.metadata))
    }

    pub fn info(&self, k: usize) -> FrameInfo {
        let mut info = FrameInfo::new(format!("{}_{k:05}", self.name), self.data_path.clone());
        info.platform = self.platform;
        info.sequence = Some(self.name.clone());
        // M3ED timestamps are microseconds.
        info.timestamp_s = self.ts_start_us.as_ref().and_then(|t| t.get(k)).map(|&t| t as f64 * 1e-6);
        info.world_from_lidar = self.poses.as_ref().and_then(|p| p.get(k)).copied();
        info.objects = self.objects.get(k).cloned().unwrap_or_default();
        info.point_channels = CHANNELS.iter().map(|s| s.to_string()).collect();
        info
    }

    /// Pad bytes stored after each packet: 0, or [`crate::ouster::ROS_PACKET_PAD_BYTES`] in
    /// recordings made through ouster-ros 0.x (the Pi3DET release).
    pub fn row_pad_bytes(&self) -> usize {
        self.row_pad_bytes
    }

    /// Bytes per stored packet: the packet and its pad.
    fn stored_packet_bytes(&self) -> usize {
        self.format.packet_bytes() + self.row_pad_bytes
    }

    /// The packets of sweep `k` as the sensor sent them (pad bytes removed), one per datagram:
    /// what a replayer sends.
    pub fn read_packets(&self, k: usize) -> Result<Vec<Vec<u8>>> {
        let row = self.read_row(k)?;
        let n = self.format.packet_bytes();
        Ok(row.chunks_exact(self.stored_packet_bytes()).map(|p| p[..n].to_vec()).collect())
    }

    /// The stored bytes of sweep `k` (one HDF5 row: its packets, each followed by its pad).
    pub fn read_row(&self, k: usize) -> Result<Vec<u8>> {
        let spare = self.spare_handles.lock().ok().and_then(|mut v| v.pop());
        let handle = match spare {
            Some(h) => h,
            None => H5File::open(&self.data_path)?.dataset("/ouster/data")?,
        };
        let row = handle.read_row(k as u64);
        if let Ok(mut v) = self.spare_handles.lock() {
            v.push(handle);
        }
        row
    }

    /// Decodes sweep `k` into `sweep` (reused between calls to save allocations).
    pub fn read_sweep(&self, k: usize, sweep: &mut Sweep) -> Result<()> {
        let bytes = self.read_row(k)?;
        debug_assert_eq!(bytes.len(), self.packets_per_sweep * self.stored_packet_bytes());
        self.format.decode_rows(&bytes, self.stored_packet_bytes(), sweep);
        if sweep.columns_out_of_range > 0 {
            tracing::warn!(
                "{}: sweep {k}: {} columns with a measurement id outside the {}-column frame skipped",
                self.data_path.display(),
                sweep.columns_out_of_range,
                sweep.w
            );
        }
        Ok(())
    }

    /// The points of sweep `k` as the SDK would give them (destaggered order, range > 0).
    pub fn sweep_points(&self, k: usize) -> Result<Vec<SweepPoint>> {
        let mut sweep = Sweep::default();
        self.read_sweep(k, &mut sweep)?;
        let mut points = Vec::with_capacity(sweep.range_mm.len());
        self.lut().points(&sweep, &mut points);
        Ok(points)
    }

    pub fn load(&self, k: usize) -> Result<Frame> {
        thread_local! {
            // Reused between loads: fresh multi-megabyte buffers per sweep cost page faults,
            // which serialise threads on the address-space lock.
            static SWEEP: std::cell::RefCell<Sweep> = std::cell::RefCell::new(Sweep::default());
        }
        let points = SWEEP.with(|cell| -> Result<PointCloud> {
            let mut sweep = cell.borrow_mut();
            self.read_sweep(k, &mut sweep)?;
            Ok(sweep_points_cloud(self.lut(), &sweep)?)
        })?;
        Ok(Frame { info: self.info(k), points })
    }
}

/// The first valid column's timestamp of a sweep (ns, sensor clock), if any column is valid.
pub fn sweep_start_ns(sweep: &Sweep) -> Option<u64> {
    (0..sweep.w).filter(|&v| sweep.column_valid[v]).map(|v| sweep.column_timestamp_ns[v]).min()
}

/// A decoded sweep's returns as a point cloud with [`CHANNELS`] (zero ranges dropped), as the
/// dataset reader and the live UDP source both give them.
pub fn sweep_points_cloud(lut: &XyzLut, sweep: &Sweep) -> std::result::Result<PointCloud, DataError> {
    let t0 = sweep_start_ns(sweep).unwrap_or(0);
    let mut data = Vec::with_capacity(sweep.range_mm.len() * CHANNELS.len());
    lut.for_each_point(sweep, |p| {
        data.extend_from_slice(&[
            p.xyz[0] as f32,
            p.xyz[1] as f32,
            p.xyz[2] as f32,
            intensity(p.reflectivity),
            (p.timestamp_ns.saturating_sub(t0) as f64 * 1e-9) as f32,
            f32::from(p.beam),
        ]);
    });
    PointCloud::from_vec(data, CHANNELS.iter().map(|s| s.to_string()).collect())
}

/// `Ln_T_L0` maps the first frame's LiDAR coordinates into frame n's, so the pose of frame n in
/// the first frame (our `world_from_lidar`, world = the first LiDAR frame) is its inverse.
fn read_poses(path: &Path) -> Result<Vec<Pose>> {
    let file = H5File::open(path)?;
    let ds = file.dataset("/Ln_T_L0")?;
    let n = match *ds.shape() {
        [n, 4, 4] => n as usize,
        ref s => return Err(SequenceError::invalid(path, format!("/Ln_T_L0 has shape {s:?}, expected (N, 4, 4)"))),
    };
    let values = ds.read_f64()?;
    (0..n)
        .map(|k| {
            let m: [[f64; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| values[16 * k + 4 * i + j]));
            Pose::try_from_matrix(&m)
                .map(|p| p.inverse())
                .map_err(|e| SequenceError::invalid(path, format!("/Ln_T_L0[{k}]: {e}")))
        })
        .collect()
}

/// Every sequence under a root, as one dataset: frame `i` is sequence by sequence, in path order.
pub struct SequenceDataset {
    root: PathBuf,
    sequences: Vec<Sequence>,
    /// `(sequence, frame)` of each dataset index.
    index: Vec<(usize, usize)>,
}

impl SequenceDataset {
    /// A sequence folder, or any folder above them (`processed/`, `processed/Car`, ...).
    pub fn open(root: &Path, options: SequenceOptions) -> Result<Self> {
        let dirs = find_sequences(root);
        if dirs.is_empty() {
            return Err(SequenceError::Data(DataError::UnknownFormat {
                path: root.to_path_buf(),
                hint: "no sequence folder with a *data*.h5 file".into(),
            }));
        }
        let sequences = dirs.iter().map(|d| Sequence::open(d, options)).collect::<Result<Vec<_>>>()?;
        let index = sequences.iter().enumerate().flat_map(|(s, seq)| (0..seq.len()).map(move |k| (s, k))).collect();
        Ok(Self { root: root.to_path_buf(), sequences, index })
    }

    pub fn sequences(&self) -> &[Sequence] {
        &self.sequences
    }

    /// The sequence and frame of a dataset index.
    pub fn locate(&self, index: usize) -> Result<(&Sequence, usize), DataError> {
        let &(s, k) = self
            .index
            .get(index)
            .ok_or_else(|| DataError::invalid(&self.root, format!("frame index {index} out of range")))?;
        Ok((&self.sequences[s], k))
    }
}

impl Dataset for SequenceDataset {
    fn format(&self) -> Format {
        // The frames are Pi3DET's own; `pi3det info` names the source as a sequence release.
        Format::Pi3det
    }

    fn root(&self) -> &Path {
        &self.root
    }

    fn len(&self) -> usize {
        self.index.len()
    }

    fn info(&self, index: usize) -> Result<FrameInfo, DataError> {
        let (seq, k) = self.locate(index)?;
        Ok(seq.info(k))
    }

    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let (seq, k) = self.locate(index)?;
        Ok(seq.load(k)?)
    }
}
