//! Clusters of detections for fusion: MS3D++'s ball query on 3-D centres — one ball per box,
//! identical balls once, a ball kept with at least `min_members` boxes at as many distinct
//! centres (members repeated by test-time augmentation or duplicate detectors do not count twice).

use std::collections::{BTreeSet, HashMap};

/// Sorted member indices of each kept ball, in a deterministic order.
pub fn ball_clusters(centres: &[[f64; 3]], radius_m: f64, min_members: usize) -> Vec<Vec<usize>> {
    let cell = |c: &[f64; 3]| -> [i64; 3] { [0, 1, 2].map(|k| (c[k] / radius_m).floor() as i64) };
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, c) in centres.iter().enumerate() {
        grid.entry(cell(c)).or_default().push(i);
    }
    let r2 = radius_m * radius_m;
    let mut balls = BTreeSet::new();
    for c in centres {
        let k = cell(c);
        let mut members = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(ids) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        // Inclusive, as scipy's `query_ball_point`.
                        members.extend(ids.iter().copied().filter(|&j| dist2(c, &centres[j]) <= r2));
                    }
                }
            }
        }
        if members.len() >= min_members {
            members.sort_unstable();
            balls.insert(members);
        }
    }
    balls.into_iter().filter(|m| distinct_centres(centres, m) >= min_members).collect()
}

fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// Centres counted as equal when they agree to 4 decimals (numpy `round(4)` + `unique`).
fn distinct_centres(centres: &[[f64; 3]], members: &[usize]) -> usize {
    let keys: BTreeSet<[i64; 3]> = members.iter().map(|&i| centres[i].map(|v| (v * 1e4).round() as i64)).collect();
    keys.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn balls_by_hand() {
        // Three boxes within 1 m of each other, a fourth 1.2 m from the first only, one far away.
        let c = [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.6, 0.0], [-1.2, 0.0, 0.0], [10.0, 0.0, 0.0]];
        let balls = ball_clusters(&c, 1.0, 3);
        assert_eq!(balls, vec![vec![0, 1, 2]]);
        let balls = ball_clusters(&c, 1.25, 3);
        // Ball of 0: {0,1,2,3}; of 1: {0,1,2}; of 2: {0,1,2}; of 3: {0,3}.
        assert_eq!(balls, vec![vec![0, 1, 2], vec![0, 1, 2, 3]]);
    }

    #[test]
    fn repeated_centres_do_not_count_twice() {
        let c = [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.00001, 1.0, 0.0], [1.2, 1.0, 0.0]];
        assert!(ball_clusters(&c, 1.0, 3).is_empty());
        assert_eq!(ball_clusters(&c, 1.0, 2), vec![vec![0, 1, 2, 3]]);
    }

    #[test]
    fn the_radius_is_inclusive() {
        let c = [[0.0, 0.0, 0.0], [1.5, 0.0, 0.0]];
        assert_eq!(ball_clusters(&c, 1.5, 2), vec![vec![0, 1]]);
    }
}
