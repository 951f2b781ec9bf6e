//! `pi3det run`: a trained detector on a stream — live Ouster packets, a ROS 2 bag, or a dataset
//! at a rate — with detections written as they are made.
//!
//! `pi3det run --ckpt runs/pp/final.safetensors --source 'ouster-udp://0.0.0.0:7502?metadata=os.json' --sink det.jsonl --sink run.mcap`
//!
//! The source runs on its own thread and hands complete sweeps to a bounded queue
//! (`--queue`, default 2). Inference takes the oldest; when it falls behind a live source the
//! queue drops the oldest pending sweep (counted), so memory and latency stay bounded. A
//! recorded source without `rate=` waits instead, so every sweep is processed. Latency runs from
//! a sweep's completion (its last packet, or its message read) to its detections; p50/p95/p99
//! are shown on the progress line and printed at the end (Ctrl-C ends a live run cleanly).
//!
//! A robot computer is shared (SLAM, planning, drivers), and a run must not fall apart when a
//! neighbour takes a core. Every parallel layer of libtorch waits for its slowest thread; with
//! OpenMP's spinning waits a thread whose core a neighbour has taken stalls the whole layer and
//! its siblings burn their time slices spinning, so `pi3det` starts `run` and `bench live` with
//! `OMP_WAIT_POLICY=PASSIVE` (unless set): waiting threads sleep. libtorch gets [`live_threads`]
//! intra-op threads unless `--torch-threads` or `PI3DET_TORCH_THREADS` says otherwise.
//!
//! Before the source opens, the whole path runs on a simulated sweep a few times (allocator
//! buffers, oneDNN's kernels), so the first real sweep is not the slow one; a checkpoint whose
//! inference precision is `auto` is timed in f32 and in bf16 there and keeps the faster (bf16
//! pays on some CPUs with native bfloat16 and costs on others). Measured:
//! results/2026-12-06-live-threads.md.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::args::{open_subset, DeviceArgs};
use anyhow::{bail, Context, Result};
use pi3det_data::{Frame, Object};
use pi3det_live::sink::FrameLatency;
use pi3det_live::source::dataset::DatasetSource;
use pi3det_live::{
    open_sink, open_source, DropOldestQueue, Flow, LatencyHistogram, LiveFrame, SinkSpec, Source, SourceSpec,
};
use pi3det_nn::data_loader::prepare_frame;
use pi3det_nn::detect::to_objects;
use pi3det_nn::export::TorchScriptModel;
use pi3det_nn::precision::Precision;
use pi3det_nn::preprocess::Preprocessor;
use pi3det_nn::Detector;

