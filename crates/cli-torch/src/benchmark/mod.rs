//! `pi3det bench suite`: the Pi3DET cross-platform benchmark (paper §5, Tables 2–4) as a resumable,
//! shardable set of jobs. A suite (`configs/benchmark/<suite>.toml`, [`suite`]) names datasets,
//! tasks, methods and detectors; each (task, method, detector) cell runs in
//! `OUT/cells/<task>__<method>__<detector>/` ([`methods`]) and leaves `cell.json` (everything it
//! depends on), `result.json` and `log.txt`. A cell whose `result.json` is done with the same
//! `cell.json` is skipped, so an interrupted run resumes; a failing cell is recorded as failed
//! with its log and the others go on; a cell another process is running in the same folder (its
//! lock file held) is left to it. `--only` runs a subset, `--shard i/N` a deterministic share,
//! `--merge DIR…` combines the cell folders of several machines; every run ends by writing the
//! tables ([`table`]): `benchmark.md`, `benchmark.csv`, `benchmark.json`, `gap_closed.png`.
//!
//! `--seeds 0,1` runs the suite once per seed (`OUT/seed_<S>`) and writes one table of per-seed
//! values, mean ± spread and each row's paired-bootstrap interval against source-only ([`stats`]).
//!
//! `pi3det bench suite --suite configs/benchmark/mini.toml --out runs/bench`

pub mod methods;
pub mod stats;
pub mod suite;
pub mod table;

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::DeviceArgs;
use anyhow::{bail, Context, Result};
use serde::Serialize;

use methods::{Ctx, Log};
use suite::{matches_any, Cell, Shard, Suite};
use table::{CellResult, Status};

#[derive(clap::Args, Debug, Clone)]
pub struct BenchmarkArgs {
    /// The suite (e.g. configs/benchmark/mini.toml).
    #[arg(long)]
    pub suite: PathBuf,
    #[arg(long, default_value = "runs/bench")]
    pub out: PathBuf,
    /// Run only the cells matching these ids (`task/method/detector`, `*` as a wildcard), comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Run the cells at positions ≡ i − 1 (mod N) of the suite's order (1-based i).
    #[arg(long, value_name = "i/N")]
    pub shard: Option<Shard>,
    /// Combine the cell folders of these benchmark outputs into --out and write the tables (runs nothing).
    #[arg(long, num_args = 1.., value_name = "DIR")]
    pub merge: Vec<PathBuf>,
    /// Print the suite's cell ids, one per line, and exit.
    #[arg(long)]
    pub list: bool,
    /// Run cells again even when finished with the same config.
    #[arg(long)]
    pub force: bool,
    /// Run the suite once per seed (in OUT/seed_<S>, paired: the same data and validation split
    /// per seed where the suite fixes them) and write one table of mean, spread and intervals.
    #[arg(long, value_delimiter = ',')]
    pub seeds: Vec<u64>,
    /// Paired bootstrap draws over validation sequences for each row's interval against
    /// source-only (0: no intervals).
    #[arg(long, default_value_t = 200)]
    pub bootstrap: usize,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// A cell id as a folder name.
pub fn cell_dir_name(id: &str) -> String {
    id.replace('/', "__")
}

/// Everything a cell's result depends on, as stored in its `cell.json`.
#[derive(Serialize)]
struct CellKey<'a> {
    id: String,
    seed: u64,
    task: &'a suite::TaskSpec,
    source: &'a suite::DatasetSpec,
    target: &'a suite::DatasetSpec,
    method: &'a suite::MethodSpec,
    detector: String,
    pi3det_net: Option<String>,
    /// MS3D++'s ensemble members' configs (a changed member file reruns the cell).
    members: Vec<String>,
    schedule: &'a suite::Schedule,
}

