//! `--set KEY=VALUE` on `pi3det train` and `pi3det adapt`: one config key changed from the
//! command line, like OpenPCDet's `--set`, so a study over one setting needs no hand-edited copy
//! of the config. `KEY` is the dotted path in the TOML file (`detector.pfa.kl_weight`,
//! `pseudo_labels.positive_score`; a number indexes an array of tables:
//! `detector.head.anchors.0.matched_threshold`); `VALUE` is a TOML value (`0.2`, `true`,
//! `[1, 2]`, `"moments"`), a bare word being taken as a string. Overrides are applied to the
//! file's table before it is read, so an unknown key or a value of the wrong type is refused like
//! the same mistake in the file, and the run's saved config records the result.

use std::path::Path;
use std::str::FromStr;

use crate::error::{NnError, Result};

/// One `KEY=VALUE` override.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigOverride {
    /// The dotted key, split.
    pub path: Vec<String>,
    pub value: toml::Value,
}

impl FromStr for ConfigOverride {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let (key, raw) = s.split_once('=').ok_or_else(|| format!("--set {s:?}: expected KEY=VALUE"))?;
        let path: Vec<String> = key.trim().split('.').map(|p| p.trim().to_string()).collect();
        if path.iter().any(String::is_empty) {
            return Err(format!("--set {s:?}: empty part in the key {key:?}"));
        }
        let raw = raw.trim();
        // A TOML value when it parses as one; otherwise the text itself (`kl_estimator=mixture`).
        let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| toml::Value::String(raw.to_string()));
        Ok(Self { path, value })
    }
}

impl ConfigOverride {
    pub fn key(&self) -> String {
        self.path.join(".")
    }

    /// Sets the value in `table`, creating missing tables on the way (an optional section the
    /// file leaves out); refuses to descend into a value that is neither a table nor an array.
    pub fn apply(&self, table: &mut toml::Table) -> std::result::Result<(), String> {
        let (first, _) = self.path.split_first().expect("a parsed key has a part");
        let child = table.entry(first.clone()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        set(child, &self.path, 1, &self.value).map_err(|why| format!("--set {}: {why}", self.key()))
    }
}

/// Sets `path[done..]` below `node` (the value at `path[..done]`) to `value`.
fn set(node: &mut toml::Value, path: &[String], done: usize, value: &toml::Value) -> std::result::Result<(), String> {
    let Some(part) = path.get(done) else {
        *node = value.clone();
        return Ok(());
    };
    let at = path[..done].join(".");
    let child = match node {
        toml::Value::Table(t) => t.entry(part.clone()).or_insert_with(|| toml::Value::Table(toml::Table::new())),
        toml::Value::Array(items) => {
            let n = items.len();
            let i: usize = part.parse().map_err(|_| format!("{at} is an array: index it with a number ({at}.0)"))?;
            items.get_mut(i).ok_or_else(|| format!("{at} has {n} entries, none at index {i}"))?
        }
        other => return Err(format!("{at} is not a table but a value of type {}", other.type_str())),
    };
    set(child, path, done + 1, value)
}

/// A config file read with `overrides` applied, refused with the file's name when it does not
/// parse, an override does not fit, or the result is not a `T`.
pub fn read_config<T: serde::de::DeserializeOwned>(path: &Path, overrides: &[ConfigOverride]) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| NnError::io(path, e))?;
    let bad = |message: String| NnError::ConfigFile { path: path.to_path_buf(), message };
    if overrides.is_empty() {
        // Straight from the text: the parser's errors then point at the line.
        return toml::from_str(&text).map_err(|e| bad(e.to_string()));
    }
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| bad(e.to_string()))?;
    overrides.iter().try_for_each(|o| o.apply(&mut table)).map_err(bad)?;
    toml::Value::Table(table).try_into().map_err(|e: toml::de::Error| {
        let keys: Vec<String> = overrides.iter().map(ConfigOverride::key).collect();
        bad(format!("{} (with --set {})", e.message().trim_end(), keys.join(", ")))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn set(s: &str) -> ConfigOverride {
        s.parse().unwrap()
    }

    #[test]
    fn values_parse_as_toml_and_bare_words_as_strings() {
        assert_eq!(set("a.b=0.2").value, toml::Value::Float(0.2));
        assert_eq!(set(" a.b = 3 ").path, vec!["a", "b"]);
        assert_eq!(set("a=true").value, toml::Value::Boolean(true));
        assert_eq!(set("a=[1, 2]").value, toml::Value::Array(vec![1.into(), 2.into()]));
        assert_eq!(set("a=\"x y\"").value, toml::Value::String("x y".into()));
        assert_eq!(set("a=mixture").value, toml::Value::String("mixture".into()));
        for bad in ["a.b", "a..b=1", "=1", "a.=1"] {
            assert!(bad.parse::<ConfigOverride>().is_err(), "{bad:?} was accepted");
        }
    }

    #[test]
    fn apply_sets_nested_keys_creates_tables_and_indexes_arrays() {
        let mut t: toml::Table = toml::from_str("[x]\ny = 1\n[[z]]\nw = 1\n[[z]]\nw = 2\n").unwrap();
        set("x.y=5").apply(&mut t).unwrap();
        set("new.deep.k=\"v\"").apply(&mut t).unwrap();
        set("z.1.w=7").apply(&mut t).unwrap();
        let want: toml::Table =
            toml::from_str("[x]\ny = 5\n[new.deep]\nk = \"v\"\n[[z]]\nw = 1\n[[z]]\nw = 7\n").unwrap();
        assert_eq!(t, want);
        let err = |s: &str| set(s).apply(&mut t.clone()).unwrap_err();
        assert!(err("x.y.q=1").contains("x.y is not a table but a value of type integer"), "{}", err("x.y.q=1"));
        assert!(err("z.w=1").contains("index it with a number"), "{}", err("z.w=1"));
        assert!(err("z.2.w=1").contains("z has 2 entries"), "{}", err("z.2.w=1"));
    }
}