/// Run a detector on a live or recorded stream (Ouster UDP, ROS 2 bag, dataset folder) and
/// write detections as they are made (JSON lines, Foxglove MCAP).
#[derive(clap::Args, Debug, Clone)]
pub struct RunArgs {
    /// Checkpoint (.safetensors) of `pi3det train` or `pi3det adapt`, or a model exported by
    /// `pi3det export` (.pt, with its .json and .roi.pt beside it).
    #[arg(long)]
    pub ckpt: PathBuf,
    /// `ouster-udp://HOST:PORT?metadata=FILE`, `mcap://BAG.mcap?topic=/points[&rate=HZ]`,
    /// `dataset://DIR?split=val[&rate=HZ]`, or a bare `*.mcap` / folder path.
    #[arg(long)]
    pub source: String,
    /// `*.jsonl` / `jsonl://FILE` (what `pi3det eval` reads) or `*.mcap` / `mcap://FILE[?points=false]`
    /// (Foxglove); repeat for several. None: detections are counted and timed only.
    #[arg(long = "sink")]
    pub sinks: Vec<String>,
    /// Levelling of each sweep from its own ground (a tilting drone or quadruped, a sensor
    /// mounted higher or lower than in training); boxes come back in the sensor frame.
    #[command(flatten)]
    pub level: crate::args::LevelArgs,
    /// Sweeps waiting for inference at most; a live source drops the oldest beyond this.
    #[arg(long, default_value_t = 2)]
    pub queue: usize,
    /// Stop after this many sweeps.
    #[arg(long)]
    pub max_frames: Option<u64>,
    /// Override the checkpoint's score threshold.
    #[arg(long)]
    pub score_threshold: Option<f64>,
    /// Write a JSON summary (counters, latency percentiles) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Replace sink files (and the report) an earlier run left.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// The network: a checkpoint in Rust, or an exported TorchScript model (`pi3det export`).
enum Net {
    Native(Detector),
    Script(TorchScriptModel),
}

/// A loaded detector with its preprocessing, for one sweep at a time.
pub struct LiveDetector {
    net: Net,
    prep: Arc<Preprocessor>,
}

/// What the warm-up found: the last pass's total (ms), and for an `auto` precision the one kept
/// with each one's best network time (ms).
#[derive(Debug, Clone)]
pub struct WarmUp {
    pub last_ms: f64,
    pub precision: Option<(Precision, Vec<(Precision, f64)>)>,
}

impl std::fmt::Display for WarmUp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "warmed up ({WARM_UP_PASSES} passes on a simulated sweep, the last {:.0} ms)", self.last_ms)?;
        if let Some((p, times)) = &self.precision {
            let t: Vec<String> = times.iter().map(|(p, ms)| format!("{p:?} {ms:.0} ms")).collect();
            write!(f, "; precision auto: network {} → {p:?}", t.join(", "))?;
        }
        Ok(())
    }
}

/// Stage times of one sweep (ms).
#[derive(Debug, Clone, Copy, Default)]
pub struct StageMs {
    pub prep: f64,
    pub network: f64,
    pub post: f64,
}

/// libtorch intra-op threads for a live run: the cores, at most four (the network's layers are
/// small; more threads wait more at each layer's end and take cores from the neighbours).
/// `PI3DET_TORCH_THREADS` overrides it.
pub fn live_threads() -> usize {
    pi3det_nn::device::env_threads().unwrap_or_else(|| pi3det_nn::device::cores().min(4))
}

/// Network passes on a simulated sweep before a run (see the module doc).
pub const WARM_UP_PASSES: usize = 3;

impl LiveDetector {
    pub fn load(args: &RunArgs) -> Result<Self> {
        let device = args.device.setup(args.device.torch_threads.unwrap_or_else(live_threads))?;
        let adjust = |cfg: &mut pi3det_nn::DetectorConfig| {
            if let Some(t) = args.score_threshold {
                cfg.post.score_threshold = t;
            }
        };
        let net = if args.ckpt.extension().is_some_and(|e| e == "pt") {
            Net::Script(TorchScriptModel::load(&args.ckpt, device, adjust)?)
        } else {
            let mut ck = pi3det_nn::checkpoint::load(&args.ckpt)?;
            adjust(&mut ck.config);
            let mut det = Detector::new(&ck.config, device)?;
            ck.load_into(&mut det, &args.ckpt)?;
            Net::Native(det)
        };
        let cfg = match &net {
            Net::Native(d) => d.cfg().clone(),
            Net::Script(m) => m.det.cfg().clone(),
        };
        let mut prep = Preprocessor::new(&cfg)?;
        let level = args.level.level();
        eprintln!("{}", level.describe(&cfg));
        if let Some(h) = level.height_m(&cfg) {
            prep = prep.with_frame_transform(crate::detect::vpp(&cfg, h)?);
        }
        Ok(Self { net, prep: Arc::new(prep) })
    }

