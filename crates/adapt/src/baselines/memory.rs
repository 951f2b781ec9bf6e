//! ST3D's quality-aware triplet memory (Yang et al. 2021, §3.2; ST3D++ keeps one per class): the
//! pseudo-labels of a target frame are not replaced at each refresh but merged with the new
//! detections. Each remembered box is matched to its best new box by 3D IoU (≥ `match_iou`,
//! one-to-one, pairs taken by falling IoU so two memories never claim one box); a matched pair
//! keeps the higher-scoring box and resets the counter. An unmatched memory counts up: from
//! `ignore_after` misses it is *ignored* (neither positive nor negative in training), from
//! `remove_after` it is dropped. New boxes no memory matched join with a counter of zero.

use pi3det_data::Object;
use pi3det_geometry::iou_3d;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MemoryConfig {
    pub match_iou: f64,
    pub ignore_after: u32,
    pub remove_after: u32,
    /// Match only boxes of the same class (ST3D++); ST3D matches across classes.
    pub per_class: bool,
}

impl Default for MemoryConfig {
    fn default() -> Self {
        Self { match_iou: 0.1, ignore_after: 2, remove_after: 3, per_class: false }
    }
}

/// One remembered pseudo-box.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryBox {
    pub object: Object,
    /// Refreshes in a row this box found no new match.
    pub misses: u32,
}

impl MemoryBox {
    pub fn new(object: Object) -> Self {
        Self { object, misses: 0 }
    }

    pub fn score(&self) -> f64 {
        self.object.score.unwrap_or(1.0)
    }
}

/// The memory of one frame after a refresh with `new` detections.
pub fn update(old: &[MemoryBox], new: &[Object], cfg: &MemoryConfig) -> Vec<MemoryBox> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, m) in old.iter().enumerate() {
        for (j, n) in new.iter().enumerate() {
            if cfg.per_class && m.object.name != n.name {
                continue;
            }
            let iou = iou_3d(&m.object.box3d, &n.box3d);
            if iou >= cfg.match_iou {
                pairs.push((iou, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let (mut old_match, mut new_taken) = (vec![None; old.len()], vec![false; new.len()]);
    for (_, i, j) in pairs {
        if old_match[i].is_none() && !new_taken[j] {
            old_match[i] = Some(j);
            new_taken[j] = true;
        }
    }
    let mut out = Vec::with_capacity(old.len() + new.len());
    for (m, matched) in old.iter().zip(&old_match) {
        match matched {
            Some(j) => {
                let n = &new[*j];
                let keep = if n.score.unwrap_or(1.0) > m.score() { n.clone() } else { m.object.clone() };
                out.push(MemoryBox { object: keep, misses: 0 });
            }
            None if m.misses + 1 >= cfg.remove_after => {}
            None => out.push(MemoryBox { object: m.object.clone(), misses: m.misses + 1 }),
        }
    }
    out.extend(new.iter().zip(&new_taken).filter(|(_, t)| !**t).map(|(n, _)| MemoryBox::new(n.clone())));
    out
}

/// The training labels of a frame's memory: boxes missed `ignore_after` times or more, and boxes
/// scoring below `positive_score`, get score 0 so the preprocessor's ignored band
/// ([`pi3det_nn::preprocess::Preprocessor::with_ignore_score_below`]) takes them.
pub fn training_labels(memory: &[MemoryBox], cfg: &MemoryConfig, positive_score: f64) -> Vec<Object> {
    memory
        .iter()
        .map(|m| {
            let ignored = m.misses >= cfg.ignore_after || m.score() < positive_score;
            Object { score: Some(if ignored { 0.0 } else { m.score() }), ..m.object.clone() }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::Box3d;

    fn obj(name: &str, x: f64, score: f64) -> Object {
        Object { score: Some(score), ..Object::new(name, Box3d::new(x, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0)) }
    }

    fn xs(m: &[MemoryBox]) -> Vec<(f64, f64, u32)> {
        m.iter().map(|b| (b.object.box3d.x, b.score(), b.misses)).collect()
    }

    #[test]
    fn match_keeps_the_higher_score_and_resets() {
        let cfg = MemoryConfig::default();
        let old = vec![MemoryBox { object: obj("Car", 0.0, 0.9), misses: 1 }, MemoryBox::new(obj("Car", 20.0, 0.4))];
        // x = 0.5: IoU 0.78 with the first memory (lower score); x = 20.3: IoU 0.86 (higher score).
        let new = vec![obj("Car", 0.5, 0.6), obj("Car", 20.3, 0.7)];
        assert_eq!(xs(&update(&old, &new, &cfg)), vec![(0.0, 0.9, 0), (20.3, 0.7, 0)]);
    }

    #[test]
    fn misses_count_then_ignore_then_remove() {
        let cfg = MemoryConfig::default();
        let mut m = vec![MemoryBox::new(obj("Car", 0.0, 0.9))];
        m = update(&m, &[], &cfg);
        assert_eq!(xs(&m), vec![(0.0, 0.9, 1)]);
        assert_eq!(training_labels(&m, &cfg, 0.6)[0].score, Some(0.9), "one miss still teaches");
        m = update(&m, &[], &cfg);
        assert_eq!(xs(&m), vec![(0.0, 0.9, 2)]);
        assert_eq!(training_labels(&m, &cfg, 0.6)[0].score, Some(0.0), "ignored at two misses");
        m = update(&m, &[], &cfg);
        assert!(m.is_empty(), "removed at three");
    }

    #[test]
    fn unmatched_new_boxes_join_and_empty_sets() {
        let cfg = MemoryConfig::default();
        let old = vec![MemoryBox::new(obj("Car", 0.0, 0.8))];
        // IoU below 0.1 (no overlap): no match; the new box joins, the old one counts a miss.
        let m = update(&old, &[obj("Car", 10.0, 0.3)], &cfg);
        assert_eq!(xs(&m), vec![(0.0, 0.8, 1), (10.0, 0.3, 0)]);
        assert_eq!(training_labels(&m, &cfg, 0.6)[1].score, Some(0.0), "below the positive score: ignored");
        assert_eq!(xs(&update(&[], &[obj("Car", 3.0, 0.5)], &cfg)), vec![(3.0, 0.5, 0)]);
        assert!(update(&[], &[], &cfg).is_empty());
    }

    #[test]
    fn one_new_box_matches_one_memory_and_classes_when_asked() {
        let cfg = MemoryConfig::default();
        let old = vec![MemoryBox::new(obj("Car", 0.0, 0.5)), MemoryBox::new(obj("Car", 0.6, 0.5))];
        let m = update(&old, &[obj("Car", 0.5, 0.9)], &cfg);
        // The closer memory (x = 0.6) takes the new box; the other counts a miss.
        assert_eq!(xs(&m), vec![(0.0, 0.5, 1), (0.5, 0.9, 0)]);
        let per_class = MemoryConfig { per_class: true, ..cfg };
        let m = update(&[MemoryBox::new(obj("Pedestrian", 0.0, 0.5))], &[obj("Car", 0.0, 0.9)], &per_class);
        assert_eq!(m.len(), 2, "no match across classes");
    }
}
