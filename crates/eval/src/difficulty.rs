//! KITTI difficulty and class filtering: the reference's `clean_data`, quirks included.

/// Easy, moderate, hard.
pub const DIFFICULTIES: [&str; 3] = ["easy", "moderate", "hard"];
pub const MIN_HEIGHT: [f64; 3] = [40.0, 25.0, 25.0];
pub const MAX_OCCLUSION: [f64; 3] = [0.0, 1.0, 2.0];
pub const MAX_TRUNCATION: [f64; 3] = [0.15, 0.3, 0.5];

/// A ground truth as `clean_data` reads it.
#[derive(Debug, Clone)]
pub(crate) struct GtFields {
    pub name_lc: String,
    pub height: f64,
    pub occluded: f64,
    pub truncated: f64,
}

/// Ground truth state for one class and difficulty: 0 counts, 1 is ignored (consumes a
/// detection without counting), -1 takes no part.
pub(crate) fn ignored_gt(g: &GtFields, class_lc: &str, difficulty: usize) -> i8 {
    let valid_class = if g.name_lc == class_lc {
        1
    } else if crate::classes::is_neighbour(class_lc, &g.name_lc) {
        0
    } else {
        -1
    };
    let too_hard = g.occluded > MAX_OCCLUSION[difficulty]
        || g.truncated > MAX_TRUNCATION[difficulty]
        || g.height <= MIN_HEIGHT[difficulty];
    match (valid_class, too_hard) {
        (1, false) => 0,
        (0, _) | (1, true) => 1,
        _ => -1,
    }
}

/// Detection state: too small in the image is ignored (1) whatever its class — a quirk of the
/// reference kept on purpose — otherwise 0 for the class and -1 for any other.
pub(crate) fn ignored_dt(name_lc: &str, height_abs: f64, class_lc: &str, difficulty: usize) -> i8 {
    if height_abs < MIN_HEIGHT[difficulty] {
        1
    } else if name_lc == class_lc {
        0
    } else {
        -1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gt(name: &str, height: f64, occ: f64, trunc: f64) -> GtFields {
        GtFields { name_lc: name.to_string(), height, occluded: occ, truncated: trunc }
    }

    #[test]
    fn clean_data_rules() {
        assert_eq!(ignored_gt(&gt("car", 50.0, 0.0, 0.0), "car", 0), 0);
        // Height must be strictly above the minimum.
        assert_eq!(ignored_gt(&gt("car", 40.0, 0.0, 0.0), "car", 0), 1);
        assert_eq!(ignored_gt(&gt("car", 40.0, 0.0, 0.0), "car", 1), 0);
        assert_eq!(ignored_gt(&gt("car", 50.0, 1.0, 0.0), "car", 0), 1);
        assert_eq!(ignored_gt(&gt("car", 50.0, 0.0, 0.2), "car", 1), 0);
        assert_eq!(ignored_gt(&gt("van", 50.0, 0.0, 0.0), "car", 0), 1);
        assert_eq!(ignored_gt(&gt("person_sitting", 5.0, 3.0, 0.9), "pedestrian", 2), 1);
        assert_eq!(ignored_gt(&gt("pedestrian", 50.0, 0.0, 0.0), "car", 0), -1);
        assert_eq!(ignored_gt(&gt("dontcare", 50.0, 0.0, 0.0), "car", 0), -1);
        assert_eq!(ignored_dt("pedestrian", 20.0, "car", 2), 1);
        assert_eq!(ignored_dt("car", 25.0, "car", 2), 0);
        assert_eq!(ignored_dt("pedestrian", 30.0, "car", 2), -1);
    }
}