    /// Runs the whole path (points → pillars → network → NMS) on a simulated vehicle sweep
    /// `passes` times; with a checkpoint inferring in `auto` precision on the CPU, in f32 and in
    /// bf16, keeping the one whose network time was lower. Returns what it found.
    pub fn warm_up(&mut self, passes: usize) -> Result<WarmUp> {
        let frames = crate::frames::vehicle_frames(1)?;
        let passes = passes.max(1);
        let time = |d: &Self| -> Result<(f64, f64)> {
            let mut best = f64::INFINITY;
            let mut last = 0.0;
            for _ in 0..passes {
                let (_, ms) = d.detect(&frames[0])?;
                best = best.min(ms.network);
                last = ms.prep + ms.network + ms.post;
            }
            Ok((best, last))
        };
        let choose = match &self.net {
            Net::Native(d) => d.cfg().precision == Precision::Auto && !d.device().is_cuda(),
            Net::Script(_) => false,
        };
        if !choose {
            let (_, last_ms) = time(self)?;
            return Ok(WarmUp { last_ms, precision: None });
        }
        let mut network_ms = Vec::new();
        for p in [Precision::F32, Precision::Bf16] {
            self.set_precision(p)?;
            network_ms.push((p, time(self)?));
        }
        let (p, (_, last_ms)) =
            network_ms.iter().copied().min_by(|a, b| a.1 .0.total_cmp(&b.1 .0)).expect("two precisions timed");
        self.set_precision(p)?;
        Ok(WarmUp { last_ms, precision: Some((p, network_ms.iter().map(|(p, (n, _))| (*p, *n)).collect())) })
    }

    fn set_precision(&mut self, p: Precision) -> Result<()> {
        if let Net::Native(d) = &mut self.net {
            d.set_precision(p)?;
        }
        Ok(())
    }

    pub fn detector(&self) -> &Detector {
        match &self.net {
            Net::Native(d) => d,
            Net::Script(m) => &m.det,
        }
    }

    /// Detections of one sweep, boxes in its LiDAR frame.
    pub fn detect(&self, frame: &Frame) -> Result<(Vec<Object>, StageMs)> {
        let t0 = Instant::now();
        let p = prepare_frame(&self.prep, &[], frame, false, 0)?;
        let det = self.detector();
        let x = self.prep.collate_inputs(&[&p.pillars]).to_device(det.device());
        let t1 = Instant::now();
        let _guard = tch::no_grad_guard();
        let y = match &self.net {
            Net::Native(d) => d.forward_t(&x, false)?,
            Net::Script(m) => m.forward(&x)?,
        };
        if det.device().is_cuda() {
            tch::Cuda::synchronize(0);
        }
        let t2 = Instant::now();
        let mut dets = det.post_process(&y, 1)?;
        let (index, pose) = ([p.point_index], [p.detector_from_lidar]);
        pi3det_nn::post_process::fit_to_points(&det.cfg().post, &det.cfg().classes, &mut dets, &index, &pose);
        let objects = dets.first().map(|d| to_objects(det, d, &pose[0])).unwrap_or_default();
        let t3 = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        Ok((objects, StageMs { prep: ms(t0, t1), network: ms(t1, t2), post: ms(t2, t3) }))
    }
}

/// What a run measured.
#[derive(Debug, Clone)]
pub struct RunSummary {
    pub source: pi3det_live::SourceReport,
    pub processed: u64,
    pub dropped_in_queue: u64,
    pub detections: u64,
    pub total: LatencyHistogram,
    pub queue: LatencyHistogram,
    pub prep: LatencyHistogram,
    pub network: LatencyHistogram,
    pub post: LatencyHistogram,
    pub wall_s: f64,
    pub rss_start_kb: Option<u64>,
    pub rss_end_kb: Option<u64>,
    /// Resident memory once a minute: (seconds since the start, kB).
    pub rss_samples_kb: Vec<(f64, u64)>,
}

impl RunSummary {
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "source": self.source, "processed": self.processed, "dropped_in_queue": self.dropped_in_queue,
            "detections": self.detections, "latency_ms": self.total.to_json(), "queue_ms": self.queue.to_json(), "prep_ms": self.prep.to_json(),
            "network_ms": self.network.to_json(), "post_ms": self.post.to_json(),
            "wall_s": self.wall_s, "rss_start_kb": self.rss_start_kb, "rss_end_kb": self.rss_end_kb,
            "rss_samples_kb": self.rss_samples_kb,
        })
    }
}

