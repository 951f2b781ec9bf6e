//! Debug aid: overfit one simulated frame and print the loss and detections.
//! `cargo run --release -p pi3det-nn --example overfit_debug -- [anchor|center] STEPS`

use pi3det_data::Platform;
use pi3det_geometry::bev_iou;
use pi3det_nn::backbone_2d::Backbone2dConfig;
use pi3det_nn::config::{HeadConfig, PostConfig, TrainConfig};
use pi3det_nn::data_loader::frame_to_sample;
use pi3det_nn::dense_heads::{AnchorHeadConfig, CenterHeadConfig};
use pi3det_nn::optim::{OneCycle, Optimizer};
use pi3det_nn::pillarize::PillarizeConfig;
use pi3det_nn::vfe::PillarVfeConfig;
use pi3det_nn::{Detector, DetectorConfig};
use pi3det_sim::{SequenceSpec, SimConfig};
use tch::Device;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let head = if args.get(1).map(String::as_str) == Some("center") {
        HeadConfig::Center(CenterHeadConfig { shared_channels: 32, num_head_convs: 1, ..Default::default() })
    } else {
        HeadConfig::Anchor(AnchorHeadConfig::default())
    };
    let steps: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(250);
    let lr: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0.003);
    tch::manual_seed(0);
    tch::set_num_threads(std::env::var("T").ok().and_then(|v| v.parse().ok()).unwrap_or(2));
    let half = 19.2;
    let sim = SimConfig::default();
    let mut frame = None;
    'outer: for index in 0..8 {
        let spec = SequenceSpec { platform: Platform::Vehicle, index, frames: 10, seed: 7, layout: None };
        let seq = pi3det_sim::Sequence::generate(&sim, spec).unwrap();
        for f in 0..seq.len() {
            let mut fr = seq.render(f).to_frame("0", Platform::Vehicle, &seq.name);
            fr.info.objects.retain(|o| {
                o.box3d.x.abs() < half - 1.0 && o.box3d.y.abs() < half - 1.0 && o.num_points.unwrap_or(0) >= 10
            });
            let cars = fr.info.objects.iter().filter(|o| o.name == "Car").count();
            let peds = fr.info.objects.iter().filter(|o| o.name == "Pedestrian").count();
            if cars >= 2 && peds >= 1 {
                frame = Some(fr);
                break 'outer;
            }
        }
    }
    let frame = frame.unwrap();
    let cfg = DetectorConfig {
        shift_z: 1.9,
        batch_norm: pi3det_nn::BatchNorm { eps: 1e-3, momentum: 0.1 },
        pillars: PillarizeConfig {
            point_cloud_range: [-half, -half, -2.0, half, half, 4.0],
            pillar_size: [0.4, 0.4],
            max_points_per_pillar: 16,
            max_pillars_train: 12000,
            max_pillars_test: 12000,
        },
        vfe: PillarVfeConfig { num_filters: vec![32] },
        backbone: Backbone2dConfig {
            layer_nums: vec![1, 1, 1],
            layer_strides: vec![2, 2, 2],
            num_filters: vec![32, 32, 64],
            upsample_strides: vec![1, 2, 4],
            num_upsample_filters: vec![32, 32, 32],
        },
        head,
        post: PostConfig {
            score_threshold: 0.3,
            nms_iou: 0.01,
            nms_pre_max: 500,
            nms_post_max: 100,
            per_class_nms: false,
        },
        train: TrainConfig { lr, weight_decay: 0.0, augment: vec![], ..TrainConfig::default() },
        ..DetectorConfig::default()
    };
    let det = Detector::new(&cfg, Device::Cpu).unwrap();
    let s = frame_to_sample(&frame, &cfg, 1);
    for (b, c) in s.boxes.iter().zip(&s.classes) {
        println!("GT {c} {:?}", b.to_array().map(|v| (v * 100.0).round() / 100.0));
    }
    let prep = det.prep.clone();
    let pillars = prep.pillarizer().unwrap().run(&s.points, 12000);
    println!("{} points, {} pillars", s.points.len(), pillars.len());
    let x = prep.collate_inputs(&[&pillars]);
    let ft = prep.targets(&s);
    if let pi3det_nn::detector::FrameTargets::Anchor(a) = &ft {
        println!("positives {} ignored {}", a.pos_index.len(), a.labels.iter().filter(|&&l| l < 0).count());
    }
    let t = prep.collate_targets(&[&ft]);
    let ptrs: Vec<usize> = det.vs.trainable_variables().iter().map(|t| t.data_ptr() as usize).collect();
    let params = det.vs.variables().into_iter().filter(|(_, t)| ptrs.contains(&(t.data_ptr() as usize))).collect();
    let mut opt = Optimizer::new(params, &cfg.train);
    let sched = OneCycle::new(&cfg.train, steps);
    let t0 = std::time::Instant::now();
    for step in 0..steps {
        let (lr, b1) = sched.at(step);
        let ta = std::time::Instant::now();
        let out = det.forward_t(&x, true);
        let tb = std::time::Instant::now();
        let l = det.loss(&out, &t);
        let tc = std::time::Instant::now();
        opt.zero_grad();
        l.total.backward();
        let td = std::time::Instant::now();
        let gn = opt.clip_grad_norm(10.0);
        opt.update(lr, b1);
        let te = std::time::Instant::now();
        if step % 25 == 5 {
            println!(
                "  fwd {:.1} loss {:.1} bwd {:.1} opt {:.1} ms",
                (tb - ta).as_secs_f64() * 1e3,
                (tc - tb).as_secs_f64() * 1e3,
                (td - tc).as_secs_f64() * 1e3,
                (te - td).as_secs_f64() * 1e3
            );
        }
        if step % 25 == 0 || step + 1 == steps {
            let terms: Vec<String> = l.terms.iter().map(|(k, v)| format!("{k} {:.4}", v.double_value(&[]))).collect();
            println!("step {step} lr {lr:.5} loss {:.4} [{}] gn {gn:.2}", l.total.double_value(&[]), terms.join(", "));
        }
    }
    println!("{:.1} ms/step", t0.elapsed().as_secs_f64() * 1e3 / steps as f64);
    for (name, train) in [("eval", false), ("train-bn", true)] {
        let dets = {
            let _g = tch::no_grad_guard();
            let out = det.forward_t(&x, train);
            det.post_process(&out, 1).remove(0)
        };
        println!("-- {name}: {} detections", dets.len());
        for d in &dets {
            let best = s.boxes.iter().map(|b| bev_iou(b, &d.box3d)).fold(0.0, f64::max);
            println!(
                "  det {} {:.3} {:?} best iou {best:.3}",
                d.class,
                d.score,
                d.box3d.to_array().map(|v| (v * 100.0).round() / 100.0)
            );
        }
    }
}
