//! The deep-optics commands: `deep` (the study), `evaluate`, `render`.

use crate::report::{emit_line, write_text};
use crate::usage;
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::decoder::DecoderKind;
use tolray::deep::eval::{evaluate, example_images, report, EvalConfig, EvalImages, Report};
use tolray::deep::html::{render as render_html, Examples};
use tolray::deep::study::{self, StudyConfig};
use tolray::deep::{psf_options, rgb_psf_map_of, DeepConfig};
use tolray::image::render::{render, Blend, PsfMap, SensorNoise};
use tolray::image::source::TrainImages;
use tolray::image::Image;
use tolray::optim::train::{Checkpoints, RunControl};
use tolray::tolerance::{Perturbation, ToleranceSpec};
use tolray::Lens;

/// Settings of the evaluation, shared by `deep` and `evaluate`.
#[derive(Args, Clone)]
pub struct EvalArgs {
    /// Random fabricated units (tolerance patterns) per design.
    #[arg(long, default_value_t = 100)]
    pub trials: usize,
    /// Seed of the evaluation patterns (training uses another).
    #[arg(long, default_value_t = 1_000_003)]
    pub eval_seed: u64,
    /// Rays per PSF of the evaluation PSF maps.
    #[arg(long, default_value_t = 8192)]
    pub eval_spp: usize,
    /// Block side per PSF tile of the evaluation images, pixels (images are 8 x this).
    #[arg(long, default_value_t = 48)]
    pub patch: usize,
    /// Built-in photographs in the evaluation set besides the dead-leaves image (0 to 4).
    #[arg(long, default_value_t = 2)]
    pub photos: usize,
    /// Evaluate on the PNG/JPEG images of this folder instead (centre crops).
    #[arg(long, value_name = "DIR")]
    pub eval_images: Option<PathBuf>,
    /// Refocus each fabricated unit to its best RMS focus (the assembly's compensator).
    #[arg(long, value_name = "focus", value_parser = ["focus"])]
    pub compensate: Option<String>,
    /// Tolerance spec (default: the paper's Table A1).
    #[arg(long, value_name = "SPEC.json")]
    pub spec: Option<PathBuf>,
    /// The PSFs the evaluated units are imaged with: geometric (rays on pixels) or diffraction
    /// (the pupil function's FFT on the same pixels: Airy disk and diffraction of the aberrated
    /// wavefront). In `deep` and `demo` training uses them too unless --train-psf says.
    #[arg(long = "psf", default_value = "geometric", value_parser = ["geometric", "diffraction"])]
    pub psf_model: String,
}

impl EvalArgs {
    /// The evaluation's defaults with `trials` units and the tolerance spec `spec`.
    pub fn defaults(trials: usize, spec: Option<PathBuf>) -> EvalArgs {
        EvalArgs {
            trials,
            eval_seed: 1_000_003,
            eval_spp: 8192,
            patch: 48,
            photos: 2,
            eval_images: None,
            compensate: None,
            spec,
            psf_model: "geometric".into(),
        }
    }

    pub(crate) fn config(
        &self,
        lens: &Lens,
        noise: SensorNoise,
        grid: usize,
        ks: usize,
    ) -> anyhow::Result<(EvalConfig, EvalImages)> {
        if self.trials == 0 || self.trials > 100_000 {
            usage!("--trials {}: give 1 to 100000", self.trials);
        }
        if self.patch == 0 || !self.patch.is_multiple_of(8) || self.patch > 256 {
            usage!("--patch {}: give a multiple of 8 up to 256", self.patch);
        }
        if self.photos > 4 {
            usage!("--photos {}: there are 4 built-in photographs", self.photos);
        }
        let spec = match &self.spec {
            Some(p) => ToleranceSpec::read(p)?,
            None => ToleranceSpec::default(),
        };
        spec.validate(lens)?;
        let cfg = EvalConfig {
            trials: self.trials,
            seed: self.eval_seed,
            spec,
            grid,
            ks,
            spp: self.eval_spp,
            noise_sigma: noise.sigma,
            full_well_electrons: noise.full_well_electrons,
            patch_px: self.patch,
            compensate_focus: self.compensate.is_some(),
            bootstrap: 2000,
            psf: if self.psf_model == "diffraction" {
                tolray::psf::PsfModel::Diffraction
            } else {
                tolray::psf::PsfModel::Geometric
            },
        };
        let side = grid * self.patch;
        let images = match &self.eval_images {
            Some(d) => EvalImages::from_dir(d, side)?,
            None => EvalImages::builtin(side, self.photos, self.eval_seed)?,
        };
        Ok((cfg, images))
    }
}