/// Resident memory of this process (Linux), kB.
pub fn rss_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find_map(|l| l.strip_prefix("VmRSS:")).and_then(|v| v.split_whitespace().next()?.parse().ok())
}

/// Opens `--source`: a dataset split through the detector crate's reader, the rest by pi3det-live.
pub fn open_any_source(uri: &str) -> Result<Box<dyn Source>> {
    let spec: SourceSpec = uri.parse()?;
    Ok(match &spec {
        SourceSpec::Dataset { path, split, rate_hz } => {
            let subset = open_subset(path, split.as_deref(), None, 0)
                .with_context(|| format!("--source {uri}: cannot open the dataset"))?;
            Box::new(DatasetSource::new(subset.dataset, subset.indices, *rate_hz, path.display().to_string()))
        }
        _ => open_source(&spec)?,
    })
}

/// Streams `source` through `detector` into `sinks` until the source ends, `max_frames`
/// sweeps are done or `stop` is set. `on_progress` sees the summary about once a second.
pub fn stream(
    detector: &LiveDetector,
    mut source: Box<dyn Source>,
    sinks: &mut [Box<dyn pi3det_live::Sink>],
    queue_len: usize,
    max_frames: Option<u64>,
    stop: Arc<AtomicBool>,
    on_progress: &mut dyn FnMut(&RunSummary),
) -> Result<RunSummary> {
    let queue = Arc::new(DropOldestQueue::<LiveFrame>::new(queue_len));
    let live = source.is_live();
    let producer = {
        let (queue, stop) = (queue.clone(), stop.clone());
        std::thread::Builder::new()
            .name("source".into())
            .spawn(move || {
                let r = source.run(
                    &mut |f| {
                        // Live: push always succeeds (dropping the oldest if full).
                        let kept = if live {
                            queue.push(f);
                            true
                        } else {
                            queue.push_wait(f)
                        };
                        if kept && !queue.is_closed() {
                            Flow::Continue
                        } else {
                            Flow::Stop
                        }
                    },
                    &stop,
                );
                queue.close();
                r
            })
            .context("cannot start the source thread")?
    };
    let start = Instant::now();
    let mut s = RunSummary {
        source: Default::default(),
        processed: 0,
        dropped_in_queue: 0,
        detections: 0,
        total: LatencyHistogram::default(),
        queue: LatencyHistogram::default(),
        prep: LatencyHistogram::default(),
        network: LatencyHistogram::default(),
        post: LatencyHistogram::default(),
        wall_s: 0.0,
        rss_start_kb: rss_kb(),
        rss_end_kb: None,
        rss_samples_kb: Vec::new(),
    };
    let mut last_progress = Instant::now();
    let result = (|| -> Result<()> {
        while let Some(lf) = queue.pop() {
            let queue_ms = lf.arrived.elapsed().as_secs_f64() * 1e3;
            let (objects, ms) = detector.detect(&lf.frame)?;
            let total_ms = lf.arrived.elapsed().as_secs_f64() * 1e3;
            let lat = FrameLatency { queue_ms, prep_ms: ms.prep, network_ms: ms.network, post_ms: ms.post, total_ms };
            for sink in sinks.iter_mut() {
                sink.write(&lf, &objects, &lat)?;
            }
            s.processed += 1;
            s.detections += objects.len() as u64;
            s.total.record(total_ms);
            s.queue.record(queue_ms);
            s.prep.record(ms.prep);
            s.network.record(ms.network);
            s.post.record(ms.post);
            let t = start.elapsed().as_secs_f64();
            if t >= 60.0 * (s.rss_samples_kb.len() + 1) as f64 {
                if let Some(kb) = rss_kb() {
                    s.rss_samples_kb.push((t, kb));
                }
            }
            if last_progress.elapsed() >= Duration::from_secs(1) {
                s.dropped_in_queue = queue.dropped();
                s.wall_s = start.elapsed().as_secs_f64();
                on_progress(&s);
                last_progress = Instant::now();
            }
            if max_frames.is_some_and(|m| s.processed >= m) || stop.load(Ordering::Relaxed) {
                break;
            }
        }
        Ok(())
    })();
    // Whatever ended the loop, the source stops and its counters come back.
    stop.store(true, Ordering::Relaxed);
    queue.close();
    let source_result = producer.join().map_err(|_| anyhow::anyhow!("the source thread panicked"))?;
    result?;
    s.source = source_result?;
    for sink in sinks.iter_mut() {
        sink.finish()?;
    }
    s.dropped_in_queue = queue.dropped();
    s.wall_s = start.elapsed().as_secs_f64();
    s.rss_end_kb = rss_kb();
    Ok(s)
}

