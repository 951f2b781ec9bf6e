//! Weighted box fusion (Solovyev et al., "Weighted boxes fusion", 2021) for upright 3D boxes:
//! the boxes several views or models give for one class are clustered greedily by BEV IoU with
//! each cluster's fused box, best score first, and every cluster becomes one box — the
//! score-weighted mean of its members — scored by the sum of each view's best member score over
//! the number of views, so a box every view agrees on keeps its score and one a single view saw
//! loses the others' share. Test-time augmentation uses it to merge its views.

use serde::{Deserialize, Serialize};

use crate::boxes::Box3d;
use crate::iou::BevFootprint;

/// How boxes are clustered and scored.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BoxFusionConfig {
    /// A box joins the cluster whose fused box it overlaps most in BEV, if at least this much.
    pub iou_threshold: f64,
}

impl Default for BoxFusionConfig {
    fn default() -> Self {
        Self { iou_threshold: 0.55 }
    }
}

/// One box to fuse: where it came from (`view` < the number of views) and its score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionMember {
    pub box3d: Box3d,
    pub score: f64,
    pub view: usize,
}

/// A fused box and how many members it has.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusedBox {
    pub box3d: Box3d,
    pub score: f64,
    pub members: usize,
}

/// Fuses the boxes of one class from `num_views` views (see the module header). Members with a
/// view index ≥ `num_views` or a non-finite score are left out. The result is sorted by score,
/// best first.
pub fn weighted_box_fusion(members: &[FusionMember], num_views: usize, cfg: &BoxFusionConfig) -> Vec<FusedBox> {
    let mut order: Vec<usize> =
        (0..members.len()).filter(|&i| members[i].view < num_views && members[i].score.is_finite()).collect();
    order.sort_by(|&i, &j| members[j].score.total_cmp(&members[i].score));
    // Per cluster: its members and its current fused box (with footprint).
    let mut clusters: Vec<(Vec<usize>, Box3d, BevFootprint)> = Vec::new();
    for i in order {
        let print = BevFootprint::new(&members[i].box3d);
        let best = clusters
            .iter()
            .enumerate()
            .map(|(c, (_, _, p))| (c, p.iou(&print)))
            .filter(|&(_, iou)| iou >= cfg.iou_threshold)
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((c, _)) => {
                let cluster = &mut clusters[c];
                cluster.0.push(i);
                cluster.1 = mean_box(members, &cluster.0);
                cluster.2 = BevFootprint::new(&cluster.1);
            }
            None => clusters.push((vec![i], members[i].box3d, print)),
        }
    }
    let mut out: Vec<FusedBox> = clusters
        .into_iter()
        .map(|(idx, box3d, _)| {
            let mut best = vec![0.0f64; num_views];
            for &i in &idx {
                best[members[i].view] = best[members[i].view].max(members[i].score);
            }
            FusedBox { box3d, score: best.iter().sum::<f64>() / num_views.max(1) as f64, members: idx.len() }
        })
        .collect();
    out.sort_by(|a, b| b.score.total_cmp(&a.score));
    out
}

/// The score-weighted mean of `idx`'s boxes. Headings are averaged as offsets from the first
/// (best) member's, each taken modulo π into (−π/2, π/2]: a box turned by π is the same box, and
/// the best member keeps the direction.
fn mean_box(members: &[FusionMember], idx: &[usize]) -> Box3d {
    let first = members[idx[0]].box3d;
    if idx.len() == 1 {
        return first;
    }
    let (mut w, mut acc, mut dh) = (0.0, [0.0f64; 6], 0.0);
    for &i in idx {
        let m = &members[i];
        let s = m.score.max(1e-6);
        let b = m.box3d;
        for (a, v) in acc.iter_mut().zip([b.x, b.y, b.z, b.dx, b.dy, b.dz]) {
            *a += s * v;
        }
        let mut d = (b.heading - first.heading).rem_euclid(std::f64::consts::PI);
        if d > std::f64::consts::FRAC_PI_2 {
            d -= std::f64::consts::PI;
        }
        dh += s * d;
        w += s;
    }
    let [x, y, z, dx, dy, dz] = acc.map(|a| a / w);
    Box3d { x, y, z, dx, dy, dz, heading: first.heading + dh / w }.with_wrapped_heading()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(x: f64, heading: f64, score: f64, view: usize) -> FusionMember {
        FusionMember { box3d: Box3d::new(x, 0.0, 0.0, 4.0, 2.0, 1.5, heading), score, view }
    }

    #[test]
    fn agreeing_views_make_one_weighted_box() {
        let cfg = BoxFusionConfig::default();
        let out = weighted_box_fusion(&[m(10.0, 0.0, 0.9, 0), m(10.3, 0.1, 0.3, 1)], 2, &cfg);
        assert_eq!(out.len(), 1);
        let b = out[0].box3d;
        assert!((b.x - (10.0 * 0.9 + 10.3 * 0.3) / 1.2).abs() < 1e-12);
        assert!((b.heading - 0.1 * 0.3 / 1.2).abs() < 1e-12);
        assert!((out[0].score - 0.6).abs() < 1e-12);
        assert_eq!(out[0].members, 2);
    }

    #[test]
    fn a_box_one_view_saw_keeps_its_share_of_the_score() {
        let cfg = BoxFusionConfig::default();
        let out = weighted_box_fusion(&[m(10.0, 0.0, 0.8, 0), m(30.0, 0.0, 0.6, 1)], 4, &cfg);
        assert_eq!(out.len(), 2);
        assert!((out[0].score - 0.2).abs() < 1e-12);
        assert!((out[1].score - 0.15).abs() < 1e-12);
        // Two boxes of one view in one cluster count that view once, at its best.
        let out = weighted_box_fusion(&[m(10.0, 0.0, 0.8, 0), m(10.1, 0.0, 0.5, 0)], 2, &cfg);
        assert_eq!(out.len(), 1);
        assert!((out[0].score - 0.4).abs() < 1e-12);
    }

    #[test]
    fn headings_a_half_turn_apart_average_as_one_direction() {
        let cfg = BoxFusionConfig::default();
        let pi = std::f64::consts::PI;
        let out = weighted_box_fusion(&[m(10.0, 0.05, 0.5, 0), m(10.0, 0.05 + pi - 0.1, 0.5, 1)], 2, &cfg);
        assert_eq!(out.len(), 1);
        assert!(out[0].box3d.heading.abs() < 1e-12, "{:?}", out[0].box3d);
    }

    #[test]
    fn bad_members_are_left_out() {
        let cfg = BoxFusionConfig::default();
        let out = weighted_box_fusion(&[m(10.0, 0.0, f64::NAN, 0), m(10.0, 0.0, 0.5, 7)], 2, &cfg);
        assert!(out.is_empty());
    }
}
