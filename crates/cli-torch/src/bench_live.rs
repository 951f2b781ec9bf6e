//! `pi3det bench live`: `pi3det run`'s path end to end on this machine — a loopback replayer
//! sends an OS1-64 packet stream (1024 × 10 Hz, LEGACY) over UDP, or a dataset is streamed at
//! 10 Hz, and the detector runs on every sweep it can take — with and without Virtual Platform
//! Pose. Prints latency percentiles (sweep complete → detections), drops and memory. `--load N`
//! runs N busy processes beside it for the whole benchmark, as the other software of a robot
//! computer would be, so the latency goal is measured under contention too.
//!
//! `pi3det bench live --ckpt runs/demo/pointpillars_vehicle/final.safetensors [--data runs/demo/data/quadruped/val [--udp]] [--seconds 600] [--load 1]`

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::args::{open_subset, DeviceArgs};
use anyhow::{bail, Context, Result};
use pi3det_live::replay::{self, Faults, ReplayPlan};
use pi3det_live::source::dataset::DatasetSource;
use pi3det_live::source::ouster_udp::{UdpOptions, UdpSource};
use pi3det_live::Source;
use pi3det_sequence::ouster::{PacketFormat, SensorMetadata, XyzLut};
use pi3det_sequence::synth::{metadata_json, SynthSpec};

use crate::run::{stream, LiveDetector, RunArgs, RunSummary};

/// Latency of `pi3det run` on loopback, with and without VPP; `--seconds 600` for a soak.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchLiveArgs {
    #[arg(long)]
    pub ckpt: PathBuf,
    /// Stream this dataset's frames at `--rate` instead of synthetic Ouster packets over UDP.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// With `--data`: send its frames as OS1-64 packets over UDP (each point encoded into the
    /// pixel whose return it is nearest), so the whole live path runs on real scenes.
    #[arg(long, requires = "data")]
    pub udp: bool,
    /// Seconds per configuration.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Sweeps per second the sensor sends.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// VPP's virtual sensor height for the "with VPP" rows.
    #[arg(long, default_value_t = 1.887)]
    pub vpp_height: f64,
    /// Only the rows without VPP, or only those with.
    #[arg(long, value_parser = ["both", "off", "on"], default_value = "both")]
    pub vpp: String,
    #[arg(long, default_value_t = 2)]
    pub queue: usize,
    /// Busy processes (a spinning shell loop each) running beside the benchmark.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub load: usize,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Busy processes, ended when dropped.
struct BusyLoad(Vec<std::process::Child>);

impl BusyLoad {
    fn start(n: usize) -> Result<Self> {
        let mut children = Vec::with_capacity(n);
        for _ in 0..n {
            let child = std::process::Command::new("sh")
                .args(["-c", "while :; do :; done"])
                .stdin(std::process::Stdio::null())
                .spawn()
                .context("--load: cannot start a busy process (sh)")?;
            children.push(child);
        }
        Ok(Self(children))
    }
}

