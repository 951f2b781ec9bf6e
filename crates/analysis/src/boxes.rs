//! Box statistics (appendix Tables 12–14): length, width and height per class, objects per frame
//! and points per box.

use std::collections::BTreeMap;

use pi3det_data::Object;
use serde::Serialize;

use crate::error::AnalysisError;
use crate::histogram::Histogram;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClassStats {
    /// Box `dx` (along the heading), `dy`, `dz`.
    pub length_m: Histogram,
    pub width_m: Histogram,
    pub height_m: Histogram,
    /// Points inside the box (inclusive test on the frame's points), binned as log10(1 + n).
    pub points_per_box: Histogram,
}

impl ClassStats {
    pub fn new(bins: usize) -> Self {
        Self {
            // Up to 20 m: buses and trams exceed 10 m (paper appendix).
            length_m: Histogram::new(0.0, 20.0, bins),
            width_m: Histogram::new(0.0, 5.0, bins),
            height_m: Histogram::new(0.0, 5.0, bins),
            points_per_box: points_histogram(bins),
        }
    }

    pub fn count(&self) -> u64 {
        self.length_m.count()
    }

    fn merge(&mut self, o: &ClassStats) -> Result<(), AnalysisError> {
        self.length_m.merge(&o.length_m)?;
        self.width_m.merge(&o.width_m)?;
        self.height_m.merge(&o.height_m)?;
        self.points_per_box.merge(&o.points_per_box)
    }
}

fn points_histogram(bins: usize) -> Histogram {
    Histogram::log10p1(0.0, 1e6, bins)
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxStats {
    bins: usize,
    pub classes: BTreeMap<String, ClassStats>,
    /// All classes together; one value per frame (frames without objects count as 0).
    pub objects_per_frame: Histogram,
    pub points_per_box: Histogram,
}

impl BoxStats {
    pub fn new(bins: usize) -> Self {
        Self {
            bins,
            classes: BTreeMap::new(),
            objects_per_frame: Histogram::new(0.0, 200.0, 200),
            points_per_box: points_histogram(bins),
        }
    }

    /// A frame's objects and the number of points inside each (same order).
    pub fn add_frame(&mut self, objects: &[Object], points_inside: &[usize]) {
        self.objects_per_frame.add(objects.len() as f64);
        for (o, &n) in objects.iter().zip(points_inside) {
            let c = self.classes.entry(o.name.clone()).or_insert_with(|| ClassStats::new(self.bins));
            c.length_m.add(o.box3d.dx);
            c.width_m.add(o.box3d.dy);
            c.height_m.add(o.box3d.dz);
            c.points_per_box.add(n as f64);
            self.points_per_box.add(n as f64);
        }
    }

    /// Objects of a class per frame, over `frames` frames.
    pub fn class_per_frame(&self, class: &str) -> f64 {
        let frames = self.objects_per_frame.count().max(1) as f64;
        self.classes.get(class).map_or(0.0, |c| c.count() as f64 / frames)
    }

    pub fn merge(&mut self, o: &BoxStats) -> Result<(), AnalysisError> {
        self.objects_per_frame.merge(&o.objects_per_frame)?;
        self.points_per_box.merge(&o.points_per_box)?;
        for (k, v) in &o.classes {
            match self.classes.get_mut(k) {
                Some(c) => c.merge(v)?,
                None => {
                    self.classes.insert(k.clone(), v.clone());
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::Box3d;

    #[test]
    fn sizes_counts_and_points_per_class() {
        let car = |l| Object::new("Car", Box3d::new(10.0, 0.0, -1.0, l, 2.0, 1.6, 0.0));
        let ped = Object::new("Pedestrian", Box3d::new(5.0, 1.0, -0.8, 0.8, 0.6, 1.8, 0.0));
        let mut a = BoxStats::new(100);
        a.add_frame(&[car(4.0), car(5.0), ped.clone()], &[100, 300, 9]);
        let mut b = BoxStats::new(100);
        b.add_frame(&[], &[]);
        a.merge(&b).unwrap();
        let c = &a.classes["Car"];
        assert_eq!(c.count(), 2);
        assert_eq!((c.length_m.moments.mean, c.width_m.moments.mean, c.height_m.moments.mean), (4.5, 2.0, 1.6));
        assert_eq!(c.points_per_box.moments.mean, 200.0);
        assert_eq!(a.objects_per_frame.moments.mean, 1.5);
        assert_eq!(a.class_per_frame("Car"), 1.0);
        assert_eq!(a.class_per_frame("Cyclist"), 0.0);
        assert_eq!(a.points_per_box.moments.count, 3);
        assert!((a.classes["Pedestrian"].points_per_box.quantile(0.5).unwrap() - 9.0).abs() < 1e-9);
    }
}