/// `tolray deep`: the study.
#[derive(Args)]
pub struct DeepArgs {
    /// Lens JSON file or built-in name (not with --resume).
    #[arg(required_unless_present = "resume", conflicts_with = "resume")]
    pub lens: Option<String>,
    /// Continue the study in DIR exactly where its checkpoint stopped (every setting comes from
    /// the checkpoint; the output directory is DIR).
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// Iterations between checkpoints (`checkpoint.json`; 0: only on Ctrl-C).
    #[arg(long, default_value_t = 25)]
    pub checkpoint_every: usize,
    /// Output directory: designs, logs, report.json, report.html.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Iterations of the spot-loss focus fit (stage 0).
    #[arg(long, default_value_t = 300)]
    pub spot_iters: usize,
    /// Iterations of stage 1 (lens and decoder, no tolerances).
    #[arg(long, default_value_t = 200)]
    pub stage1_iters: usize,
    /// Iterations of each design's stage 2 (tolerance-aware; the conventional design trains as
    /// long without tolerances).
    #[arg(long, default_value_t = 100)]
    pub stage2_iters: usize,
    /// Training crops (and tolerance patterns) per iteration (the paper: 64).
    #[arg(long, default_value_t = 32)]
    pub samples: usize,
    /// Side of the training crops, pixels (the paper: 256).
    #[arg(long, default_value_t = 32)]
    pub crop: usize,
    /// Decoder: wiener, unet or wiener+unet.
    #[arg(long, default_value = "wiener+unet")]
    pub decoder: String,
    /// U-Net width (channels of its first level).
    #[arg(long, default_value_t = 8)]
    pub unet_width: usize,
    /// Rays per PSF during training.
    #[arg(long, default_value_t = 256)]
    pub psf_spp: usize,
    /// Gaussian noise σ (linear [0, 1] units; the paper: 0.01).
    #[arg(long, default_value_t = 0.01)]
    pub noise: f64,
    /// Electrons of a full well (signal 1): adds photon shot noise, variance signal / full well,
    /// to the Gaussian noise (which is then the read noise: electrons / full well). Off: the
    /// paper's Gaussian noise alone.
    #[arg(long, value_name = "ELECTRONS")]
    pub full_well_electrons: Option<f64>,
    /// Weight of the spot loss in the image stages (per mm).
    #[arg(long, default_value_t = 0.1)]
    pub lambda_spot: f64,
    /// Weight of the PSF-similarity loss in stage 2.
    #[arg(long, default_value_t = 0.01)]
    pub lambda_psf: f64,
    /// Train on random flipped blocks of the PNG/JPEG images of this folder (e.g. DIV2K) instead
    /// of the built-in dead leaves.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
    /// Refocus each sampled unit in the tolerance phases before imaging it (what a fabricated,
    /// focused unit delivers); independent of the evaluation's `--compensate`. Each unit's
    /// refocus is its best RMS focus for the current design, and the lens gradient includes its
    /// derivative (README, "Deep optics").
    #[arg(long, value_name = "focus", value_parser = ["focus"])]
    pub train_compensate: Option<String>,
    /// The PSFs training renders with and differentiates: geometric (rays on pixels, the
    /// paper's) or diffraction (the pupil function's FFT on the same pixels, its exact
    /// gradient by dual numbers; several times slower). Default: as --psf.
    #[arg(long, value_name = "MODEL", value_parser = ["geometric", "diffraction"])]
    pub train_psf: Option<String>,
    /// Skip the decoder-only control.
    #[arg(long)]
    pub no_decoder_only: bool,
    /// Also train the optics-only control (the paper's Table 3: decoder frozen after stage 1,
    /// lens trained with tolerances).
    #[arg(long)]
    pub optics_only: bool,
    /// Iterations between validation-PSNR measurements on a held-out batch of fabricated units
    /// (0: none; otherwise the end of every phase is measured too).
    #[arg(long, default_value_t = 10)]
    pub validate_every: usize,
    /// Training seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub eval: EvalArgs,
}