pub fn run(args: &RunArgs) -> Result<()> {
    let sink_specs: Vec<SinkSpec> = args.sinks.iter().map(|s| s.parse()).collect::<Result<_, _>>()?;
    let mut seen = std::collections::BTreeSet::new();
    for s in &sink_specs {
        if !seen.insert(s.path().clone()) {
            bail!("--sink {} given twice", s.path().display());
        }
        if !args.overwrite && s.path().exists() {
            bail!("{} exists; pass --overwrite to replace it", s.path().display());
        }
    }
    if let Some(r) = &args.report {
        if !args.overwrite && r.exists() {
            bail!("{} exists; pass --overwrite to replace it", r.display());
        }
    }
    let mut detector = LiveDetector::load(args)?;
    let warm = detector.warm_up(WARM_UP_PASSES)?;
    eprintln!(
        "run: {} libtorch thread(s), OMP_WAIT_POLICY {}; {warm}",
        tch::get_num_threads(),
        std::env::var("OMP_WAIT_POLICY").unwrap_or_else(|_| "unset".into())
    );
    let source = open_any_source(&args.source)?;
    let mut sinks = sink_specs.iter().map(|s| open_sink(s, args.overwrite)).collect::<Result<Vec<_>, _>>()?;
    eprintln!(
        "run: {} → {}",
        source.describe(),
        if sinks.is_empty() { "(no sink)".into() } else { args.sinks.join(", ") }
    );
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        // A second Ctrl-C while shutting down falls through to the default (exit).
        let _ = ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::Relaxed) {
                std::process::exit(130);
            }
        });
    }
    let bar = indicatif::ProgressBar::new_spinner();
    let summary = stream(&detector, source, &mut sinks, args.queue, args.max_frames, stop, &mut |s| {
        bar.set_message(format!(
            "{} sweeps ({:.1}/s), {} dropped, latency {}",
            s.processed,
            s.processed as f64 / s.wall_s.max(1e-9),
            s.dropped_in_queue,
            s.total.summary()
        ));
        bar.tick();
    })?;
    bar.finish_and_clear();
    println!("{}", format_summary(&summary));
    if let Some(r) = &args.report {
        let json = serde_json::to_vec_pretty(&summary.to_json())?;
        pi3det_data::io::write_atomic(r, &json, true)?;
    }
    Ok(())
}

pub fn format_summary(s: &RunSummary) -> String {
    let mut out = format!(
        "{} sweeps processed in {:.1} s ({:.1}/s), {} detections; dropped in the queue: {}\nsource: {}\nlatency (sweep complete → detections): {}\n  of which waiting {}, points → pillars {}, network {}, decode + NMS {}",
        s.processed,
        s.wall_s,
        s.processed as f64 / s.wall_s.max(1e-9),
        s.detections,
        s.dropped_in_queue,
        s.source,
        s.total.summary(),
        s.queue.summary(),
        s.prep.summary(),
        s.network.summary(),
        s.post.summary()
    );
    if let (Some(a), Some(b)) = (s.rss_start_kb, s.rss_end_kb) {
        out.push_str(&format!(
            "\nmemory (RSS): {:.1} MB at start, {:.1} MB at end",
            a as f64 / 1024.0,
            b as f64 / 1024.0
        ));
    }
    out
}
