//! `cargo xtask trade`: what each minute of CPU buys with each sampler (or any variant of the
//! configuration), measured: every variant trained to the same wall-time budgets, over several
//! seeds and scenes; a table of Chamfer, accuracy, completeness, F-score, PSNR (masked where
//! the scene has masks) and normal consistency as mean ± std, the iterations each variant fits
//! in the budget (the run-level cost of guidance: grid updates and surface losses included), and
//! a plot of the first six (the distances, the F-score, the masked PSNR) against wall time with
//! error bars.
//!
//! Runs are folders `OUT/SCENE/VARIANT/bBUDGET/sSEED`; a run whose `metrics.json` exists is not
//! run again, so an interrupted table resumes where it stopped. The paper's ablation is the same
//! command with one budget and variants of the guided configuration (`--variant NAME:key=v,…`).

use anyhow::{Context, Result, bail};
use datasets::io::write_atomic;
use prob_grid::ShapeName;
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use trainer::config::{Budget, SamplerKind, TrainConfig, parse_duration, parse_overrides};
use trainer::folder::checkpoint_path;
use trainer::metrics::RunMetrics;
use trainer::plot::{Panel, Point, Series, render};
use trainer::run::{AtomicFiles, Outcome, RunOptions, RunRequest};
use trainer::snapshot::SnapshotMetrics;

/// Options of `cargo xtask trade`.
#[derive(clap::Args, Debug)]
pub struct TradeArgs {
    /// Dataset folders (repeat); each is a scene.
    #[arg(long)]
    pub data: Vec<PathBuf>,
    /// Built-in scenes by shape (repeat): composite, multipart, …. Default: composite when no
    /// --data is given.
    #[arg(long, value_parser = ShapeName::from_name)]
    pub scene: Vec<ShapeName>,
    /// Wall-time budgets (repeat): 60s, 2m, …
    #[arg(long, default_value = "60s", value_parser = parse_duration)]
    pub budget: Vec<Duration>,
    /// Seeds 0 … n − 1.
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Variants (repeat) `NAME` or `NAME:key=value,key=value`; `uniform`, `guided`, `error-map`
    /// and `soft-mining` alone mean the samplers. Default: uniform and guided.
    #[arg(long, value_parser = parse_variant)]
    pub variant: Vec<Variant>,
    /// Output folder.
    #[arg(long, default_value = "out/trade")]
    pub out: PathBuf,
    /// Only aggregate the runs already in the folder (no training).
    #[arg(long)]
    pub report_only: bool,
    /// One run per scene, variant and seed, trained to the longest budget; the shorter budgets'
    /// rows are its snapshots (`output.snapshots`) at those training times. A snapshot's schedules
    /// (learning rate, s, coarse-to-fine levels) follow the longest budget, so its row is the
    /// quality along one run, not that of a run given the shorter budget. The table reads their
    /// metrics only, so they keep no checkpoint unless `output.snapshot_checkpoints=true` is given.
    #[arg(long)]
    pub snapshots: bool,
    /// Overrides `key=value` shared by every run.
    pub overrides: Vec<String>,
}

/// A named set of overrides.
#[derive(Debug, Clone)]
pub struct Variant {
    name: String,
    overrides: Vec<String>,
    /// The sampler a variant named after one stands for (unless its overrides set one).
    sampler: Option<SamplerKind>,
}

/// `NAME` or `NAME:key=value,key=value`.
fn parse_variant(text: &str) -> std::result::Result<Variant, String> {
    let (name, rest) = text.split_once(':').unwrap_or((text, ""));
    if name.is_empty() {
        return Err(format!("{text:?}: a variant needs a name"));
    }
    let overrides: Vec<String> = rest.split(',').map(str::trim).filter(|s| !s.is_empty()).map(String::from).collect();
    let sets_sampler = overrides.iter().any(|o| o.split_once('=').is_some_and(|(key, _)| key.trim() == "sampler"));
    let sampler = SamplerKind::from_name(name).ok().filter(|_| !sets_sampler);
    Ok(Variant { name: name.to_string(), overrides, sampler })
}

/// The folder name of a budget: exact (`b120`, `b90.5`), so that two budgets never share runs.
fn budget_dir(budget: Duration) -> String {
    format!("b{}", budget.as_secs_f64())
}