impl Drop for BusyLoad {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// Up to 30 frames of `data` encoded as OS1-64 sweeps (packets concatenated).
fn encoded_frames(data: &std::path::Path, spec: &SynthSpec, md: &SensorMetadata) -> Result<Vec<Vec<u8>>> {
    let s = open_subset(data, None, None, 30)?;
    let lut = XyzLut::new(md);
    let mut out = Vec::new();
    let (mut kept, mut total) = (0usize, 0usize);
    for &i in &s.indices {
        let f = s.dataset.load(i)?;
        let (packets, n) = replay::encode_cloud(spec, &lut, &f.points, 0, 0);
        kept += n;
        total += f.points.len();
        out.push(packets);
    }
    if out.is_empty() {
        bail!("{}: no frames", data.display());
    }
    eprintln!(
        "encoded {} frames of {} as OS1-64 packets: {kept} of {total} points on a pixel",
        out.len(),
        data.display()
    );
    Ok(out)
}

fn udp_source(dir: &std::path::Path, args: &BenchLiveArgs) -> Result<(Box<dyn Source>, std::thread::JoinHandle<()>)> {
    let spec = SynthSpec::os1_64("bench", 1);
    let md = dir.join("os1_64.json");
    std::fs::write(&md, metadata_json(&spec)).with_context(|| md.display().to_string())?;
    let mut o = UdpOptions::new("127.0.0.1:0".parse()?, md);
    o.timeout_s = Some(1.0);
    let src = UdpSource::open(&o)?;
    let addr: SocketAddr = src.local_addr().context("no local address")?;
    let sweeps = (args.seconds * args.rate).ceil() as usize;
    // One second of distinct sweeps, sent over and over with running frame ids.
    let one_s = args.rate.ceil() as usize;
    let rate = args.rate;
    if args.udp {
        let data = args.data.clone().context("--udp needs --data")?;
        let md = SensorMetadata::parse(&o.metadata, &metadata_json(&spec))?;
        let recorded = encoded_frames(&data, &spec, &md)?;
        let format = PacketFormat::new(&md);
        let sender = std::thread::spawn(move || {
            let mut sent = 0;
            while sent < sweeps {
                let n = one_s.min(sweeps - sent);
                let batch: Vec<Vec<Vec<u8>>> = (sent..sent + n)
                    .map(|k| {
                        let mut p = recorded[k % recorded.len()].clone();
                        replay::relabel(&format, &mut p, k as u16, 1_000_000_000 + k as u64 * 100_000_000);
                        p.chunks(format.packet_bytes()).map(<[u8]>::to_vec).collect()
                    })
                    .collect();
                if replay::send(&batch, addr, rate).is_err() {
                    return;
                }
                sent += n;
            }
        });
        return Ok((Box::new(src), sender));
    }
    let sender = std::thread::spawn(move || {
        let mut sent = 0;
        while sent < sweeps {
            let n = one_s.min(sweeps - sent);
            let plan = ReplayPlan {
                sweeps: n,
                first_frame_id: sent as u16,
                restart_at: None,
                faults: Faults::default(),
                seed: 1,
            };
            let batch = replay::datagrams(&spec, &plan);
            if replay::send(&batch, addr, rate).is_err() {
                return;
            }
            sent += n;
        }
    });
    Ok((Box::new(src), sender))
}

fn one(args: &BenchLiveArgs, vpp: bool, dir: &std::path::Path) -> Result<RunSummary> {
    let run_args = RunArgs {
        ckpt: args.ckpt.clone(),
        source: String::new(),
        sinks: Vec::new(),
        level: crate::args::LevelArgs { vpp_height: vpp.then_some(args.vpp_height), no_level: !vpp },
        queue: args.queue,
        max_frames: None,
        score_threshold: None,
        report: None,
        overwrite: false,
        device: args.device.clone(),
    };
    let mut detector = LiveDetector::load(&run_args)?;
    // What `pi3det run` does before its source opens.
    let warm = detector.warm_up(crate::run::WARM_UP_PASSES)?;
    eprintln!("  {warm}");
    let (source, sender): (Box<dyn Source>, Option<std::thread::JoinHandle<()>>) = match &args.data {
        Some(d) if !args.udp => {
            let s = open_subset(d, None, None, 0)?;
            let n = ((args.seconds * args.rate).ceil() as usize).max(1);
            let indices: Vec<usize> = (0..n).map(|k| s.indices[k % s.indices.len().max(1)]).collect();
            (Box::new(DatasetSource::new(s.dataset, indices, Some(args.rate), d.display().to_string())), None)
        }
        _ => {
            let (s, h) = udp_source(dir, args)?;
            (s, Some(h))
        }
    };
    let stop = Arc::new(AtomicBool::new(false));
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let summary = stream(&detector, source, &mut [], args.queue, None, stop.clone(), &mut |s| {
        if tty {
            eprint!("\r  {} sweeps, {} dropped, {}   ", s.processed, s.dropped_in_queue, s.total.summary());
        }
    })?;
    if tty {
        eprintln!();
    }
    stop.store(true, Ordering::Relaxed);
    if let Some(h) = sender {
        let _ = h.join();
    }
    Ok(summary)
}

pub fn run(args: &BenchLiveArgs) -> Result<()> {
    let dir = tempfile::tempdir()?;
    let modes: &[bool] = match args.vpp.as_str() {
        "off" => &[false],
        "on" => &[true],
        _ => &[false, true],
    };
    let input = match &args.data {
        Some(d) if args.udp => format!("{} as OS1-64 1024 packets over UDP loopback at {} Hz", d.display(), args.rate),
        Some(d) => format!("{} at {} Hz", d.display(), args.rate),
        None => format!("synthetic OS1-64 1024 packets (random ranges) over UDP loopback at {} Hz", args.rate),
    };
    let threads = args.device.torch_threads.unwrap_or_else(crate::run::live_threads);
    println!(
        "pi3det run on {input}, {:.0} s per row, queue {}, {threads} libtorch thread(s), OMP_WAIT_POLICY {}, {} busy process(es) beside it",
        args.seconds,
        args.queue,
        std::env::var("OMP_WAIT_POLICY").unwrap_or_else(|_| "unset".into()),
        args.load
    );
    let _load = BusyLoad::start(args.load)?;
    println!("| VPP | sweeps in | processed | dropped | p50 ms | p95 ms | p99 ms | max ms | mean: wait / pillars / network / NMS ms | RSS start → each minute → end MB |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |");
    for &vpp in modes {
        let s = one(args, vpp, dir.path())?;
        let mb = |kb: Option<u64>| kb.map_or("?".into(), |k| format!("{:.0}", k as f64 / 1024.0));
        println!(
            "| {} | {} | {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} / {:.1} / {:.1} / {:.1} | {} |",
            if vpp { format!("on ({} m)", args.vpp_height) } else { "off".into() },
            s.source.sweeps,
            s.processed,
            s.dropped_in_queue,
            s.total.quantile_ms(0.5),
            s.total.quantile_ms(0.95),
            s.total.quantile_ms(0.99),
            s.total.max_ms(),
            s.queue.mean_ms(),
            s.prep.mean_ms(),
            s.network.mean_ms(),
            s.post.mean_ms(),
            std::iter::once(mb(s.rss_start_kb))
                .chain(s.rss_samples_kb.iter().map(|(_, kb)| mb(Some(*kb))))
                .chain(std::iter::once(mb(s.rss_end_kb)))
                .collect::<Vec<_>>()
                .join(" → ")
        );
    }
    Ok(())
}
