//! Label sets: boxes per frame id, read from any detection format `pi3det eval` reads (JSON
//! lines, `result.pkl`, a KITTI result folder) and written as JSON lines, with track ids when
//! they have them.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use pi3det_data::Object;
use pi3det_eval::{Detections, JsonlFrame};

use crate::AutolabelError;

#[derive(Debug, Clone, Default, PartialEq)]
pub struct LabelSet {
    /// Where it was read from (for messages); empty when built in memory.
    pub source: PathBuf,
    pub frames: BTreeMap<String, Vec<Object>>,
}

impl LabelSet {
    /// Reads detections; boxes given only in a camera frame are rejected (fusion works in LiDAR).
    pub fn read(path: &Path) -> Result<Self, AutolabelError> {
        let dets = Detections::read(path)?;
        let mut frames = BTreeMap::new();
        for (id, list) in dets.frames {
            let mut objects = Vec::with_capacity(list.len());
            for d in list {
                let Some(b) = d.lidar else {
                    return Err(AutolabelError::invalid(
                        path,
                        format!("frame {id}: a detection has no LiDAR-frame box"),
                    ));
                };
                let mut o = Object::new(d.name, b);
                o.score = Some(d.score);
                objects.push(o);
            }
            frames.insert(id, objects);
        }
        Ok(Self { source: path.to_path_buf(), frames })
    }

    pub fn num_boxes(&self) -> usize {
        self.frames.values().map(Vec::len).sum()
    }

    /// Frame ids here that `known` does not hold: an error naming this set's file and the first one.
    pub fn check_frames<'a>(&self, known: impl IntoIterator<Item = &'a str>) -> Result<(), AutolabelError> {
        let known: std::collections::BTreeSet<&str> = known.into_iter().collect();
        let missing: Vec<&String> = self.frames.keys().filter(|id| !known.contains(id.as_str())).collect();
        match missing.first() {
            None => Ok(()),
            Some(first) => Err(AutolabelError::invalid(
                &self.source,
                format!("{} frame(s) are not in the data, the first is {first:?}", missing.len()),
            )),
        }
    }

    /// Writes one JSON line per frame (the format `pi3det eval` reads); `track_ids` per frame,
    /// when given, are written beside the boxes.
    pub fn write_jsonl(
        &self,
        path: &Path,
        track_ids: Option<&BTreeMap<String, Vec<u64>>>,
        overwrite: bool,
    ) -> Result<(), AutolabelError> {
        if path.exists() && !overwrite {
            return Err(AutolabelError::invalid(path, "exists; pass --overwrite to replace it"));
        }
        let file = std::fs::File::create(path).map_err(|e| AutolabelError::io(path, e))?;
        let mut w = std::io::BufWriter::new(file);
        for (id, objects) in &self.frames {
            let mut line = JsonlFrame::from_objects(id.clone(), objects);
            line.track_ids = track_ids.and_then(|t| t.get(id).cloned());
            let text = serde_json::to_string(&line).map_err(|e| AutolabelError::invalid(path, e.to_string()))?;
            writeln!(w, "{text}").map_err(|e| AutolabelError::io(path, e))?;
        }
        w.flush().map_err(|e| AutolabelError::io(path, e))
    }
}