pub fn deep(a: &DeepArgs) -> anyhow::Result<()> {
    let lens;
    let (cfg, start, out) = match &a.resume {
        Some(dir) => {
            let ck = study::read_checkpoint(dir)?;
            (
                ck.config.clone(),
                study::Start::Checkpoint(Box::new(ck)),
                dir.clone(),
            )
        }
        None => {
            lens = Lens::load(a.lens.as_deref().unwrap_or_default())?;
            (
                study_config(a, &lens)?,
                study::Start::Lens(&lens),
                a.out.clone(),
            )
        }
    };
    let images = cfg.eval_images()?;
    run_study(cfg, start, &images, &out, a.checkpoint_every, "tolray deep")
}

/// The sensor noise of `--noise` and `--full-well-electrons`, checked (usage errors name the flag).
pub(crate) fn sensor_noise(noise: f64, full_well: Option<f64>) -> anyhow::Result<SensorNoise> {
    if !(noise >= 0.0 && noise.is_finite()) {
        usage!("--noise {noise}: must be zero or positive");
    }
    if let Some(f) = full_well {
        if !(f >= 1.0 && f.is_finite()) {
            usage!("--full-well-electrons {f}: give a finite number of at least 1");
        }
    }
    Ok(SensorNoise {
        sigma: noise,
        full_well_electrons: full_well,
    })
}

/// The study settings of the flags.
fn study_config(a: &DeepArgs, lens: &Lens) -> anyhow::Result<StudyConfig> {
    let mut d = DeepConfig::for_lens(lens);
    d.optics.samples = a.samples;
    d.optics.seed = a.seed;
    d.optics.psf_spp = a.psf_spp;
    d.crop_px = a.crop;
    d.decoder = DecoderKind::parse(&a.decoder)?;
    d.unet_width = a.unet_width;
    let sensor = sensor_noise(a.noise, a.full_well_electrons)?;
    d.noise_sigma = sensor.sigma;
    d.full_well_electrons = sensor.full_well_electrons;
    d.lambda_spot = a.lambda_spot;
    d.lambda_psf = a.lambda_psf;
    d.compensate_focus = a.train_compensate.is_some();
    d.psf = match a.train_psf.as_deref().unwrap_or(&a.eval.psf_model) {
        "diffraction" => tolray::psf::PsfModel::Diffraction,
        _ => tolray::psf::PsfModel::Geometric,
    };
    if let Some(p) = &a.eval.spec {
        d.optics.spec = ToleranceSpec::read(p)?;
    }
    d.validate()?;
    if let Some(dir) = &a.images {
        d.train_images = TrainImages::from_dir(dir, d.crop_px + d.optics.psf_ks - 1)?;
    }
    let (eval, _) = a
        .eval
        .config(lens, sensor, d.optics.psf_grid, d.optics.psf_ks)?;
    Ok(StudyConfig {
        deep: d,
        spot_iters: a.spot_iters,
        stage1_iters: a.stage1_iters,
        stage2_iters: a.stage2_iters,
        conventional: true,
        tolerance_aware: true,
        decoder_only: !a.no_decoder_only,
        optics_only: a.optics_only,
        evaluate_stage1: false,
        validate_every: a.validate_every,
        eval,
        eval_photos: a.eval.photos,
        eval_images_dir: a.eval.eval_images.clone(),
    })
}

