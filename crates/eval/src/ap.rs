//! Score thresholds, precision / recall / orientation curves and R11 / R40 average precision,
//! as the reference's `get_thresholds`, `eval_class` and `get_mAP` / `get_mAP_R40` compute them.

/// Sample points of the curves; slot `i` belongs to the `i`-th score threshold, not to recall
/// `i / 40` (which is why one found GT gives R40 = 0 and R11 = 100/11).
pub const N_SAMPLE_PTS: usize = 41;

/// The reference's `get_thresholds`: walks the TP scores in descending order and keeps a score
/// each time recall passes the next of the 41 recall positions. The float arithmetic (recall as
/// `(i+1)/num_gt`, the running sum of 1/40) is kept as is: it decides ties.
pub fn get_thresholds(tp_scores: &mut [f64], num_gt: usize) -> Vec<f64> {
    // Descending, NaN-free (scores are validated on input).
    tp_scores.sort_unstable_by(|a, b| b.total_cmp(a));
    let n = tp_scores.len();
    let num_gt = num_gt as f64;
    let step = 1.0 / (N_SAMPLE_PTS as f64 - 1.0);
    let mut current_recall = 0.0f64;
    let mut out = Vec::with_capacity(N_SAMPLE_PTS);
    for (i, &score) in tp_scores.iter().enumerate() {
        let l_recall = (i + 1) as f64 / num_gt;
        let r_recall = if i < n - 1 { (i + 2) as f64 / num_gt } else { l_recall };
        if (r_recall - current_recall) < (current_recall - l_recall) && i < n - 1 {
            continue;
        }
        out.push(score);
        current_recall += step;
    }
    // Cannot exceed 41 (see the bound in the module tests); the reference would index out of
    // its arrays, we keep the first 41.
    out.truncate(N_SAMPLE_PTS);
    out
}

/// Totals of one score threshold over all frames: `[tp, fp, fn]` and the AOS similarity sum.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PrCounts {
    pub tp: u64,
    pub fp: u64,
    pub fn_: u64,
    pub similarity: f64,
}

/// Precision, recall and orientation-similarity curves (41 slots; unused slots stay 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Curves {
    pub precision: [f64; N_SAMPLE_PTS],
    pub recall: [f64; N_SAMPLE_PTS],
    pub aos: [f64; N_SAMPLE_PTS],
}

/// `np.max(x[i:])` propagates NaN (0/0 precision at a threshold with neither TP nor FP).
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

fn suffix_max(v: &mut [f64; N_SAMPLE_PTS]) {
    for i in (0..N_SAMPLE_PTS - 1).rev() {
        v[i] = nan_max(v[i], v[i + 1]);
    }
}

pub fn curves(pr: &[PrCounts]) -> Curves {
    let mut c = Curves { precision: [0.0; N_SAMPLE_PTS], recall: [0.0; N_SAMPLE_PTS], aos: [0.0; N_SAMPLE_PTS] };
    for (i, p) in pr.iter().take(N_SAMPLE_PTS).enumerate() {
        let (tp, fp, fn_) = (p.tp as f64, p.fp as f64, p.fn_ as f64);
        c.recall[i] = tp / (tp + fn_);
        c.precision[i] = tp / (tp + fp);
        c.aos[i] = p.similarity / (tp + fp);
    }
    suffix_max(&mut c.precision);
    suffix_max(&mut c.recall);
    suffix_max(&mut c.aos);
    c
}

/// 11-point AP (slots 0, 4, …, 40), in percent.
pub fn ap_r11(p: &[f64; N_SAMPLE_PTS]) -> f64 {
    let mut sum = 0.0;
    for i in (0..N_SAMPLE_PTS).step_by(4) {
        sum += p[i];
    }
    sum / 11.0 * 100.0
}

/// 40-point AP (slots 1..=40), in percent.
pub fn ap_r40(p: &[f64; N_SAMPLE_PTS]) -> f64 {
    let mut sum = 0.0;
    for v in &p[1..] {
        sum += v;
    }
    sum / 40.0 * 100.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds_of_perfect_detections() {
        // 41 GT all found with distinct scores: one threshold per recall position.
        let mut s: Vec<f64> = (0..41).map(|i| 0.5 + i as f64 * 0.01).collect();
        let t = get_thresholds(&mut s, 41);
        assert_eq!(t.len(), 41);
        // One GT found: a single threshold.
        assert_eq!(get_thresholds(&mut [0.9], 1), vec![0.9]);
        assert!(get_thresholds(&mut [], 0).is_empty());
    }

    #[test]
    fn never_more_than_41_thresholds() {
        for n in 1..300 {
            let mut s: Vec<f64> = (0..n).map(|i| i as f64).collect();
            assert!(get_thresholds(&mut s, n).len() <= N_SAMPLE_PTS, "{n}");
        }
    }

    #[test]
    fn ap_of_constant_precision() {
        let p = [1.0; N_SAMPLE_PTS];
        assert!((ap_r40(&p) - 100.0).abs() < 1e-12);
        assert!((ap_r11(&p) - 100.0).abs() < 1e-12);
        let mut q = [0.0; N_SAMPLE_PTS];
        q[0] = 1.0;
        assert_eq!(ap_r40(&q), 0.0);
        assert!((ap_r11(&q) - 100.0 / 11.0).abs() < 1e-12);
    }

    #[test]
    fn curves_take_suffix_max_and_keep_nan() {
        let pr =
            [PrCounts { tp: 1, fp: 1, fn_: 1, similarity: 1.0 }, PrCounts { tp: 2, fp: 0, fn_: 0, similarity: 2.0 }];
        let c = curves(&pr);
        assert_eq!(c.precision[0], 1.0);
        assert_eq!(c.precision[1], 1.0);
        assert_eq!(c.recall[0], 1.0);
        assert_eq!(c.aos[0], 1.0);
        assert_eq!(c.precision[2], 0.0);
        let c = curves(&[PrCounts { tp: 1, fp: 0, fn_: 0, similarity: 1.0 }, PrCounts::default()]);
        assert!(c.precision[0].is_nan());
    }
}
