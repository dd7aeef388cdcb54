//! The Monte Carlo commands: `tolray tolerance`, `sensitivity` and `merge`.

use crate::args::{parse_shard, LensArgs, TolArgs};
use crate::report::{emit, fmt_list, tolerance_text, with_progress, write_text};
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::figures;
use tolray::tolerance::{merge_reports, monte_carlo, sensitivity, McReport};

/// Arguments of `tolray tolerance`.
#[derive(Args)]
pub struct ToleranceArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    #[command(flatten)]
    pub tol: TolArgs,
    /// Number of trials of the study.
    #[arg(long, default_value_t = 1000)]
    pub trials: usize,
    /// Random seed; trial k uses pattern k of this seed.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Run only shard K of N (K from 0, e.g. $SLURM_ARRAY_TASK_ID) and write a partial report.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,
    /// Write the report (every trial with its pattern, statistics, yield) as JSON.
    #[arg(long, value_name = "FILE.json")]
    pub json: Option<PathBuf>,
    /// Write a histogram and CDF picture (PNG at 2 pixels per point, or SVG if FILE ends in .svg).
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
    /// Write the pattern of trial K to a file, to re-trace it with `spot --perturb`.
    #[arg(long, value_names = ["K", "FILE.json"], num_args = 2)]
    pub save_pattern: Option<Vec<String>>,
}

/// Runs `tolray tolerance`.
pub fn run(a: ToleranceArgs) -> anyhow::Result<()> {
    let ToleranceArgs {
        lens,
        tol,
        trials,
        seed,
        shard,
        json,
        png,
        save_pattern,
    } = a;
    let (l, file_fields) = lens.load_with_fields()?;
    let opts = tol.options(&l, trials, seed, file_fields)?;
    let shard = shard.as_deref().map(parse_shard).transpose()?;
    eprintln!(
        "tolerance spec (pivot at each element's {:?} vertex):\n{}",
        opts.spec.pivot,
        opts.spec.to_json().trim_end()
    );
    let n = shard.map_or(trials, |(k, n)| (k + 1) * trials / n - k * trials / n);
    let report = with_progress(n as u64, "trials", |tick| {
        monte_carlo(&l, &lens.lens, &opts, shard, tick)
    })?;
    emit(&tolerance_text(&report));
    if let Some(p) = json {
        write_text(&p, &(serde_json::to_string_pretty(&report)? + "\n"))?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(p) = png {
        figures::save(&figures::tolerance_figure(&report), &p)?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(v) = save_pattern {
        let k: usize = v[0]
            .parse()
            .map_err(|_| anyhow::anyhow!("--save-pattern: \"{}\" is not a trial number", v[0]))?;
        let t = report
            .trials
            .iter()
            .find(|t| t.index == k)
            .ok_or_else(|| anyhow::anyhow!("--save-pattern: trial {k} is not in this run"))?;
        write_text(Path::new(&v[1]), &t.pattern.to_json())?;
        eprintln!("wrote the pattern of trial {k} to {}", v[1]);
    }
    Ok(())
}

/// Arguments of `tolray sensitivity`.
#[derive(Args)]
pub struct SensitivityArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    #[command(flatten)]
    pub tol: TolArgs,
    /// Write the table as JSON.
    #[arg(long, value_name = "FILE.json")]
    pub json: Option<PathBuf>,
    /// Rows to print.
    #[arg(long, default_value_t = 20)]
    pub top: usize,
}

/// Runs `tolray sensitivity`.
pub fn run_sensitivity(a: SensitivityArgs) -> anyhow::Result<()> {
    let SensitivityArgs {
        lens,
        tol,
        json,
        top,
    } = a;
    let (l, file_fields) = lens.load_with_fields()?;
    let opts = tol.options(&l, 0, 0, file_fields)?;
    let (nominal, rows) = sensitivity(&l, &opts)?;
    let fields: Vec<String> = opts.fields.iter().map(|f| f.label()).collect();
    let c = opts.criterion;
    let (label, nom) = match &nominal.criterion {
        Some(v) => (c.label(), v.clone()),
        None => ("RMS spot (µm)".to_string(), nominal.rms_um.clone()),
    };
    emit(&format!(
        "Sensitivity of {label} to each operand alone at -max / +max{}; nominal per field {}: {}\n",
        if opts.compensate_focus {
            ", refocused"
        } else {
            ""
        },
        fields.join(", "),
        fmt_list(&nom)
    ));
    emit(&format!(
        "{:>16} {:>6} {:>4} {:>10}   {:<30} {:<30} {:>10}\n",
        "operand", "target", "axis", "max", "at -max", "at +max", "worst |d|"
    ));
    for r in rows.iter().take(top) {
        let (minus, plus, worst) = match (&r.criterion_minus, &r.criterion_plus) {
            (Some(a), Some(b)) => (a, b, r.worst_delta_criterion.unwrap_or(f64::NAN)),
            _ => (&r.rms_minus_um, &r.rms_plus_um, r.worst_delta_um),
        };
        emit(&format!(
            "{:>16} {:>6} {:>4} {:>7} {:<3}  {:<30} {:<30} {:>10.4}\n",
            format!("{:?}", r.operand).to_lowercase(),
            r.target,
            if r.operand.axes() == 1 {
                "-"
            } else {
                ["x", "y", "z"][r.axis]
            },
            r.max,
            r.operand.unit(),
            fmt_list(minus),
            fmt_list(plus),
            worst
        ));
    }
    if let Some(p) = json {
        write_text(
            &p,
            &(serde_json::to_string_pretty(&serde_json::json!({
                "criterion": c.spelling(),
                "nominal_rms_um": nominal.rms_um,
                "nominal_criterion": nominal.criterion,
                "rows": rows
            }))? + "\n"),
        )?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

/// Arguments of `tolray merge`.
#[derive(Args)]
pub struct MergeArgs {
    /// Shard reports (JSON).
    #[arg(required = true)]
    pub parts: Vec<PathBuf>,
    /// Output report.
    #[arg(long, value_name = "FILE.json")]
    pub json: PathBuf,
    /// Write a histogram and CDF picture (PNG at 2 pixels per point, or SVG if FILE ends in .svg).
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
}

/// Runs `tolray merge`.
pub fn run_merge(a: MergeArgs) -> anyhow::Result<()> {
    let MergeArgs { parts, json, png } = a;
    let reports = parts
        .iter()
        .map(|p| -> anyhow::Result<McReport> {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("{}: cannot read", p.display()))?;
            serde_json::from_str(&text)
                .with_context(|| format!("{}: not a tolray tolerance report", p.display()))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let merged = merge_reports(&reports)?;
    emit(&tolerance_text(&merged));
    write_text(&json, &(serde_json::to_string_pretty(&merged)? + "\n"))?;
    if let Some(p) = png {
        figures::save(&figures::tolerance_figure(&merged), &p)?;
    }
    Ok(())
}