/// Runs (or continues) the study with progress lines, checkpoints and Ctrl-C (a checkpoint, then
/// exit code 130, naming `command` to resume with), and writes the report.
pub(crate) fn run_study(
    cfg: StudyConfig,
    start: study::Start<'_>,
    images: &EvalImages,
    out: &Path,
    checkpoint_every: usize,
    command: &str,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create directory", out.display()))?;
    write_text(
        &out.join("study.json"),
        &(serde_json::to_string_pretty(&cfg)? + "\n"),
    )?;
    let t0 = std::time::Instant::now();
    let mut last = std::time::Instant::now();
    let mut progress = |p: study::Progress<'_>| {
        let (branch, l) = match p {
            study::Progress::Focus(l, n) => {
                if last.elapsed().as_secs_f64() > 5.0 || l.iter % 50 == 0 || l.iter + 1 == n {
                    last = std::time::Instant::now();
                    eprintln!(
                        "[{:6.0} s] {:16} iter {:4} of {n}: spot loss {:.3e}, RMS spot {:.1} µm",
                        t0.elapsed().as_secs_f64(),
                        "focus fit",
                        l.iter,
                        l.loss,
                        l.spot_um
                    );
                }
                return;
            }
            study::Progress::Image(branch, l) => (branch, l),
        };
        if last.elapsed().as_secs_f64() > 5.0 || l.iter % 50 == 0 || l.val_psnr_db.is_some() {
            last = std::time::Instant::now();
            eprintln!(
                "[{:6.0} s] {branch:16} iter {:4}: image loss {:.3e}, batch PSNR {:.2} dB, spot {:.1} µm{}",
                t0.elapsed().as_secs_f64(),
                l.iter,
                l.image_loss,
                l.psnr_db,
                l.spot_um,
                l.psf_similarity
                    .map_or(String::new(), |s| format!(", PSF similarity {s:.3}"))
                    + &l.val_psnr_db
                        .map_or(String::new(), |v| format!(", validation PSNR {v:.2} dB"))
            );
        }
    };
    crate::app::GRACEFUL_STOP.store(true, std::sync::atomic::Ordering::SeqCst);
    let stop = || crate::app::STOP_REQUESTED.load(std::sync::atomic::Ordering::SeqCst);
    // `--checkpoint-every 0`: only when stopped.
    let ctl = RunControl {
        checkpoints: Checkpoints::every(checkpoint_every),
        stop: &stop,
    };
    let Some(report) = study::run_resumable(start, &cfg, images, out, ctl, &mut progress)? else {
        eprintln!(
            "interrupted: checkpoint written to {}; continue with `{command} --resume {}`",
            out.join("checkpoint.json").display(),
            out.display()
        );
        std::process::exit(130);
    };
    eprintln!("[{:6.0} s] evaluated", t0.elapsed().as_secs_f64());
    finish(
        &report,
        out,
        images,
        &out.join("report.json"),
        &out.join("report.html"),
    )?;
    Ok(())
}

/// `tolray evaluate`.
#[derive(Args)]
pub struct EvaluateArgs {
    /// Design directories (each with lens.json and decoder.bin, as `deep` writes them).
    #[arg(required = true)]
    pub designs: Vec<PathBuf>,
    /// Gaussian noise σ (linear [0, 1] units) [default: the designs' training sensor
    /// (`sensor.json`), else 0.01].
    #[arg(long)]
    pub noise: Option<f64>,
    /// Electrons of a full well (signal 1): adds photon shot noise, variance signal / full well,
    /// to the Gaussian noise (which is then the read noise: electrons / full well) [default: the
    /// designs' training sensor, else off].
    #[arg(long, value_name = "ELECTRONS")]
    pub full_well_electrons: Option<f64>,
    /// Run only slice K of N of the trials (e.g. 0/4); `merge-eval` combines the slices.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,
    /// Output report.
    #[arg(long, value_name = "FILE.json")]
    pub json: PathBuf,
    /// Output HTML report.
    #[arg(long, value_name = "FILE.html")]
    pub html: Option<PathBuf>,
    #[command(flatten)]
    pub eval: EvalArgs,
}