fn cell_key(s: &Suite, c: &Cell) -> String {
    let t = s.task(&c.task);
    let d = &s.detectors[&c.detector];
    let key = CellKey {
        id: s.cell_id(c),
        seed: s.seed,
        task: t,
        source: &s.datasets[&t.source],
        target: &s.datasets[&t.target],
        method: &s.methods[c.method],
        detector: d.config.to_toml(),
        pi3det_net: (s.methods[c.method].kind == suite::MethodKind::Pi3detNet)
            .then(|| d.pi3det_net.as_ref().map(|a| a.to_toml()))
            .flatten(),
        members: s.methods[c.method]
            .ensemble
            .iter()
            .filter_map(|m| m.config.as_ref())
            .map(|p| std::fs::read_to_string(p).unwrap_or_default())
            .collect(),
        schedule: &s.schedule,
    };
    serde_json::to_string_pretty(&key).unwrap_or_default()
}

fn read_result(dir: &Path) -> Option<CellResult> {
    serde_json::from_slice(&std::fs::read(dir.join("result.json")).ok()?).ok()
}

/// Whether the cell in `dir` finished with exactly `key`.
fn finished(dir: &Path, key: &str) -> bool {
    std::fs::read_to_string(dir.join("cell.json")).is_ok_and(|k| k == key)
        && read_result(dir).is_some_and(|r| r.status == Status::Done)
}

/// The cells to run: `--only` (every pattern must match) and `--shard`.
pub fn select(s: &Suite, only: &[String], shard: Option<Shard>) -> Result<Vec<Cell>> {
    let all = s.cells();
    let ids: Vec<String> = all.iter().map(|c| s.cell_id(c)).collect();
    for p in only {
        if !ids.iter().any(|id| matches_any(id, std::slice::from_ref(p))) {
            bail!("--only {p:?} matches no cell of the suite (cells: {})", ids.join(", "));
        }
    }
    let picked: Vec<Cell> =
        all.into_iter().zip(&ids).filter(|(_, id)| only.is_empty() || matches_any(id, only)).map(|(c, _)| c).collect();
    Ok(match shard {
        Some(sh) => sh.take(&picked),
        None => picked,
    })
}

/// Runs one cell in its folder; failures (errors and panics) become a failed result. `None`
/// when another process is running the cell in the same output folder (its lock is held).
fn run_one(ctx: &Ctx<'_>, cell: &Cell, key: &str) -> Result<Option<CellResult>> {
    let s = ctx.suite;
    let id = s.cell_id(cell);
    let cells = ctx.out.join("cells");
    std::fs::create_dir_all(&cells).with_context(|| format!("creating {}", cells.display()))?;
    let lock_path = cells.join(format!("{}.lock", cell_dir_name(&id)));
    let lock = std::fs::File::create(&lock_path).with_context(|| format!("creating {}", lock_path.display()))?;
    match lock.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            eprintln!("[{id}] another process is running this cell in {}: left to it", ctx.out.display());
            return Ok(None);
        }
        Err(std::fs::TryLockError::Error(e)) => {
            return Err(e).with_context(|| format!("locking {}", lock_path.display()))
        }
    }
    let dir = cells.join(cell_dir_name(&id));
    if dir.exists() {
        std::fs::remove_dir_all(&dir).with_context(|| format!("clearing {}", dir.display()))?;
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    pi3det_data::io::write_atomic(&dir.join("cell.json"), key.as_bytes(), true)?;
    let mut log = Log::create(&dir.join("log.txt"), id.clone())?;
    log.line(format!("cell {id}"));
    let t = Instant::now();
    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| methods::run_cell(ctx, cell, &dir, &mut log)));
    let (status, error, outcome) = match run {
        Ok(Ok(o)) => (Status::Done, None, Some(o)),
        Ok(Err(e)) => (Status::Failed, Some(format!("{e:#}")), None),
        Err(p) => {
            let msg = p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
            (Status::Failed, Some(format!("panicked: {}", msg.unwrap_or_default())), None)
        }
    };
    if let Some(e) = &error {
        log.line(format!("FAILED: {e}"));
    }
    let seconds = t.elapsed().as_secs_f64();
    log.line(format!("{} in {seconds:.0} s", if status == Status::Done { "done" } else { "failed" }));
    let m = &s.methods[cell.method];
    let (ap, pseudo_labels) = match outcome {
        Some(o) => (Some(o.ap), o.pseudo_labels),
        None => (None, Vec::new()),
    };
    let r = CellResult {
        id,
        task: cell.task.clone(),
        method: m.label(),
        kind: m.kind,
        detector: cell.detector.clone(),
        status,
        error,
        ap,
        pseudo_labels,
        seconds,
    };
    pi3det_data::io::write_atomic(&dir.join("result.json"), &serde_json::to_vec_pretty(&r)?, true)?;
    drop(lock);
    Ok(Some(r))
}

