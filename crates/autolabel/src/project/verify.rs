//! The open-vocabulary class check hook: the paper asks a vision foundation model whether each
//! crop shows the labelled class; no such weights ship here, so `--verify-cmd` hands every crop
//! to an external command and records its answer.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

use image::RgbImage;

use crate::error::AutolabelError;

/// Runs `sh -c TEMPLATE` per crop with `{crop}` and `{class}` bound to the crop's PNG path and
/// the class name (passed as positional arguments, so no value is ever parsed by the shell).
pub struct Verifier {
    script: String,
    dir: PathBuf,
    next: AtomicUsize,
}

impl Verifier {
    pub fn new(template: &str) -> Result<Self, AutolabelError> {
        if !template.contains("{crop}") {
            return Err(AutolabelError::Input(format!("--verify-cmd {template:?}: it should contain {{crop}}")));
        }
        let stamp = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!("pi3det-verify-{}-{stamp}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| AutolabelError::io(&dir, e))?;
        let script = template.replace("{crop}", "\"$1\"").replace("{class}", "\"$2\"");
        Ok(Self { script, dir, next: AtomicUsize::new(0) })
    }

    /// The command's first stdout line, or why there is none.
    pub fn verify(&self, crop: &RgbImage, class: &str) -> Result<String, String> {
        let path = self.dir.join(format!("crop_{}.png", self.next.fetch_add(1, Ordering::Relaxed)));
        crop.save_with_format(&path, image::ImageFormat::Png).map_err(|e| format!("{}: {e}", path.display()))?;
        let out = Command::new("sh")
            .arg("-c")
            .arg(&self.script)
            .arg("pi3det-verify")
            .arg(&path)
            .arg(class)
            .output()
            .map_err(|e| format!("could not run sh: {e}"));
        let _ = std::fs::remove_file(&path);
        let out = out?;
        let first = |b: &[u8]| String::from_utf8_lossy(b).lines().next().unwrap_or("").trim().to_string();
        if out.status.success() {
            Ok(first(&out.stdout))
        } else {
            Err(format!("{}: {}", out.status, first(&out.stderr)))
        }
    }
}

impl Drop for Verifier {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_the_command_with_crop_and_class() {
        let v = Verifier::new("printf '%s\\n' \"$(basename {crop})\" {class}; echo second").unwrap();
        let crop = RgbImage::new(4, 3);
        let answer = v.verify(&crop, "Car; rm -rf /").unwrap();
        assert!(answer.starts_with("crop_") && answer.ends_with(".png"), "{answer}");
        let fails = Verifier::new("echo nope >&2; test -f {crop} && exit 3").unwrap();
        assert_eq!(fails.verify(&crop, "Car").unwrap_err(), "exit status: 3: nope");
        assert!(Verifier::new("echo {class}").is_err());
    }
}