fn design_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Parses `K/N` into the trial range of slice K of N (the Monte Carlo's slicing).
fn shard_range(s: &str, trials: usize) -> anyhow::Result<std::ops::Range<usize>> {
    let kn = s.split_once('/').and_then(|(k, n)| {
        Some((
            k.trim().parse::<usize>().ok()?,
            n.trim().parse::<usize>().ok()?,
        ))
    });
    match kn {
        Some((k, n)) if n > 0 && k < n => Ok(k * trials / n..(k + 1) * trials / n),
        _ => usage!("--shard {s}: give K/N with 0 <= K < N"),
    }
}

pub fn evaluate_cmd(a: &EvaluateArgs) -> anyhow::Result<()> {
    let designs: Vec<_> = a
        .designs
        .iter()
        .map(|p| Ok((design_name(p), study::load_design(p)?)))
        .collect::<anyhow::Result<_>>()?;
    let d0 = &designs[0].1;
    let sensor = evaluation_sensor(a)?;
    let (cfg, images) = a
        .eval
        .config(&d0.lens, sensor, d0.decoder.grid, d0.decoder.ks)?;
    let range = match &a.shard {
        None => 0..cfg.trials,
        Some(s) => shard_range(s, cfg.trials)?,
    };
    let mut scores = Vec::new();
    for (name, d) in &designs {
        eprintln!("evaluating {name} on {} units", range.len());
        scores.push(evaluate(name, d, &images, &cfg, range.clone())?);
    }
    let names: Vec<String> = designs.iter().map(|d| d.0.clone()).collect();
    let pairs: Vec<(String, String)> = names
        .iter()
        .skip(1)
        .map(|b| (names[0].clone(), b.clone()))
        .collect();
    let img_names: Vec<String> = images.images.iter().map(|i| i.0.clone()).collect();
    let r = report(&cfg, &img_names, scores, &pairs)?;
    let html = a.html.as_ref().map(|h| (h.clone(), designs));
    print_report(&r);
    write_text(&a.json, &(serde_json::to_string_pretty(&r)? + "\n"))?;
    eprintln!("wrote {}", a.json.display());
    if let Some((path, designs)) = html {
        let examples = examples(&r, &images, &designs)?;
        write_text(&path, &render_html(&r, &examples))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// The sensor of `tolray evaluate`: the flags where given, else the sensor the designs were
/// trained under (their `sensor.json`, which must agree), else the paper's σ = 0.01. A design
/// trained under another sensor than the one evaluated is named on stderr.
fn evaluation_sensor(a: &EvaluateArgs) -> anyhow::Result<SensorNoise> {
    // The designs that record their training sensor, with it.
    let known: Vec<(String, SensorNoise)> = a
        .designs
        .iter()
        .map(|p| Ok(study::load_sensor(p)?.map(|s| (design_name(p), s))))
        .collect::<anyhow::Result<Vec<_>>>()?
        .into_iter()
        .flatten()
        .collect();
    let sensor = if a.noise.is_some() || a.full_well_electrons.is_some() {
        sensor_noise(a.noise.unwrap_or(0.01), a.full_well_electrons)?
    } else {
        match known.first() {
            None => SensorNoise::gaussian(0.01),
            Some((first, s)) => {
                if let Some((n, _)) = known.iter().find(|t| t.1 != *s) {
                    usage!(
                        "designs {first} and {n} were trained under different sensors ({}): give --noise (and --full-well-electrons) to evaluate both under one",
                        study::SENSOR_FILE
                    );
                }
                *s
            }
        }
    };
    for (n, s) in &known {
        if *s != sensor {
            eprintln!(
                "warning: design {n} was trained with noise σ {}{}; evaluating with σ {}{}",
                s.sigma,
                full_well(s),
                sensor.sigma,
                full_well(&sensor)
            );
        }
    }
    Ok(sensor)
}

fn full_well(s: &SensorNoise) -> String {
    s.full_well_electrons
        .map_or(String::new(), |f| format!(" and a {f}-electron full well"))
}

/// `tolray merge-eval`: combines evaluation shards into the single-run report.
#[derive(Args)]
pub struct MergeEvalArgs {
    /// Shard reports (`evaluate --shard K/N --json ...`).
    #[arg(required = true)]
    pub parts: Vec<PathBuf>,
    /// Output report.
    #[arg(long, value_name = "FILE.json")]
    pub json: PathBuf,
}

pub fn merge_eval(a: &MergeEvalArgs) -> anyhow::Result<()> {
    let parts: Vec<Report> = a
        .parts
        .iter()
        .map(|p| Ok(tolray::files::read_json(p)?))
        .collect::<anyhow::Result<_>>()?;
    let r = tolray::deep::eval::merge(&parts)?;
    print_report(&r);
    write_text(&a.json, &(serde_json::to_string_pretty(&r)? + "\n"))?;
    eprintln!("wrote {}", a.json.display());
    Ok(())
}

/// `tolray pool-eval`: pools the reports of studies that differ only in their training seed.
#[derive(Args)]
pub struct PoolEvalArgs {
    /// Study directories (their report.json) or evaluation reports, one per training seed, all
    /// evaluated with the same settings (the same fabricated units).
    #[arg(required = true, value_name = "DIR|REPORT.json")]
    pub reports: Vec<PathBuf>,
    /// Also write the pooled comparison as JSON.
    #[arg(long, value_name = "FILE.json")]
    pub json: Option<PathBuf>,
}

pub fn pool_eval(a: &PoolEvalArgs) -> anyhow::Result<()> {
    let reports: Vec<Report> = a
        .reports
        .iter()
        .map(|p| {
            let f = if p.is_dir() {
                p.join("report.json")
            } else {
                p.clone()
            };
            Ok(tolray::files::read_json(&f)?)
        })
        .collect::<anyhow::Result<_>>()?;
    let r = tolray::deep::eval::pool(&reports)?;
    emit_line(&format!(
        "{} studies (training seeds) on the same {} fabricated units; intervals: two-level \
         bootstrap ({} resamples of seeds and units), 95 %",
        r.studies, r.trials, r.bootstrap
    ));
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:+.3}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    for p in &r.pairs {
        emit_line(&format!(
            "{} − {}: mean PSNR per seed {}; pooled {:+.3} dB [{:+.3}, {:+.3}]",
            p.a,
            p.b,
            list(&p.per_seed_mean_diff),
            p.psnr_mean_diff,
            p.psnr_mean_diff_ci95[0],
            p.psnr_mean_diff_ci95[1]
        ));
        emit_line(&format!(
            "{} − {}: PSNR @90 % per seed {}; pooled {:+.3} dB [{:+.3}, {:+.3}]",
            p.a,
            p.b,
            list(&p.per_seed_yield90_diff),
            p.psnr_yield90_diff,
            p.psnr_yield90_diff_ci95[0],
            p.psnr_yield90_diff_ci95[1]
        ));
    }
    if let Some(j) = &a.json {
        write_text(j, &(serde_json::to_string_pretty(&r)? + "\n"))?;
        eprintln!("wrote {}", j.display());
    }
    Ok(())
}

/// The best, median and worst unit of each design, rendered again for the HTML report.
fn examples(
    r: &Report,
    images: &EvalImages,
    designs: &[(String, tolray::deep::Design)],
) -> anyhow::Result<Examples> {
    let mut out = Vec::new();
    for s in &r.scores {
        let Some((_, d)) = designs.iter().find(|(n, _)| *n == s.name) else {
            continue;
        };
        let mut order: Vec<&tolray::deep::eval::TrialScore> = s.trials.iter().collect();
        order.sort_by(|a, b| b.psnr.total_cmp(&a.psnr));
        let mut list = Vec::new();
        if let (Some(best), Some(worst)) = (order.first(), order.last()) {
            let median = order[order.len() / 2];
            for (label, t) in [("best", *best), ("median", median), ("worst", *worst)] {
                let imgs = example_images(d, images, &r.config, Some(t.index))?;
                if let Some(first) = imgs.into_iter().next() {
                    list.push((format!("{label} unit (pattern {})", t.index), t.psnr, first));
                }
            }
        }
        out.push((s.name.clone(), list));
    }
    Ok(out)
}

fn print_report(r: &Report) {
    let (header, rows) = r.design_table();
    let width = |k: usize| {
        rows.iter()
            .map(|row| row[k].chars().count())
            .chain([header[k].chars().count()])
            .max()
            .unwrap_or(0)
    };
    let widths: Vec<usize> = (0..header.len()).map(width).collect();
    let line = |cells: &[&str]| {
        let mut s = format!("{:<w$}", cells[0], w = widths[0]);
        for (c, w) in cells.iter().zip(&widths).skip(1) {
            s.push_str(&format!("  {c:>w$}"));
        }
        s
    };
    emit_line(&line(&header));
    for row in &rows {
        emit_line(&line(&row.iter().map(String::as_str).collect::<Vec<_>>()));
    }
    for p in &r.pairs {
        emit_line(&format!(
            "{} − {}: mean PSNR {:+.3} dB [{:+.3}, {:+.3}], PSNR @90 % {:+.3} dB [{:+.3}, {:+.3}] (bootstrap 95 %)",
            p.a, p.b, p.psnr_mean_diff, p.psnr_mean_diff_ci95[0], p.psnr_mean_diff_ci95[1],
            p.psnr_yield90_diff, p.psnr_yield90_diff_ci95[0], p.psnr_yield90_diff_ci95[1]
        ));
    }
}

/// Writes the report (JSON and HTML with the examples of the study's designs in `dir`).
fn finish(
    r: &Report,
    dir: &Path,
    images: &EvalImages,
    json: &Path,
    html: &Path,
) -> anyhow::Result<()> {
    print_report(r);
    write_text(json, &(serde_json::to_string_pretty(r)? + "\n"))?;
    let designs: Vec<_> = r
        .scores
        .iter()
        .map(|s| Ok((s.name.clone(), study::load_design(&dir.join(&s.name))?)))
        .collect::<anyhow::Result<_>>()?;
    write_text(html, &render_html(r, &examples(r, images, &designs)?))?;
    eprintln!("wrote {} and {}", json.display(), html.display());
    Ok(())
}

/// `tolray render`: a capture simulated through a lens' RGB PSF map.
#[derive(Args)]
pub struct RenderArgs {
    /// Lens JSON file or built-in name.
    pub lens: String,
    /// Input image (PNG or JPEG, sRGB).
    #[arg(long, value_name = "IN.png")]
    pub image: PathBuf,
    /// Output capture (PNG, sRGB).
    #[arg(long, value_name = "OUT.png")]
    pub out: PathBuf,
    /// Also write the linear capture as OpenEXR.
    #[arg(long, value_name = "OUT.exr")]
    pub exr: Option<PathBuf>,
    /// Trace the lens perturbed by this tolerance pattern.
    #[arg(long, value_name = "PATTERN.json")]
    pub perturb: Option<PathBuf>,
    /// Gaussian noise σ (linear [0, 1] units).
    #[arg(long, default_value_t = 0.01)]
    pub noise: f64,
    /// Electrons of a full well (signal 1): adds photon shot noise, variance signal / full well,
    /// to the Gaussian noise (which is then the read noise: electrons / full well). Off: the
    /// paper's Gaussian noise alone.
    #[arg(long, value_name = "ELECTRONS")]
    pub full_well_electrons: Option<f64>,
    /// PSF grid per side.
    #[arg(long, default_value_t = 8)]
    pub grid: usize,
    /// PSF kernel size, pixels (odd).
    #[arg(long, default_value_t = 51)]
    pub ks: usize,
    /// Rays per PSF.
    #[arg(long, default_value_t = 8192)]
    pub spp: usize,
    /// Seed of the rays and the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// How PSFs meet between fields: `tiles` (each tile its own PSF, as training and
    /// evaluation) or `bilinear` (blended between the four surrounding field centres; ~4x slower).
    #[arg(long, value_enum, default_value = "tiles")]
    pub blend: BlendArg,
    /// PSF model: geometric (rays on pixels) or diffraction (the pupil function's FFT on the
    /// same pixels).
    #[arg(long = "psf", default_value = "geometric", value_parser = ["geometric", "diffraction"])]
    pub psf_model: String,
}

/// `--blend`.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum BlendArg {
    Tiles,
    Bilinear,
}

pub fn render_cmd(a: &RenderArgs) -> anyhow::Result<()> {
    let sensor = sensor_noise(a.noise, a.full_well_electrons)?;
    if a.grid == 0 || a.grid > 64 {
        usage!("--grid {}: give 1 to 64", a.grid);
    }
    let lens = Lens::load(&a.lens)?;
    let img = Image::load(&a.image)?;
    let sys = match &a.perturb {
        None => lens.compile(),
        Some(p) => {
            let (pl, adj) = Perturbation::read(p)?.apply(&lens)?;
            tolray::lens::System::compile(&pl, &adj, &|_, v| v)
        }
    };
    let opts = psf_options(&lens, a.ks, a.spp, a.seed);
    tolray::psf::check_options(&opts)?;
    let model = if a.psf_model == "diffraction" {
        tolray::psf::PsfModel::Diffraction
    } else {
        tolray::psf::PsfModel::Geometric
    };
    let psfs = rgb_psf_map_of(model, &lens, &sys, a.grid, &lens.rgb_wavelengths_nm, &opts)?;
    let map = PsfMap::new(a.grid, a.ks, psfs)?;
    let blend = match a.blend {
        BlendArg::Tiles => Blend::Tiles,
        BlendArg::Bilinear => Blend::Bilinear,
    };
    let mut y = render(&img, &map, blend)?;
    sensor.add(&mut y.data, a.seed, 0);
    y.save_png(&a.out)?;
    let shot = sensor.full_well_electrons.map_or(String::new(), |f| {
        format!(" and shot noise of a {f}-electron full well")
    });
    emit_line(&format!(
        "rendered {} ({}x{} px) through {} with a {g}x{g} RGB PSF map of {k}x{k} px kernels, noise σ {}{shot}",
        a.image.display(), img.width, img.height, a.lens, a.noise, g = a.grid, k = a.ks
    ));
    eprintln!("wrote {}", a.out.display());
    if let Some(e) = &a.exr {
        y.save_exr(e)?;
        eprintln!("wrote {}", e.display());
    }
    Ok(())
}