/// The results of the suite's cells found under `out/cells` (with the suite's current config).
pub fn collect(s: &Suite, out: &Path) -> Vec<CellResult> {
    s.cells()
        .iter()
        .filter_map(|c| {
            let dir = out.join("cells").join(cell_dir_name(&s.cell_id(c)));
            let same = std::fs::read_to_string(dir.join("cell.json")).is_ok_and(|k| k == cell_key(s, c));
            read_result(&dir).filter(|_| same)
        })
        .collect()
}

/// Writes the tables of what `out` holds (with intervals from `resamples` bootstrap draws).
pub fn write_tables(s: &Suite, out: &Path, resamples: usize) -> Result<Vec<CellResult>> {
    let results = collect(s, out);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut md = table::markdown(s, &results);
    let run = stats::SeedRun { seed: s.seed, suite: s, out, results: &results };
    md += &stats::comparison(&[run], resamples)?;
    pi3det_data::io::write_atomic(&out.join("benchmark.md"), md.as_bytes(), true)?;
    pi3det_data::io::write_atomic(&out.join("benchmark.csv"), table::csv(&results).as_bytes(), true)?;
    #[derive(Serialize)]
    struct Json<'a> {
        suite: &'a str,
        cells: &'a [CellResult],
        gap_closed: Vec<(String, Vec<(String, f64)>)>,
    }
    let j = Json { suite: &s.name, cells: &results, gap_closed: table::gap_closed(s, &results) };
    pi3det_data::io::write_atomic(&out.join("benchmark.json"), &serde_json::to_vec_pretty(&j)?, true)?;
    table::chart(s, &results, &out.join("gap_closed.png"))?;
    Ok(results)
}

/// Copies the suite's finished cells of `dirs` into `out` (a done cell wins over a failed one;
/// the same cell done in two folders with different configs is an error).
pub fn merge(s: &Suite, dirs: &[PathBuf], out: &Path) -> Result<usize> {
    let mut n = 0;
    for c in s.cells() {
        let name = cell_dir_name(&s.cell_id(&c));
        let key = cell_key(s, &c);
        let mut best: Option<(PathBuf, Status)> = None;
        for d in dirs {
            let src = d.join("cells").join(&name);
            let Some(r) = read_result(&src) else { continue };
            if std::fs::read_to_string(src.join("cell.json")).ok().as_deref() != Some(key.as_str()) {
                bail!("{}: ran with another config than this suite's", src.display());
            }
            if best.as_ref().is_none_or(|(_, st)| *st == Status::Failed && r.status == Status::Done) {
                best = Some((src, r.status));
            }
        }
        if let Some((src, _)) = best {
            let dst = out.join("cells").join(&name);
            if dst != src {
                if dst.exists() {
                    std::fs::remove_dir_all(&dst).with_context(|| format!("clearing {}", dst.display()))?;
                }
                copy_dir(&src, &dst)?;
            }
            n += 1;
        }
    }
    Ok(n)
}