/// What a run of the table was made with, kept beside its metrics: a folder is reused only for
/// the same scene, variant, overrides, budget, seed and snapshot times (`--snapshots`).
fn run_record(scene: &SceneSpec, variant: &Variant, overrides: &[String], budget: Duration, seed: u64, snapshots: &[f64]) -> Value {
    let scene = match scene {
        SceneSpec::Folder(p) => p.display().to_string(),
        SceneSpec::Builtin(s) => format!("builtin:{s}"),
    };
    let sampler = variant.sampler.map(SamplerKind::name);
    let mut record =
        json!({"scene": scene, "variant": variant.name, "overrides": overrides, "sampler": sampler, "budget_s": budget.as_secs_f64(), "seed": seed});
    if !snapshots.is_empty() {
        record["snapshots_s"] = json!(snapshots);
    }
    record
}

/// Fails when two entries have the same name (they would share run folders).
fn distinct_names<'a>(what: &str, names: impl Iterator<Item = String> + 'a) -> Result<()> {
    let mut seen = std::collections::BTreeSet::new();
    for n in names {
        if !seen.insert(n.clone()) {
            bail!("two {what} are named {n:?}: they would share run folders (rename one)");
        }
    }
    Ok(())
}

/// A scene of the table: a folder or a built-in shape.
#[derive(Debug, Clone)]
enum SceneSpec {
    Folder(PathBuf),
    Builtin(ShapeName),
}

impl SceneSpec {
    fn name(&self) -> String {
        match self {
            SceneSpec::Folder(p) => p.file_name().map_or("data".into(), |n| n.to_string_lossy().into_owned()),
            SceneSpec::Builtin(s) => format!("builtin-{s}"),
        }
    }
}

/// A figure of a run's metrics that a table reports.
type Figure = fn(&RunMetrics) -> Option<f64>;

/// The metrics a table reports: key, label for tables and plots, the figure.
/// The first six are plotted.
const METRICS: [(&str, &str, Figure); 9] = [
    ("chamfer", "Chamfer (normalised units) ↓", |m| m.chamfer),
    ("chamfer_observed", "Chamfer over what the views observe ↓", |m| m.observed.as_ref().and_then(|o| o.chamfer)),
    ("accuracy", "accuracy (normalised units) ↓", |m| m.accuracy),
    ("completeness", "completeness (normalised units) ↓", |m| m.completeness),
    ("f_score", "F-score ↑", |m| m.f_score),
    ("psnr_masked", "PSNR inside the masks (dB) ↑", |m| m.psnr_masked),
    ("psnr", "PSNR, whole image (dB) ↑", |m| m.psnr),
    ("normal_consistency", "normal consistency ↑", |m| m.normal_consistency),
    ("normal_consistency_observed", "normal consistency over what the views observe ↑", |m| m.observed.as_ref().and_then(|o| o.normal_consistency)),
];

