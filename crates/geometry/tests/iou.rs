//! Properties of the exact rotated IoU: symmetry, identity, containment, rigid invariance,
//! agreement with Monte-Carlo, and the edge cases that break float32 kernels.

use pi3det_geometry::{bev_iou, bev_iou_matrix, iou_3d, iou_3d_matrix, BevFootprint, Box3d, Pose, PoseExt};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

fn random_box(rng: &mut ChaCha8Rng, spread: f64) -> Box3d {
    Box3d::new(
        rng.random_range(-spread..spread),
        rng.random_range(-spread..spread),
        rng.random_range(-0.5..0.5),
        rng.random_range(0.3..5.0),
        rng.random_range(0.3..3.0),
        rng.random_range(0.5..2.5),
        rng.random_range(-PI..PI),
    )
}

#[test]
fn symmetric_and_bounded() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..2000 {
        let (a, b) = (random_box(&mut rng, 2.0), random_box(&mut rng, 2.0));
        let (ab, ba) = (bev_iou(&a, &b), bev_iou(&b, &a));
        assert!((ab - ba).abs() < 1e-12, "{a:?} {b:?}");
        assert!((0.0..=1.0).contains(&ab));
        let (ab3, ba3) = (iou_3d(&a, &b), iou_3d(&b, &a));
        assert!((ab3 - ba3).abs() < 1e-12);
    }
}

#[test]
fn identical_boxes_give_one() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for _ in 0..1000 {
        let a = random_box(&mut rng, 80.0);
        assert!((bev_iou(&a, &a) - 1.0).abs() < 1e-9, "{a:?}");
        assert!((iou_3d(&a, &a) - 1.0).abs() < 1e-9, "{a:?}");
    }
    // Axis-aligned, 45°, and far from the origin: the float32 reference fails on these.
    for h in [0.0, FRAC_PI_4, FRAC_PI_2, PI, -2.9] {
        let a = Box3d::new(70.3, -41.7, 1.0, 4.2, 1.9, 1.6, h);
        assert!((bev_iou(&a, &a) - 1.0).abs() < 1e-9);
        assert!((iou_3d(&a, &a) - 1.0).abs() < 1e-9);
    }
}

#[test]
fn heading_flip_is_same_footprint() {
    let a = Box3d::new(3.0, 4.0, 0.0, 4.0, 2.0, 1.5, 0.4);
    let b = Box3d { heading: 0.4 + PI, ..a };
    assert!((bev_iou(&a, &b) - 1.0).abs() < 1e-9);
}

#[test]
fn containment_gives_volume_ratio() {
    let outer = Box3d::new(1.0, 2.0, 0.0, 6.0, 4.0, 3.0, 0.7);
    let inner = Box3d::new(1.2, 2.1, 0.2, 2.0, 1.0, 1.0, 0.9);
    let expected_bev = (2.0 * 1.0) / (6.0 * 4.0);
    assert!((bev_iou(&outer, &inner) - expected_bev).abs() < 1e-12);
    let expected_3d = inner.volume() / outer.volume();
    assert!((iou_3d(&outer, &inner) - expected_3d).abs() < 1e-12);
}

#[test]
fn invariant_under_common_rigid_motion() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..500 {
        let (a, b) = (random_box(&mut rng, 3.0), random_box(&mut rng, 3.0));
        let t = Pose::from_xyz_rpy(
            [rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0), rng.random_range(-5.0..5.0)],
            0.0,
            0.0,
            rng.random_range(-PI..PI),
        );
        let (ta, tb) = (a.transformed(&t), b.transformed(&t));
        assert!((bev_iou(&a, &b) - bev_iou(&ta, &tb)).abs() < 1e-9);
        assert!((iou_3d(&a, &b) - iou_3d(&ta, &tb)).abs() < 1e-9);
    }
}

/// Monte-Carlo estimate of the 3D IoU: the fraction of points sampled uniformly inside `a` that
/// also fall inside `b` estimates the intersection volume (standard error < 0.002 at n = 100k).
fn monte_carlo_iou_3d(a: &Box3d, b: &Box3d, rng: &mut ChaCha8Rng, n: usize) -> f64 {
    let (s, c) = a.heading.sin_cos();
    let mut hits = 0usize;
    for _ in 0..n {
        let u = rng.random_range(-0.5..0.5) * a.dx;
        let v = rng.random_range(-0.5..0.5) * a.dy;
        let w = rng.random_range(-0.5..0.5) * a.dz;
        hits += b.contains([a.x + c * u - s * v, a.y + s * u + c * v, a.z + w]) as usize;
    }
    let inter = hits as f64 / n as f64 * a.volume();
    inter / (a.volume() + b.volume() - inter)
}