fn copy_dir(src: &Path, dst: &Path) -> Result<()> {
    std::fs::create_dir_all(dst).with_context(|| format!("creating {}", dst.display()))?;
    for e in std::fs::read_dir(src).with_context(|| format!("reading {}", src.display()))? {
        let e = e?;
        let to = dst.join(e.file_name());
        if e.file_type()?.is_dir() {
            copy_dir(&e.path(), &to)?;
        } else {
            std::fs::copy(e.path(), &to).with_context(|| format!("copying {}", e.path().display()))?;
        }
    }
    Ok(())
}

pub fn run(args: &BenchmarkArgs) -> Result<Vec<CellResult>> {
    let s = Suite::from_file(&args.suite)?;
    if args.list {
        for c in select(&s, &args.only, args.shard)? {
            println!("{}", s.cell_id(&c));
        }
        return Ok(Vec::new());
    }
    if !args.merge.is_empty() {
        let n = merge(&s, &args.merge, &args.out)?;
        let results = write_tables(&s, &args.out, args.bootstrap)?;
        eprintln!("merged {n} cells from {} folders → {}", args.merge.len(), args.out.join("benchmark.md").display());
        return Ok(results);
    }
    let cells = select(&s, &args.only, args.shard)?;
    let device = args.device.setup(0)?;
    if args.seeds.is_empty() {
        let results = run_seed(&s, &args.out, &cells, args, device)?;
        print!("{}", std::fs::read_to_string(args.out.join("benchmark.md")).unwrap_or_default());
        return Ok(results);
    }
    let mut seeds = args.seeds.clone();
    seeds.sort_unstable();
    seeds.dedup();
    let suites: Vec<Suite> = seeds.iter().map(|&seed| Suite { seed, ..s.clone() }).collect();
    let outs: Vec<PathBuf> = seeds.iter().map(|seed| args.out.join(format!("seed_{seed}"))).collect();
    let mut all = Vec::new();
    for (suite, out) in suites.iter().zip(&outs) {
        eprintln!("seed {}: {}", suite.seed, out.display());
        all.push(run_seed(suite, out, &cells, args, device)?);
    }
    let runs: Vec<stats::SeedRun<'_>> = suites
        .iter()
        .zip(&outs)
        .zip(&all)
        .map(|((suite, out), results)| stats::SeedRun { seed: suite.seed, suite, out, results })
        .collect();
    let md = format!(
        "# Benchmark `{}`, seeds {seeds:?}\n\nPer-seed tables: {}.\n{}{}",
        s.name,
        outs.iter().map(|o| format!("`{}`", o.join("benchmark.md").display())).collect::<Vec<_>>().join(", "),
        stats::comparison(&runs, args.bootstrap)?,
        table::notes(&s)
    );
    pi3det_data::io::write_atomic(&args.out.join("benchmark.md"), md.as_bytes(), true)?;
    print!("{md}");
    Ok(all.into_iter().flatten().collect())
}

/// Runs `cells` of `s` in `out` (skipping finished ones) and writes its tables.
fn run_seed(
    s: &Suite,
    out: &Path,
    cells: &[Cell],
    args: &BenchmarkArgs,
    device: tch::Device,
) -> Result<Vec<CellResult>> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let ctx = Ctx { suite: s, out, device };
    let t0 = Instant::now();
    let (mut ran, mut skipped, mut failed) = (0, 0, 0);
    for c in cells {
        let id = s.cell_id(c);
        let key = cell_key(s, c);
        let dir = out.join("cells").join(cell_dir_name(&id));
        if !args.force && finished(&dir, &key) {
            eprintln!("[{id}] finished earlier with the same config: skipped");
            skipped += 1;
            continue;
        }
        let Some(r) = run_one(&ctx, c, &key)? else {
            skipped += 1;
            continue;
        };
        ran += 1;
        if r.status == Status::Failed {
            failed += 1;
        }
    }
    let results = write_tables(s, out, args.bootstrap)?;
    eprintln!(
        "{ran} cells run ({failed} failed), {skipped} skipped, in {:.0} s → {}",
        t0.elapsed().as_secs_f64(),
        out.join("benchmark.md").display()
    );
    Ok(results)
}