/// Mean and sample standard deviation.
fn mean_std(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 { v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { 0.0 };
    Some((mean, var.sqrt()))
}

/// The metrics of a finished run of the table (`None`: not run yet); an unreadable file is an
/// error naming it.
fn read_metrics(dir: &Path) -> Result<Option<RunMetrics>> {
    if !dir.join("metrics.json").is_file() {
        return Ok(None);
    }
    Ok(RunMetrics::read(dir).map(Some)?)
}

/// Runs the table (or only reports it).
pub fn run(args: &TradeArgs, stop: &AtomicBool) -> Result<()> {
    let mut scenes: Vec<SceneSpec> = args.data.iter().cloned().map(SceneSpec::Folder).collect();
    scenes.extend(args.scene.iter().cloned().map(SceneSpec::Builtin));
    if scenes.is_empty() {
        scenes.push(SceneSpec::Builtin(ShapeName::Composite));
    }
    let variants: Vec<Variant> = if args.variant.is_empty() {
        [SamplerKind::Uniform, SamplerKind::Guided]
            .map(|kind| Variant { name: kind.name().into(), overrides: Vec::new(), sampler: Some(kind) })
            .to_vec()
    } else {
        args.variant.clone()
    };
    let budgets = &args.budget;
    // The budgets trained: each, or only the longest when the others are its snapshots.
    let longest = budgets.iter().copied().max().context("--budget: give at least one")?;
    let trained: Vec<Duration> = if args.snapshots { vec![longest] } else { budgets.clone() };
    let snapshot_times: Vec<f64> =
        if args.snapshots { budgets.iter().filter(|b| **b < longest).map(Duration::as_secs_f64).collect() } else { Vec::new() };
    if args.seeds == 0 {
        bail!("--seeds must be ≥ 1");
    }
    distinct_names("scenes", scenes.iter().map(SceneSpec::name))?;
    distinct_names("variants", variants.iter().map(|v| v.name.clone()))?;
    distinct_names("budgets", budgets.iter().map(|b| budget_dir(*b)))?;
    let sink = Arc::new(AtomicFiles);
    let total = scenes.len() * variants.len() * trained.len() * args.seeds as usize;
    let mut done = 0;
    // Seeds outermost, then budgets, scenes and variants: an interrupted table has every
    // variant at the same seeds.
    for seed in 0..args.seeds {
        for &budget in &trained {
            for scene in &scenes {
                for variant in &variants {
                    done += 1;
                    let dir = args.out.join(scene.name()).join(&variant.name).join(budget_dir(budget)).join(format!("s{seed}"));
                    let mut overrides = args.overrides.clone();
                    overrides.extend(variant.overrides.iter().cloned());
                    let record = run_record(scene, variant, &overrides, budget, seed, &snapshot_times);
                    if read_metrics(&dir)?.is_some() {
                        let kept = std::fs::read_to_string(dir.join("trade_run.json")).ok().and_then(|t| serde_json::from_str::<Value>(&t).ok());
                        if kept.as_ref() != Some(&record) {
                            bail!("{} holds a run made with other settings than this table's ({record}); use another --out", dir.display());
                        }
                        continue;
                    }
                    if args.report_only {
                        continue;
                    }
                    eprintln!("trade: run {done}/{total}: {} · {} · {:.0} s · seed {seed}", scene.name(), variant.name, budget.as_secs_f64());
                    // An interrupted run resumes from its checkpoint; a folder without one starts over.
                    let resume = checkpoint_path(&dir).is_file();
                    if !resume && dir.exists() {
                        std::fs::remove_dir_all(&dir).with_context(|| format!("clearing the unfinished run {}", dir.display()))?;
                    }
                    let request = if resume {
                        RunRequest::Resume { dir: dir.clone(), data: None }
                    } else {
                        // A sweep's snapshots are read for their metrics: no checkpoint each
                        // (≈ 20 MB for the default model) unless the overrides, applied after
                        // this default, ask for them.
                        let mut values = vec![("output.snapshot_checkpoints".to_string(), toml::Value::Boolean(false))];
                        values.extend(parse_overrides(&overrides)?);
                        let mut config = TrainConfig::load_values(None, &values).with_context(|| format!("the variant {:?}", variant.name))?;
                        config.seed = seed;
                        if let Some(kind) = variant.sampler {
                            config.sampler = kind;
                        }
                        if let SceneSpec::Builtin(shape) = scene {
                            config.data.builtin.shape = *shape;
                        }
                        config.budget = Budget::Time(budget);
                        config.output.snapshots.extend(&snapshot_times);
                        RunRequest::Fresh {
                            config: Box::new(config),
                            data: match scene {
                                SceneSpec::Folder(p) => Some(p.clone()),
                                SceneSpec::Builtin(_) => None,
                            },
                            out: dir.clone(),
                            overwrite: false,
                        }
                    };
                    let outcome = trainer::run::run(&request, &RunOptions::default(), stop, sink.clone())
                        .with_context(|| format!("the run in {}", dir.display()))?;
                    if let Outcome::Stopped { .. } = outcome {
                        bail!("stopped; run the same command again to continue the table");
                    }
                    write_atomic(&dir.join("trade_run.json"), serde_json::to_string_pretty(&record)?.as_bytes())?;
                    write_atomic(&dir.join(MACHINE_FILE), crate::machine::Machine::this().line().as_bytes())?;
                }
            }
        }
    }
    report(args, &scenes, &variants, budgets)
}

/// The file of a run folder that names the machine the table trained it on.
const MACHINE_FILE: &str = "trade_machine.txt";

/// The machines the runs in `dirs` were trained on ([`MACHINE_FILE`]), each once.
fn machines(dirs: &[PathBuf]) -> Vec<String> {
    let mut names: Vec<String> =
        dirs.iter().map(|d| std::fs::read_to_string(d.join(MACHINE_FILE)).unwrap_or_else(|_| "machine not recorded".into())).collect();
    names.sort();
    names.dedup();
    names
}

/// The runs of one row of the table (seeds 0 … n − 1 that have finished), their folders, and with
/// `--snapshots` for a budget shorter than the longest, the longest budget whose runs' snapshots
/// they are.
fn read_row(args: &TradeArgs, scene: &SceneSpec, variant: &Variant, budget: Duration) -> Result<(Vec<RunMetrics>, Vec<PathBuf>, Option<Duration>)> {
    let longest = args.budget.iter().copied().max().unwrap_or(budget);
    let snapshot_of = (args.snapshots && budget < longest).then_some(longest);
    let base = args.out.join(scene.name()).join(&variant.name).join(budget_dir(snapshot_of.unwrap_or(budget)));
    let (mut runs, mut dirs) = (Vec::new(), Vec::new());
    for s in 0..args.seeds {
        let dir = base.join(format!("s{s}"));
        let run = if snapshot_of.is_none() {
            read_metrics(&dir)?
        } else if let Some(snapshot) = SnapshotMetrics::read(&dir, budget.as_secs_f64())? {
            let (config, _) = trainer::folder::read_run_config(&dir)?;
            Some(snapshot.as_run_metrics(config.sampler))
        } else {
            None
        };
        if let Some(run) = run {
            runs.push(run);
            dirs.push(dir);
        }
    }
    Ok((runs, dirs, snapshot_of))
}

/// Aggregates the runs in the folder: trade.md, trade.json, trade.png.
fn report(args: &TradeArgs, scenes: &[SceneSpec], variants: &[Variant], budgets: &[Duration]) -> Result<()> {
    let colours = [
        [0.2, 0.35, 0.85],
        [0.85, 0.15, 0.15],
        [0.15, 0.6, 0.25],
        [0.6, 0.3, 0.7],
        [0.9, 0.55, 0.1],
        [0.3, 0.3, 0.3],
        [0.1, 0.65, 0.7],
        [0.7, 0.55, 0.2],
    ];
    let mut md = String::new();
    let mut all = Vec::new();
    let mut panels = Vec::new();
    for scene in scenes {
        md += &format!(
            "\n### {}\n\n| budget | variant | runs | iterations | s / iteration | grid s | {} | machine |\n|---|---|---|---|---|---|{}---|\n",
            scene.name(),
            METRICS.iter().map(|m| m.1).collect::<Vec<_>>().join(" | "),
            "---|".repeat(METRICS.len())
        );
        // (variant, metric) → points (budget, mean, std).
        let mut curves: BTreeMap<(usize, &str), Vec<Point>> = BTreeMap::new();
        for &budget in budgets {
            for (vi, variant) in variants.iter().enumerate() {
                let (runs, dirs, snapshot_of) = read_row(args, scene, variant, budget)?;
                let machines = machines(&dirs);
                if runs.is_empty() {
                    continue;
                }
                let get = |figure: Figure| -> Vec<f64> { runs.iter().filter_map(figure).collect() };
                // A run whose mesh has no point within the outlier distance of the truth has an
                // infinite Chamfer (JSON null): said, never silently left out of the mean.
                let unbounded = runs.iter().filter(|r| r.chamfer.is_none() && r.mesh_triangles > 0 && r.f_score.is_some()).count();
                let fmt = |(key, _, figure): &(&str, &str, Figure)| {
                    let cell = match mean_std(&get(*figure)) {
                        Some((m, s)) if key.starts_with("psnr") => format!("{m:.2} ± {s:.2}"),
                        Some((m, s)) if *key == "f_score" => format!("{m:.3} ± {s:.3}"),
                        Some((m, s)) => format!("{m:.4} ± {s:.4}"),
                        None => "—".into(),
                    };
                    let distance = matches!(*key, "chamfer" | "chamfer_observed" | "accuracy" | "completeness");
                    if distance && unbounded > 0 {
                        format!("{cell} over {} runs; {unbounded} with no part of the mesh near the truth (∞)", runs.len() - unbounded)
                    } else {
                        cell
                    }
                };
                let iterations = mean_std(&get(|r| Some(r.steps as f64))).map_or("—".into(), |(m, s)| format!("{m:.0} ± {s:.0}"));
                let per_iteration = mean_std(&get(RunMetrics::seconds_per_iteration)).map_or("—".into(), |(m, s)| format!("{m:.3} ± {s:.3}"));
                let grid = match snapshot_of {
                    Some(_) => "—".into(),
                    None => mean_std(&get(|r| Some(r.grid_s))).map_or("—".into(), |(m, _)| format!("{m:.1}")),
                };
                let seconds = budget.as_secs_f64();
                let label = snapshot_of.map_or(String::new(), |of| format!(" (snapshot of {:.0} s)", of.as_secs_f64()));
                md += &format!(
                    "| {seconds:.0} s{label} | {} | {} | {iterations} | {per_iteration} | {grid} | {} | {} |\n",
                    variant.name,
                    runs.len(),
                    METRICS.iter().map(fmt).collect::<Vec<_>>().join(" | "),
                    machines.join("; ")
                );
                for (key, _, figure) in METRICS {
                    if let Some((m, s)) = mean_std(&get(figure)) {
                        curves.entry((vi, key)).or_default().push((seconds, m, (runs.len() > 1).then_some(s)));
                    }
                }
                all.push(json!({"scene": scene.name(), "variant": variant.name, "overrides": variant.overrides, "sampler": variant.sampler.map(SamplerKind::name), "budget_s": seconds, "machines": machines, "runs": runs}));
            }
        }
        for (key, label, _) in METRICS.iter().take(6) {
            let series: Vec<Series> = variants
                .iter()
                .enumerate()
                .filter_map(|(vi, v)| {
                    curves.get(&(vi, *key)).map(|points| Series { label: v.name.clone(), color: colours[vi % colours.len()], points: points.clone() })
                })
                .collect();
            if !series.is_empty() {
                panels.push(Panel {
                    title: format!("{}: {}", scene.name(), label.trim_end_matches(['↑', '↓', ' '])),
                    x_label: "training wall-time budget (s)".into(),
                    y_label: label.to_string(),
                    series,
                    markers: Vec::new(),
                });
            }
        }
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let tau = all.iter().find_map(|g| g["runs"][0]["f_score_tau"].as_f64()).map_or(String::new(), |t| format!(" F-score at τ = {t}."));
    let header = format!(
        "Mean ± std over seeds (sample std; n = runs). Budgets are training wall time (grid updates and surface losses included; validation pictures, checkpoints, the final mesh and evaluation excluded). Metrics in the normalised frame (the bound is the unit sphere).{tau}\n"
    );
    write_atomic(&args.out.join("trade.md"), format!("{header}{md}").as_bytes())?;
    write_atomic(&args.out.join("trade.json"), serde_json::to_string_pretty(&json!({"groups": all}))?.as_bytes())?;
    if !panels.is_empty() {
        render(&panels, 5.min(panels.len()), (420, 320))?.save_png(&args.out.join("trade.png"))?;
    }
    print!("{header}{md}");
    println!(
        "\ntables: {}, runs: {}, plot: {}",
        args.out.join("trade.md").display(),
        args.out.join("trade.json").display(),
        args.out.join("trade.png").display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sampler's name stands for the sampler (typed, not an override text) unless the variant's
    /// overrides set one; other names are plain override sets; a variant needs a name.
    #[test]
    fn variants_named_after_a_sampler_set_it_unless_their_overrides_do() {
        let v = parse_variant("soft-mining").unwrap();
        assert_eq!((v.name.as_str(), v.sampler, v.overrides.len()), ("soft-mining", Some(SamplerKind::SoftMining), 0));
        let v = parse_variant("guided: sampler = uniform, render.rays=128").unwrap();
        assert_eq!((v.sampler, v.overrides), (None, vec!["sampler = uniform".to_string(), "render.rays=128".to_string()]));
        let v = parse_variant("small:render.rays=64").unwrap();
        assert_eq!((v.sampler, v.overrides.len()), (None, 1));
        // A key that only starts like "sampler" does not count as setting it.
        assert_eq!(parse_variant("guided:sampler_extra=1").unwrap().sampler, Some(SamplerKind::Guided));
        assert!(parse_variant(":render.rays=64").is_err());
    }
}