#[test]
fn agrees_with_monte_carlo() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut worst: f64 = 0.0;
    for _ in 0..1000 {
        let a = random_box(&mut rng, 1.5);
        let b = random_box(&mut rng, 1.5);
        let exact = iou_3d(&a, &b);
        let mc = monte_carlo_iou_3d(&a, &b, &mut rng, 100_000);
        worst = worst.max((exact - mc).abs());
        assert!((exact - mc).abs() < 0.01, "exact {exact} mc {mc} for {a:?} {b:?}");
    }
    eprintln!("worst |exact - monte carlo| = {worst:.4}");
}

#[test]
fn touching_and_disjoint_are_zero() {
    let a = Box3d::new(0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0);
    let side = Box3d::new(2.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0);
    let corner = Box3d::new(2.0, 2.0, 0.0, 2.0, 2.0, 2.0, 0.0);
    let above = Box3d::new(0.0, 0.0, 2.0, 2.0, 2.0, 2.0, 0.0);
    let far = Box3d::new(100.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.3);
    for b in [side, corner, far] {
        assert_eq!(bev_iou(&a, &b), 0.0);
        assert_eq!(iou_3d(&a, &b), 0.0);
    }
    assert_eq!(bev_iou(&a, &above), 1.0);
    assert_eq!(iou_3d(&a, &above), 0.0);
    // Rotated touching along a shared edge.
    let r = Box3d::new(0.0, 0.0, 0.0, 2.0, 2.0, 2.0, FRAC_PI_4);
    let r2 = Box3d::new(2f64.sqrt(), 2f64.sqrt(), 0.0, 2.0, 2.0, 2.0, FRAC_PI_4);
    assert!(bev_iou(&r, &r2).abs() < 1e-12);
}

#[test]
fn collinear_edges_and_zero_size_never_nan() {
    let a = Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.0, 0.0);
    // Shares the y = ±1 edges, half overlap along x: IoU 1/3.
    let b = Box3d::new(2.0, 0.0, 0.0, 4.0, 2.0, 1.0, 0.0);
    assert!((bev_iou(&a, &b) - 1.0 / 3.0).abs() < 1e-12);
    assert!((iou_3d(&a, &b) - 1.0 / 3.0).abs() < 1e-12);
    // Same for rotated collinear boxes.
    let h = 0.61;
    let (ra, rb) = (Box3d { heading: h, ..a }, Box3d { x: 2.0 * h.cos(), y: 2.0 * h.sin(), heading: h, ..a });
    assert!((bev_iou(&ra, &rb) - 1.0 / 3.0).abs() < 1e-9);
    for z in [
        Box3d::new(0.0, 0.0, 0.0, 0.0, 2.0, 1.0, 0.3),
        Box3d::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        Box3d::new(0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 0.0),
    ] {
        for (x, y) in [(a, z), (z, a), (z, z)] {
            let (i2, i3) = (bev_iou(&x, &y), iou_3d(&x, &y));
            assert!(i2.is_finite() && i3.is_finite());
            assert!(i3 == 0.0);
        }
    }
}

#[test]
fn matrices_match_pairwise_calls() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let a: Vec<Box3d> = (0..37).map(|_| random_box(&mut rng, 6.0)).collect();
    let b: Vec<Box3d> = (0..23).map(|_| random_box(&mut rng, 6.0)).collect();
    let m = bev_iou_matrix(&a, &b);
    let m3 = iou_3d_matrix(&a, &b);
    assert_eq!((m.rows, m.cols), (37, 23));
    for (i, ai) in a.iter().enumerate() {
        for (j, bj) in b.iter().enumerate() {
            assert_eq!(m.get(i, j), bev_iou(ai, bj));
            assert_eq!(m3.get(i, j), iou_3d(ai, bj));
        }
    }
    assert_eq!(bev_iou_matrix(&a, &[]).data.len(), 0);
}

/// NMS's bounded test answers exactly as the IoU it skips, near and far, at the thresholds the
/// project uses (proposal NMS 0.7, detection NMS 0.01, fusion 0.55) and at 0.
#[test]
fn bounded_threshold_test_equals_the_iou() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for _ in 0..20_000 {
        let a = random_box(&mut rng, 3.0);
        // Near copies (the pairs proposal NMS meets) and independent boxes.
        let b = if rng.random_bool(0.5) {
            Box3d::new(
                a.x + rng.random_range(-0.5..0.5),
                a.y + rng.random_range(-0.5..0.5),
                a.z,
                a.dx * rng.random_range(0.8..1.25),
                a.dy * rng.random_range(0.8..1.25),
                a.dz,
                a.heading + rng.random_range(-0.3..0.3),
            )
        } else {
            random_box(&mut rng, 3.0)
        };
        let (fa, fb) = (BevFootprint::new(&a), BevFootprint::new(&b));
        for t in [0.0, 0.01, 0.3, 0.55, 0.7, 0.9] {
            assert_eq!(fa.iou_exceeds(&fb, t), bev_iou(&a, &b) > t, "{a:?} {b:?} at {t}");
        }
    }
}
