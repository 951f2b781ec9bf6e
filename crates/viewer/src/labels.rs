//! Corrected labels written as a new, numbered label set beside the data; the original files are
//! never written. Each save writes `labels.<set>-<NNN>.jsonl` (the JSON lines `pi3det eval`
//! reads) and, for a Pi3DET-layout dataset, `pi3det_infos_<split>.<set>-<NNN>.pkl` per info
//! file, pointing at the existing point files.

use std::path::{Path, PathBuf};

use pi3det_data::{pi3det, Format, FrameInfo};
use pi3det_eval::JsonlFrame;

use crate::error::ViewerError;
use crate::scene::Source;

/// Where and under which name label sets of one dataset are written.
#[derive(Debug, Clone)]
pub struct LabelSetWriter {
    set: String,
    jsonl_dir: PathBuf,
    /// Pi3DET only: the original info files, with how many frames (in dataset order) each holds.
    pi3det_files: Vec<(PathBuf, usize)>,
}

/// One written label set.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SavedSet {
    pub version: u32,
    pub files: Vec<PathBuf>,
}

/// Label-set names go into file names: keep them plain.
pub fn check_set_name(set: &str) -> Result<(), ViewerError> {
    if set.is_empty() || !set.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        return Err(ViewerError::Option(format!("--label-set {set:?}: use letters, digits, '_' and '-' only")));
    }
    Ok(())
}

impl LabelSetWriter {
    pub fn new(src: &Source, set: &str) -> Result<Self, ViewerError> {
        check_set_name(set)?;
        let mut pi3det_files = Vec::new();
        if src.dataset.format() == Format::Pi3det {
            let files = if src.path.is_file() { vec![src.path.clone()] } else { pi3det::info_files(&src.path)? };
            for f in files {
                let n = pi3det::read_infos(src.dataset.root(), &f)?.len();
                pi3det_files.push((f, n));
            }
            let total: usize = pi3det_files.iter().map(|(_, n)| n).sum();
            if total != src.infos.len() {
                return Err(ViewerError::invalid(
                    &src.path,
                    format!("info files hold {total} frames but the dataset has {}", src.infos.len()),
                ));
            }
        }
        Ok(Self { set: set.to_string(), jsonl_dir: src.dataset.root().to_path_buf(), pi3det_files })
    }

    /// `(folder, name before the number, name after it)` of every file a save writes.
    fn templates(&self) -> Vec<(PathBuf, String, String)> {
        let mut t: Vec<_> = self
            .pi3det_files
            .iter()
            .map(|(f, _)| {
                let dir = f.parent().unwrap_or(Path::new(".")).to_path_buf();
                let name = f.file_name().and_then(|n| n.to_str()).unwrap_or("infos.pkl");
                // Editing a label set again numbers from its base: x.edit-001.pkl → x.edit-002.pkl.
                let base = name.split('.').next().unwrap_or(name);
                (dir, format!("{base}.{}-", self.set), ".pkl".to_string())
            })
            .collect();
        t.push((self.jsonl_dir.clone(), format!("labels.{}-", self.set), ".jsonl".to_string()));
        t
    }

    /// One more than the highest number any file of this label set already has.
    pub fn next_version(&self) -> Result<u32, ViewerError> {
        let mut top = 0;
        for (dir, pre, post) in self.templates() {
            for e in std::fs::read_dir(&dir).map_err(|e| ViewerError::io(&dir, e))? {
                let name = e.map_err(|e| ViewerError::io(&dir, e))?.file_name();
                let v = name
                    .to_str()
                    .and_then(|n| n.strip_prefix(pre.as_str()))
                    .and_then(|n| n.strip_suffix(post.as_str()))
                    .and_then(|n| n.parse::<u32>().ok());
                top = top.max(v.unwrap_or(0));
            }
        }
        Ok(top + 1)
    }

    pub fn paths(&self, version: u32) -> Vec<PathBuf> {
        self.templates().into_iter().map(|(dir, pre, post)| dir.join(format!("{pre}{version:03}{post}"))).collect()
    }

    /// Writes `infos` (every frame of the dataset, in order, with corrected objects) as the next
    /// version. Existing files are never replaced.
    pub fn save(&self, infos: &[FrameInfo]) -> Result<SavedSet, ViewerError> {
        let version = self.next_version()?;
        let paths = self.paths(version);
        if let Some(p) = paths.iter().find(|p| p.exists()) {
            return Err(ViewerError::Exists { path: p.clone() });
        }
        let mut start = 0;
        for ((_, n), path) in self.pi3det_files.iter().zip(&paths) {
            pi3det::write_infos(path, &infos[start..start + n], false)?;
            start += n;
        }
        let jsonl = paths.last().expect("the JSON-lines file is always written");
        let mut text = String::new();
        for info in infos {
            let line = serde_json::to_string(&JsonlFrame::from_objects(info.id.clone(), &info.objects))
                .map_err(|e| ViewerError::invalid(jsonl, e.to_string()))?;
            text.push_str(&line);
            text.push('\n');
        }
        pi3det_data::io::write_atomic(jsonl, text.as_bytes(), false)?;
        Ok(SavedSet { version, files: paths })
    }
}
