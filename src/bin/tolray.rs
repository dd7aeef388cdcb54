//! The `tolray` command-line tool. Exit codes: 0 success, 1 runtime error, 2 usage error.
// `!(x >= 0.0)` refuses NaN too, on purpose (as in the library).
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use anyhow::{bail, Context};
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use tolray::analysis::{spot_diagram, SpotOptions, SpotResult};
use tolray::lens::material::{self, LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use tolray::lens::{json, zemax, GlassCatalogs, Paraxial};
use tolray::optim::train::{held_out, step, IterLog, TrainConfig, TrainState};
use tolray::psf::{PsfCentre, PsfOptions, PsfRays};
use tolray::tolerance::analysis::Stats;
use tolray::tolerance::{
    merge_reports, monte_carlo, sensitivity, McOptions, McReport, Perturbation, ToleranceSpec,
};
use tolray::trace::raw::{parse_csv, parse_json, to_csv, trace_raw};
use tolray::trace::{Field, Pupil, TraceOptions};
use tolray::{figures, Lens, Object};

#[path = "tolray/deep.rs"]
mod deep;

/// A bad flag value: exit code 2, as for what clap refuses.
#[derive(Debug)]
struct Usage(String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Returns a usage error (exit code 2) with a formatted message.
#[macro_export]
macro_rules! usage {
    ($($t:tt)*) => {
        return Err(anyhow::Error::new($crate::Usage(format!($($t)*))))
    };
}

#[derive(Parser)]
#[command(
    name = "tolray",
    version,
    about = "Tolerance-aware lens design: exact ray tracing, spots and tolerances for refractive lenses.\n\nLengths in mm, spot sizes in µm, wavelengths in nm, angles in degrees. Surfaces are counted from 0.\nA LENS is a DeepLens JSON file, a Zemax .zmx file or a built-in name: lens1, lens2, cooke-triplet."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Paraxial data and prescription of a lens.
    Info {
        #[command(flatten)]
        lens: LensArgs,
        /// Wavelength for the paraxial data, nm (default: the lens' primary wavelength).
        #[arg(long, value_name = "NM")]
        wavelength: Option<f64>,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Spot diagrams and RMS spot radii per field and wavelength.
    Spot {
        #[command(flatten)]
        lens: LensArgs,
        #[command(flatten)]
        rays: RayArgs,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Write a spot-diagram picture.
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
        /// Trace the lens perturbed by this tolerance pattern (JSON, as written by `tolerance --json`).
        #[arg(long, value_name = "PATTERN.json")]
        perturb: Option<PathBuf>,
    },
    /// Monte Carlo tolerance analysis: RMS spot statistics and yield over random fabricated lenses.
    Tolerance {
        #[command(flatten)]
        lens: LensArgs,
        #[command(flatten)]
        tol: TolArgs,
        /// Number of trials of the study.
        #[arg(long, default_value_t = 1000)]
        trials: usize,
        /// Random seed; trial k uses pattern k of this seed.
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Run only shard K of N (K from 0, e.g. $SLURM_ARRAY_TASK_ID) and write a partial report.
        #[arg(long, value_name = "K/N")]
        shard: Option<String>,
        /// Write the report (every trial with its pattern, statistics, yield) as JSON.
        #[arg(long, value_name = "FILE.json")]
        json: Option<PathBuf>,
        /// Write a histogram and CDF picture.
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
        /// Write the pattern of trial K to a file, to re-trace it with `spot --perturb`.
        #[arg(long, value_names = ["K", "FILE.json"], num_args = 2)]
        save_pattern: Option<Vec<String>>,
    },
    /// Sensitivity: each tolerance operand alone at -max and +max, worst first.
    Sensitivity {
        #[command(flatten)]
        lens: LensArgs,
        #[command(flatten)]
        tol: TolArgs,
        /// Write the table as JSON.
        #[arg(long, value_name = "FILE.json")]
        json: Option<PathBuf>,
        /// Rows to print.
        #[arg(long, default_value_t = 20)]
        top: usize,
    },
    /// Geometric PSF of one field (bilinear splat at the sensor pixel pitch, unit sum).
    Psf {
        #[command(flatten)]
        lens: LensArgs,
        /// Field (fraction, 5deg angle or 2.5mm height; x:y pairs allowed).
        #[arg(long, default_value = "0")]
        field: String,
        /// Wavelengths in nm, or d, F, C, rgb (one PSF each).
        #[arg(long, value_delimiter = ',', default_value = "d")]
        wavelengths: Vec<String>,
        #[command(flatten)]
        psf: PsfArgs,
        /// Trace the lens perturbed by this tolerance pattern.
        #[arg(long, value_name = "PATTERN.json")]
        perturb: Option<PathBuf>,
        /// Write the PSF picture.
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
        /// Write the linear PSF(s) as OpenEXR.
        #[arg(long, value_name = "FILE.exr")]
        exr: Option<PathBuf>,
        /// Print the PSF values as JSON.
        #[arg(long)]
        json: bool,
    },
    /// PSF map: PSFs over a grid of fields covering the sensor.
    PsfMap {
        #[command(flatten)]
        lens: LensArgs,
        /// Fields per side of the grid.
        #[arg(long, default_value_t = 8)]
        grid: usize,
        /// Wavelength, nm (or d, F, C).
        #[arg(long, default_value = "d")]
        wavelength: String,
        #[command(flatten)]
        psf: PsfArgs,
        /// Write the map picture (each PSF normalized to its peak).
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
        /// Write the linear mosaic as OpenEXR.
        #[arg(long, value_name = "FILE.exr")]
        exr: Option<PathBuf>,
    },
    /// Two-stage optimization: stage 1 (pretrain) minimizes the RMS spot without tolerances;
    /// stage 2 (tolerance) samples tolerance patterns each iteration and minimizes the spot and
    /// PSF-similarity losses.
    Train {
        /// Lens JSON file or built-in name (ignored with --resume).
        lens: Option<String>,
        /// Object distance from the first vertex in mm, or "inf".
        #[arg(long, value_name = "MM|inf")]
        object: Option<String>,
        /// Which stages to run.
        #[arg(long, default_value = "both", value_parser = ["pretrain", "tolerance", "both"])]
        stage: String,
        /// Iterations per stage.
        #[arg(long, default_value_t = 100)]
        iters: usize,
        /// Iterations of stage 1 when it should differ from --iters.
        #[arg(long)]
        pretrain_iters: Option<usize>,
        /// Tolerance patterns per stage-2 iteration.
        #[arg(long, default_value_t = 64)]
        samples: usize,
        /// Seed of patterns and pupil samples.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output directory: log.jsonl, checkpoint.json, lens-*.json, report, pictures.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Continue the run saved in DIR exactly where it stopped.
        #[arg(long, value_name = "DIR")]
        resume: Option<PathBuf>,
        /// Write a checkpoint every K iterations (and always at the end or on Ctrl-C).
        #[arg(long, default_value_t = 10, value_name = "K")]
        checkpoint_every: usize,
        /// Tolerance spec for stage 2 (default: the paper's Table A1).
        #[arg(long, value_name = "SPEC.json")]
        spec: Option<PathBuf>,
        /// Weight of the spot loss (per mm).
        #[arg(long, default_value_t = 10.0)]
        lambda_spot: f64,
        /// Weight of the PSF-similarity loss.
        #[arg(long, default_value_t = 1.0)]
        lambda_psf: f64,
        /// Rays per PSF in stage 2.
        #[arg(long, default_value_t = 256)]
        psf_spp: usize,
        /// Factor on the learning rates in stage 2 (which fine-tunes the stage-1 design).
        #[arg(long, default_value_t = 0.1)]
        tolerance_lr_scale: f64,
        /// Maximum total track, mm.
        #[arg(long, value_name = "MM")]
        max_track: Option<f64>,
        /// Target effective focal length, mm.
        #[arg(long, value_name = "MM")]
        target_efl: Option<f64>,
        /// Held-out patterns for the final report (seed differs from training). 100 is too few
        /// to compare two designs' spreads: their standard deviations then vary by about 10 %
        /// from one held-out seed to another.
        #[arg(long, default_value_t = 400)]
        eval_trials: usize,
    },
    /// Merge shard reports of one Monte Carlo study into the report a single run gives.
    Merge {
        /// Shard reports (JSON).
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        /// Output report.
        #[arg(long, value_name = "FILE.json")]
        json: PathBuf,
        /// Write a histogram and CDF picture.
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
    },
    /// Raw ray trace: rays from a CSV/JSON file to the image plane.
    Trace {
        #[command(flatten)]
        lens: LensArgs,
        /// Input rays: CSV with columns ox,oy,oz,dx,dy,dz,wavelength_nm (mm, global frame; directions need not be normalized), or a .json array of such objects.
        #[arg(long, value_name = "FILE")]
        rays: PathBuf,
        /// Output: one row per input ray, x,y,z,dx,dy,dz,opl_mm,status (CSV, or JSON if the name ends in .json).
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Ignore clear apertures and the stop.
        #[arg(long)]
        no_apertures: bool,
    },
    /// Meridional lens drawing with a ray fan per field.
    Layout {
        #[command(flatten)]
        lens: LensArgs,
        /// Output picture.
        #[arg(long, value_name = "FILE.png")]
        png: PathBuf,
        /// Fields (see `spot --fields`).
        #[arg(long, value_delimiter = ',', default_value = "0,0.7,1")]
        fields: Vec<String>,
        /// Rays per field fan.
        #[arg(long, default_value_t = 7)]
        rays: usize,
    },
    /// Look a glass up in the built-in vendor catalogs (and --glass-catalog files): its vendor,
    /// dispersion formula and coefficients, valid range, catalog n_d / V_d and indices.
    Glass {
        /// Glass name as the vendor writes it (e.g. N-BK7, S-LAH64, H-ZF52); case-insensitive.
        name: String,
        /// A Zemax AGF glass catalog, searched before the built-in glasses (repeatable).
        #[arg(long = "glass-catalog", value_name = "FILE.agf")]
        glass_catalog: Vec<PathBuf>,
        /// Wavelengths in nm at which to print the index (default: F, d, C lines).
        #[arg(long, value_delimiter = ',', value_name = "NM,...")]
        wavelengths: Vec<f64>,
    },
    /// Convert a lens between Zemax .zmx and DeepLens JSON (the formats follow the extensions).
    Convert {
        /// Input lens: a .zmx or .json file, or a built-in name.
        input: String,
        /// Output file, ending in .zmx or .json.
        #[arg(value_parser = lens_output_path)]
        output: PathBuf,
        /// A Zemax AGF glass catalog, searched before the built-in glasses (repeatable).
        #[arg(long = "glass-catalog", value_name = "FILE.agf")]
        glass_catalog: Vec<PathBuf>,
        /// When a .zmx GLAS names a glass in no catalog: "refuse" (default: an error naming the
        /// line) or "file-values" (use the n_d and V_d on the GLAS line as a model glass;
        /// OpticStudio's 1.5 / 40 placeholder is still refused).
        #[arg(long = "glass-fallback", value_name = "refuse|file-values", default_value = "refuse", value_parser = ["refuse", "file-values"])]
        glass_fallback: String,
        /// Write the lens perturbed by this tolerance pattern (surface decenters and tilts become
        /// coordinate breaks in a .zmx file).
        #[arg(long, value_name = "PATTERN.json")]
        perturb: Option<PathBuf>,
    },
    /// Cross-check the analytic tracer against an independent engine: every surface, nominal and
    /// under Monte Carlo tolerance patterns, is tessellated within a chord bound and traced with
    /// Intel Embree 4; hits must lie within the bound of the analytic hits and RMS spots must
    /// agree. Exits with 1 when any deviation exceeds its bound. Needs a build with
    /// `--features embree`.
    Validate {
        #[command(flatten)]
        lens: LensArgs,
        #[command(flatten)]
        args: ValidateArgs,
    },
    /// The main job on built-in defaults: info, spots and pictures for every built-in lens.
    /// The main job: the deep-optics study on lens1 with the built-in defaults (`deep lens1`),
    /// or with --optics the tour of the optics half (paraxial data, spots, Monte Carlo).
    Demo {
        /// Output directory for the pictures and JSON reports.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Run the optics tour instead of the deep-optics study.
        #[arg(long)]
        optics: bool,
        /// Any further `deep` flags, after `--` (e.g. `-- --trials 20`).
        #[arg(last = true)]
        extra: Vec<String>,
    },
    /// Deep optics: lens and decoder trained jointly, conventionally and tolerance-aware, and
    /// evaluated over random fabricated units (PSNR/SSIM, manufacturing yield).
    Deep(deep::DeepArgs),
    /// Evaluates saved designs (lens + decoder) over random fabricated units.
    Evaluate(deep::EvaluateArgs),
    /// Combines `evaluate --shard` reports into the single-run report.
    MergeEval(deep::MergeEvalArgs),
    /// Simulates a capture: an image blurred by the lens' spatially variant RGB PSF map, plus noise.
    Render(deep::RenderArgs),
}

#[derive(Args)]
struct LensArgs {
    /// Lens JSON or Zemax .zmx file, or a built-in name (lens1, lens2, cooke-triplet).
    lens: String,
    /// Object distance from the first vertex in mm, or "inf" (default: from the lens file).
    #[arg(long, value_name = "MM|inf")]
    object: Option<String>,
    /// A Zemax AGF glass catalog, searched before the built-in glasses (repeatable).
    #[arg(long = "glass-catalog", value_name = "FILE.agf")]
    glass_catalog: Vec<PathBuf>,
    /// When a .zmx GLAS names a glass in no catalog: "refuse" (default: an error naming the
    /// line) or "file-values" (use the n_d and V_d on the GLAS line as a model glass;
    /// OpticStudio's 1.5 / 40 placeholder is still refused).
    #[arg(long = "glass-fallback", value_name = "refuse|file-values", default_value = "refuse", value_parser = ["refuse", "file-values"])]
    glass_fallback: String,
}

/// Accepts an output lens path ending in .zmx or .json.
fn lens_output_path(s: &str) -> Result<PathBuf, String> {
    let p = PathBuf::from(s);
    match p.extension().map(|e| e.to_ascii_lowercase()) {
        Some(e) if e == "zmx" || e == "json" => Ok(p),
        _ => Err(format!(
            "\"{s}\": give an output file ending in .zmx or .json"
        )),
    }
}

/// `tolray glass`: what the catalogs say of one glass.
fn glass_text(name: &str, agf: &[PathBuf], wavelengths_nm: &[f64]) -> anyhow::Result<String> {
    let catalogs = load_catalogs(agf, "refuse")?;
    let Some(m) = catalogs.find(name) else {
        let close = catalogs.suggest(name, 5);
        bail!(
            "glass \"{name}\" is in no catalog (built in: {}){}",
            catalogs.vendor_order().join(", "),
            if close.is_empty() {
                String::new()
            } else {
                format!("; closest: {}", close.join(", "))
            }
        );
    };
    let (vendor, formula, nd, vd, range) = match &m {
        material::Material::Catalog(g) => (
            g.vendor.to_string(),
            format!("{:?}", g.dispersion),
            g.nd,
            g.vd,
            g.range_um,
        ),
        material::Material::Agf(g) => (
            format!("{} (AGF file)", g.catalog),
            format!("AGF formula {}: {:?}", g.formula, g.dispersion),
            g.nd,
            g.vd,
            g.range_um,
        ),
        _ => bail!("\"{name}\" is not a catalog glass"),
    };
    let label = m.catalog_name().unwrap_or(name).to_string();
    let mut s = format!("{label}  ({vendor})\n");
    s += &format!("  formula       {formula}\n");
    s += &format!("  valid range   {:.3} – {:.3} µm\n", range.0, range.1);
    s += &format!("  catalog       n_d {nd:.6}, V_d {vd:.4}\n");
    let others: Vec<&str> = material::catalog()
        .iter()
        .filter(|g| g.name.eq_ignore_ascii_case(&label) && g.vendor != vendor)
        .map(|g| g.vendor)
        .collect();
    if !others.is_empty() {
        s += &format!(
            "  also named so in {} (a .zmx file's GCAT decides which is used)\n",
            others.join(", ")
        );
    }
    let wl: Vec<(String, f64)> = if wavelengths_nm.is_empty() {
        vec![
            ("F".into(), LAMBDA_F_NM),
            ("d".into(), LAMBDA_D_NM),
            ("C".into(), LAMBDA_C_NM),
        ]
    } else {
        wavelengths_nm.iter().map(|&w| (String::new(), w)).collect()
    };
    for (line, w) in wl {
        material::check_wavelength_nm(w)?;
        let n = m.index(w);
        let note = if (range.0..=range.1).contains(&(w * 1e-3)) {
            ""
        } else {
            "  (outside the formula's range)"
        };
        s += &format!("  n({w:.4} nm){:3}  {n:.6}{note}\n", line);
    }
    Ok(s)
}

/// Reads the user's AGF catalogs; their warnings go to stderr.
fn load_catalogs(paths: &[PathBuf], fallback: &str) -> anyhow::Result<GlassCatalogs> {
    let (mut catalogs, warnings) = GlassCatalogs::from_files(paths)?;
    catalogs.file_values_fallback = fallback == "file-values";
    for w in warnings {
        eprintln!("warning: {w}");
    }
    Ok(catalogs)
}

#[derive(Args)]
struct RayArgs {
    /// Fields: fraction of the full field (0.7), angle (5deg) or object height (2.5mm); x:y pairs allowed.
    #[arg(long, value_delimiter = ',', default_value = "0,0.5,0.7,1")]
    fields: Vec<String>,
    /// Wavelengths in nm, or d, F, C, rgb (the lens' RGB wavelengths).
    #[arg(long, value_delimiter = ',', default_value = "d")]
    wavelengths: Vec<String>,
    /// Pupil sampling over the paraxial entrance pupil: grid:N, hex:N or random:N.
    #[arg(long, default_value = "grid:64")]
    pupil: String,
    /// Seed for random pupil sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Aim rays at the real stop instead of the paraxial entrance pupil.
    #[arg(long)]
    aim: bool,
    /// Ignore clear apertures and the stop.
    #[arg(long)]
    no_apertures: bool,
}

#[derive(Args)]
struct PsfArgs {
    /// Kernel size, pixels (odd).
    #[arg(long, default_value_t = 51)]
    ks: usize,
    /// Rays per PSF (uniform random over the entrance pupil).
    #[arg(long, default_value_t = 8192)]
    spp: usize,
    /// Pixel pitch in µm (default: the sensor's).
    #[arg(long, value_name = "UM")]
    pitch_um: Option<f64>,
    /// Centre the PSF on the chief ray or on the centroid.
    #[arg(long, default_value = "chief", value_parser = ["chief", "centroid"])]
    centre: String,
    /// Seed of the pupil samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

impl PsfArgs {
    fn options(&self, lens: &Lens) -> anyhow::Result<PsfOptions> {
        let mut o = PsfOptions::for_lens(lens);
        o.ks = self.ks;
        if let Some(p) = self.pitch_um {
            o.pitch_mm = p * 1e-3;
        }
        o.centre = if self.centre == "centroid" {
            PsfCentre::Centroid
        } else {
            PsfCentre::Chief
        };
        o.pupil = Pupil {
            pattern: tolray::trace::PupilPattern::Random {
                n: self.spp,
                seed: self.seed,
            },
            scale: 1.0,
            aim: false,
        };
        tolray::psf::check_options(&o)?;
        Ok(o)
    }
}

fn perturbed_system(
    lens: &Lens,
    perturb: Option<&Path>,
) -> anyhow::Result<tolray::lens::System<f64>> {
    Ok(match perturb {
        None => lens.compile(),
        Some(p) => {
            let pattern = Perturbation::read(p)?;
            let (pl, adj) = pattern.apply(lens).map_err(|e| e.context(p.display()))?;
            tolray::lens::System::compile(&pl, &adj, &|_, v| v)
        }
    })
}

/// The rays of the Monte Carlo commands (`tolerance`, `sensitivity`, `validate`).
#[derive(Args)]
struct RaySampleArgs {
    /// Fields (fractions, 5deg angles or 2.5mm heights).
    #[arg(long, value_delimiter = ',', default_value = "0,0.7,1")]
    fields: Vec<String>,
    /// Wavelengths in nm, or d, F, C, rgb.
    #[arg(long, value_delimiter = ',', default_value = "d")]
    wavelengths: Vec<String>,
    /// Pupil sampling: grid:N, hex:N or random:N (random points seeded by --seed).
    #[arg(long, default_value = "grid:32")]
    pupil: String,
}

impl RaySampleArgs {
    /// The fields, wavelengths (nm) and pupil.
    fn parse(&self, lens: &Lens, seed: u64) -> anyhow::Result<(Vec<Field>, Vec<f64>, Pupil)> {
        Ok((
            parse_fields(&self.fields)?,
            parse_wavelengths(&self.wavelengths, lens)?,
            Pupil::parse(&self.pupil, seed)?,
        ))
    }
}

fn parse_fields(list: &[String]) -> tolray::Result<Vec<Field>> {
    list.iter().map(|f| Field::parse(f)).collect()
}

#[derive(Args)]
struct ValidateArgs {
    /// Use Intel Embree 4 as the reference engine (the only one so far).
    #[arg(long, required = true)]
    embree: bool,
    /// Monte Carlo tolerance patterns after the nominal lens.
    #[arg(long, default_value_t = 100)]
    trials: usize,
    /// Seed; trial k is pattern k of this seed (as in `tolray tolerance`).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Tolerance spec (JSON); default: the paper's Table A1.
    #[arg(long, value_name = "SPEC.json")]
    tolerance_spec: Option<PathBuf>,
    /// Write the full report (every case, surface and field) as JSON.
    #[arg(long, value_name = "FILE.json")]
    json: Option<PathBuf>,
    /// Chord bound of the tessellation, mm: no mesh point is farther than this from its surface.
    #[arg(long, default_value_t = 1e-4, value_name = "MM")]
    chord: f64,
    #[command(flatten)]
    rays: RaySampleArgs,
    /// Frame of the meshes: each surface's own (small f32 coordinates) or the global frame.
    #[arg(long, default_value = "local", value_parser = ["local", "global"])]
    frame: String,
    /// Assert hits and meshes within this multiple of the chord bound instead of the bound
    /// itself (values below 1 assert more than the theorem guarantees).
    #[arg(long, default_value_t = 1.0)]
    bound_scale: f64,
    /// Largest allowed RMS spot difference between the traces, µm.
    #[arg(long, default_value_t = 0.1, value_name = "UM")]
    spot_bound_um: f64,
}

#[derive(Args)]
struct TolArgs {
    /// Tolerance spec (JSON); default: the paper's Table A1 (decenter 0.04 mm, tilt 0.05 deg,
    /// axial shift 0.04 mm per element, curvature 0.3 % per surface; N(0, (max/3)^2) clamped).
    #[arg(long, value_name = "SPEC.json")]
    spec: Option<PathBuf>,
    #[command(flatten)]
    rays: RaySampleArgs,
    /// Compensator: "focus" refocuses the sensor per trial to the best RMS focus.
    #[arg(long, value_parser = ["focus"])]
    compensate: Option<String>,
    /// Ignore clear apertures and the stop.
    #[arg(long)]
    no_apertures: bool,
}

impl TolArgs {
    fn options(&self, lens: &Lens, trials: usize, seed: u64) -> anyhow::Result<McOptions> {
        let spec = match &self.spec {
            Some(p) => ToleranceSpec::read(p)?,
            None => ToleranceSpec::default(),
        };
        spec.validate(lens).map_err(|e| {
            e.context(
                self.spec
                    .as_ref()
                    .map_or("default spec".into(), |p| p.display().to_string()),
            )
        })?;
        let (fields, wavelengths_nm, pupil) = self.rays.parse(lens, seed)?;
        Ok(McOptions {
            spec,
            trials,
            seed,
            fields,
            wavelengths_nm,
            pupil,
            compensate_focus: self.compensate.is_some(),
            apertures: !self.no_apertures,
        })
    }
}

impl LensArgs {
    fn load(&self) -> anyhow::Result<Lens> {
        let catalogs = load_catalogs(&self.glass_catalog, &self.glass_fallback)?;
        let (mut lens, warnings) = Lens::load_with_catalogs(&self.lens, &catalogs)?;
        for w in warnings {
            eprintln!("warning: {w}");
        }
        if let Some(o) = &self.object {
            lens.object = Object::parse(o)?;
        }
        Ok(lens)
    }
}

fn parse_wavelengths(list: &[String], lens: &Lens) -> anyhow::Result<Vec<f64>> {
    let mut out = Vec::new();
    for w in list {
        match w.trim() {
            "d" => out.push(LAMBDA_D_NM),
            "F" => out.push(LAMBDA_F_NM),
            "C" => out.push(LAMBDA_C_NM),
            "rgb" => out.extend(lens.rgb_wavelengths_nm),
            s => match s.parse::<f64>() {
                Ok(v) => out.push(
                    material::check_wavelength_nm(v)
                        .with_context(|| format!("wavelength \"{s}\""))?,
                ),
                _ => usage!("wavelength \"{s}\": give nanometres (e.g. 587.56) or d, F, C, rgb"),
            },
        }
    }
    Ok(out)
}

impl RayArgs {
    fn options(&self, lens: &Lens) -> anyhow::Result<SpotOptions> {
        let fields = parse_fields(&self.fields)?;
        let mut pupil = Pupil::parse(&self.pupil, self.seed)?;
        pupil.aim = self.aim;
        Ok(SpotOptions {
            fields,
            wavelengths_nm: parse_wavelengths(&self.wavelengths, lens)?,
            pupil,
            trace: TraceOptions {
                apertures: !self.no_apertures,
            },
        })
    }
}

fn paraxial_text(lens: &Lens, p: &Paraxial) -> String {
    let obj = match lens.object {
        Object::Infinite => "infinity".to_string(),
        Object::Finite { distance_mm } => format!("{distance_mm} mm"),
    };
    let mut s = format!(
        "{}\n\nParaxial data at {:.4} nm (object at {obj})\n",
        lens.info, p.wavelength_nm
    );
    let rows = [
        ("effective focal length", p.efl_mm, "mm"),
        ("back focal distance", p.bfd_mm, "mm"),
        (
            "paraxial image distance (from last vertex)",
            p.image_distance_mm,
            "mm",
        ),
        (
            "prescribed image distance (from last vertex)",
            lens.image_distance_mm(),
            "mm",
        ),
        ("entrance pupil position (z)", p.entrance_pupil_z_mm, "mm"),
        (
            "entrance pupil diameter",
            p.entrance_pupil_diameter_mm,
            "mm",
        ),
        ("exit pupil position (z)", p.exit_pupil_z_mm, "mm"),
        ("exit pupil diameter", p.exit_pupil_diameter_mm, "mm"),
        ("F-number (infinity)", p.fnum, ""),
        ("working F-number", p.working_fnum, ""),
        ("paraxial magnification", p.magnification, ""),
        ("half field of view (sensor)", p.half_fov_deg, "deg"),
        ("total track", p.total_track_mm, "mm"),
    ];
    for (name, v, unit) in rows {
        s.push_str(&format!("  {name:<46} {v:>14.6} {unit}\n"));
    }
    s.push_str(&format!(
        "  {:<46} {:>14}\n",
        "aperture stop surface", p.stop_surface
    ));
    s.push_str(&format!(
        "  {:<46} {:>14.4} mm ({} x {} px, pitch {:.3} µm)\n\nPrescription (surfaces from 0; radius and gaps in mm)\n",
        "sensor half-diagonal",
        lens.sensor.half_diagonal_mm(),
        lens.sensor.resolution[0],
        lens.sensor.resolution[1],
        lens.sensor.pixel_pitch_mm() * 1e3
    ));
    s.push_str(&format!(
        "  {:>4} {:>10} {:>12} {:>9} {:>10} {:>10}  {}\n",
        "surf", "type", "radius", "conic", "gap", "semi-ap", "material after"
    ));
    for (i, sf) in lens.surfaces.iter().enumerate() {
        let ty = match (sf.role, sf.is_stop, sf.is_aspheric()) {
            (tolray::lens::SurfaceRole::Aperture, _, _) => "stop",
            (_, _, true) => "asphere",
            (_, true, _) => "sphere/stop",
            _ => "sphere",
        };
        let r = if sf.c == 0.0 {
            "inf".to_string()
        } else {
            format!("{:.4}", 1.0 / sf.c)
        };
        s.push_str(&format!(
            "  {i:>4} {ty:>10} {r:>12} {:>9.4} {:>10.4} {:>10.4}  {}\n",
            sf.k,
            sf.d_next_mm,
            sf.semi_aperture_mm,
            sf.material.json_name()
        ));
    }
    for w in lens.warnings() {
        s.push_str(&format!("warning: {w}\n"));
    }
    s
}

fn spot_table(results: &[SpotResult]) -> String {
    let mut s = format!(
        "{:>14} {:>12} {:>8} {:>12} {:>12} {:>12} {:>10} {:>12} {:>12}\n",
        "field",
        "wavelength",
        "rays",
        "RMS (µm)",
        "RMS/chief",
        "geo (µm)",
        "vignetted",
        "centroid x",
        "centroid y"
    );
    for r in results {
        let wl = r
            .wavelength_nm
            .map_or("poly".to_string(), |w| format!("{w:.2} nm"));
        let chief = r
            .stats
            .rms_chief_um
            .map_or("-".to_string(), |v| format!("{v:.4}"));
        s.push_str(&format!(
            "{:>14} {:>12} {:>8} {:>12.4} {:>12} {:>12.4} {:>9.2}% {:>12.6} {:>12.6}\n",
            r.field.label(),
            wl,
            r.stats.n_valid,
            r.stats.rms_um,
            chief,
            r.stats.geo_radius_um,
            100.0 * r.stats.vignetted_fraction,
            r.stats.centroid_mm[0],
            r.stats.centroid_mm[1]
        ));
    }
    s
}

fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    tolray::error::write_atomic(path, text.as_bytes())?;
    Ok(())
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info {
            lens,
            wavelength,
            json,
        } => {
            let l = lens.load()?;
            let p = l.paraxial(wavelength.unwrap_or(l.primary_wavelength_nm))?;
            if json {
                let v = serde_json::json!({ "paraxial": p, "lens": json::to_value(&l), "warnings": l.warnings() });
                emit_line(&serde_json::to_string_pretty(&v)?.to_string());
            } else {
                emit(&paraxial_text(&l, &p).to_string());
            }
        }
        Command::Spot {
            lens,
            rays,
            json,
            png,
            perturb,
        } => {
            let l = lens.load()?;
            let opts = rays.options(&l)?;
            let sys = perturbed_system(&l, perturb.as_deref())?;
            let results = spot_diagram(&l, &sys, &opts)?;
            if json {
                emit_line(&serde_json::to_string_pretty(&results)?.to_string());
            } else {
                emit(&spot_table(&results).to_string());
            }
            if let Some(p) = png {
                figures::save(
                    &figures::spot_figure(&results, &format!("Spot diagram: {}", lens.lens)),
                    &p,
                )?;
                eprintln!("wrote {}", p.display());
            }
        }
        Command::Trace {
            lens,
            rays,
            out,
            no_apertures,
        } => {
            let l = lens.load()?;
            let text = std::fs::read_to_string(&rays)
                .with_context(|| format!("{}: cannot read", rays.display()))?;
            let is_json = |p: &Path| {
                p.extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("json"))
            };
            let input = if is_json(&rays) {
                parse_json(&text)
            } else {
                parse_csv(&text)
            }
            .map_err(|e| e.context(rays.display()))?;
            let hits = trace_raw(
                &l.compile(),
                &input,
                TraceOptions {
                    apertures: !no_apertures,
                },
            );
            let body = if is_json(&out) {
                serde_json::to_string_pretty(&hits)? + "\n"
            } else {
                to_csv(&hits)
            };
            write_text(&out, &body)?;
            let alive = hits.iter().filter(|h| h.status == "alive").count();
            eprintln!(
                "traced {} rays ({alive} reached the image) -> {}",
                hits.len(),
                out.display()
            );
        }
        Command::Layout {
            lens,
            png,
            fields,
            rays,
        } => {
            if rays == 0 || rays > 1000 {
                usage!("--rays {rays}: give 1 to 1000 rays per field");
            }
            let l = lens.load()?;
            let p = l.paraxial(l.primary_wavelength_nm)?;
            let fields = parse_fields(&fields)?;
            figures::save(
                &figures::layout_figure(
                    &l,
                    &l.compile(),
                    &p,
                    &fields,
                    l.primary_wavelength_nm,
                    rays,
                )?,
                &png,
            )?;
            eprintln!("wrote {}", png.display());
        }
        Command::Tolerance {
            lens,
            tol,
            trials,
            seed,
            shard,
            json,
            png,
            save_pattern,
        } => {
            let l = lens.load()?;
            let opts = tol.options(&l, trials, seed)?;
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
                let k: usize = v[0].parse().map_err(|_| {
                    anyhow::anyhow!("--save-pattern: \"{}\" is not a trial number", v[0])
                })?;
                let t = report.trials.iter().find(|t| t.index == k).ok_or_else(|| {
                    anyhow::anyhow!("--save-pattern: trial {k} is not in this run")
                })?;
                write_text(Path::new(&v[1]), &t.pattern.to_json())?;
                eprintln!("wrote the pattern of trial {k} to {}", v[1]);
            }
        }
        Command::Sensitivity {
            lens,
            tol,
            json,
            top,
        } => {
            let l = lens.load()?;
            let opts = tol.options(&l, 0, 0)?;
            let (nominal, rows) = sensitivity(&l, &opts)?;
            let fields: Vec<String> = opts.fields.iter().map(|f| f.label()).collect();
            emit(&format!("Sensitivity of RMS spot (µm) to each operand alone at -max / +max; nominal per field {}: {}\n", fields.join(", "), fmt_list(&nominal)));
            emit(&format!(
                "{:>16} {:>6} {:>4} {:>10}   {:<30} {:<30} {:>10}\n",
                "operand", "target", "axis", "max", "RMS at -max", "RMS at +max", "worst |d|"
            ));
            for r in rows.iter().take(top) {
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
                    fmt_list(&r.rms_minus_um),
                    fmt_list(&r.rms_plus_um),
                    r.worst_delta_um
                ));
            }
            if let Some(p) = json {
                write_text(
                    &p,
                    &(serde_json::to_string_pretty(
                        &serde_json::json!({"nominal_rms_um": nominal, "rows": rows}),
                    )? + "\n"),
                )?;
                eprintln!("wrote {}", p.display());
            }
        }
        Command::Merge { parts, json, png } => {
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
        }
        Command::Psf {
            lens,
            field,
            wavelengths,
            psf,
            perturb,
            png,
            exr,
            json,
        } => {
            let l = lens.load()?;
            let opts = psf.options(&l)?;
            let field = Field::parse(&field)?;
            let wls = parse_wavelengths(&wavelengths, &l)?;
            let sys = perturbed_system(&l, perturb.as_deref())?;
            let pairs: Vec<(Field, f64)> = wls.iter().map(|&w| (field, w)).collect();
            let rays = PsfRays::new(&l, &pairs, &opts.pupil)?;
            let psfs: Vec<Vec<f64>> = (0..pairs.len())
                .map(|k| tolray::psf::psf_of(&sys, &rays, k, &opts, TraceOptions::default()).0)
                .collect();
            for (w, p) in wls.iter().zip(&psfs) {
                tolray::psf::check_landed(p, &format!("PSF at field {}, {w} nm", field.label()))?;
            }
            for (w, p) in wls.iter().zip(&psfs) {
                let c = p[(opts.ks / 2) * opts.ks + opts.ks / 2];
                let ee: f64 = (0..opts.ks * opts.ks)
                    .filter(|k| {
                        ((k / opts.ks) as isize - (opts.ks / 2) as isize).abs() <= 1
                            && ((k % opts.ks) as isize - (opts.ks / 2) as isize).abs() <= 1
                    })
                    .map(|k| p[k])
                    .sum();
                emit_line(&format!("PSF at field {}, {w:.2} nm: {}x{} px of {:.3} µm, sum {:.6}, centre pixel {:.4}, central 3x3 {:.4}", field.label(), opts.ks, opts.ks, opts.pitch_mm * 1e3, p.iter().sum::<f64>(), c, ee));
            }
            if json {
                emit_line(&serde_json::to_string(
                    &serde_json::json!({"ks": opts.ks, "pitch_mm": opts.pitch_mm, "wavelengths_nm": wls, "psf": psfs}),
                )?);
            }
            if let Some(p) = png {
                figures::save(
                    &figures::psf_figure(
                        &psfs,
                        opts.ks,
                        psfs.len(),
                        &format!("PSF {} field {}", lens.lens, field.label()),
                    ),
                    &p,
                )?;
                eprintln!("wrote {}", p.display());
            }
            if let Some(p) = exr {
                let (w, h, v) = figures::mosaic(&psfs, opts.ks, psfs.len());
                figures::save_exr(&p, w, h, &v)?;
                eprintln!("wrote {}", p.display());
            }
        }
        Command::PsfMap {
            lens,
            grid,
            wavelength,
            psf,
            png,
            exr,
        } => {
            let l = lens.load()?;
            let opts = psf.options(&l)?;
            if grid == 0 || grid > 64 {
                usage!("--grid {grid}: give 1 to 64 fields per side");
            }
            // The map holds grid² kernels of ks² f64 values.
            let cells = grid * grid * opts.ks * opts.ks;
            if cells > 1 << 26 {
                usage!(
                    "--grid {grid} with --ks {}: the map would hold {cells} values; at most {} \
                     (512 MB) are allowed",
                    opts.ks,
                    1usize << 26
                );
            }
            let wl = parse_wavelengths(&[wavelength], &l)?[0];
            let map = tolray::psf::psf_map(&l, &l.compile(), grid, wl, &opts)?;
            for (k, p) in map.iter().enumerate() {
                tolray::psf::check_landed(
                    p,
                    &format!("PSF map cell {k} (row-major from the top left)"),
                )?;
            }
            emit_line(&format!(
                "PSF map of {}: {grid}x{grid} fields, {}x{} px kernels, {} rays each, {wl:.2} nm",
                lens.lens, opts.ks, opts.ks, psf.spp
            ));
            if let Some(p) = png {
                figures::save(
                    &figures::psf_figure(
                        &map,
                        opts.ks,
                        grid,
                        &format!("PSF map {} ({grid}x{grid})", lens.lens),
                    ),
                    &p,
                )?;
                eprintln!("wrote {}", p.display());
            }
            if let Some(p) = exr {
                let (w, h, v) = figures::mosaic(&map, opts.ks, grid);
                figures::save_exr(&p, w, h, &v)?;
                eprintln!("wrote {}", p.display());
            }
        }
        Command::Train {
            lens,
            object,
            stage,
            iters,
            pretrain_iters,
            samples,
            seed,
            out,
            resume,
            checkpoint_every,
            spec,
            lambda_spot,
            lambda_psf,
            psf_spp,
            tolerance_lr_scale,
            max_track,
            target_efl,
            eval_trials,
        } => {
            let state = match &resume {
                Some(dir) => {
                    let p = dir.join("checkpoint.json");
                    let text = std::fs::read_to_string(&p)
                        .with_context(|| format!("{}: cannot read the checkpoint", p.display()))?;
                    serde_json::from_str::<TrainState>(&text)
                        .with_context(|| format!("{}: not a tolray checkpoint", p.display()))?
                }
                None => {
                    let Some(name) = lens.as_deref() else {
                        usage!("train needs a LENS (or --resume DIR)")
                    };
                    let mut l = Lens::load(name)?;
                    if let Some(o) = &object {
                        l.object = Object::parse(o)?;
                    }
                    let mut cfg = TrainConfig::for_lens(&l);
                    cfg.pretrain_iters = if stage == "tolerance" {
                        0
                    } else {
                        pretrain_iters.unwrap_or(iters)
                    };
                    cfg.tolerance_iters = if stage == "pretrain" { 0 } else { iters };
                    cfg.samples = samples;
                    cfg.seed = seed;
                    cfg.lambda_spot = lambda_spot;
                    cfg.lambda_psf = lambda_psf;
                    cfg.psf_spp = psf_spp;
                    if !(tolerance_lr_scale > 0.0 && tolerance_lr_scale.is_finite()) {
                        usage!("--tolerance-lr-scale {tolerance_lr_scale}: must be positive");
                    }
                    cfg.tolerance_lr_scale = tolerance_lr_scale;
                    cfg.constraints.max_total_track_mm = max_track;
                    cfg.constraints.target_efl_mm = target_efl;
                    cfg.validate()?;
                    if let Some(p) = &spec {
                        cfg.spec = ToleranceSpec::read(p)?;
                        cfg.spec.validate(&l).map_err(|e| e.context(p.display()))?;
                    }
                    std::fs::create_dir_all(&out)
                        .with_context(|| format!("{}: cannot create directory", out.display()))?;
                    json::write_file(&l, &out.join("lens-initial.json"))?;
                    TrainState::new(&l, cfg)
                }
            };
            train(
                state,
                &out,
                resume.is_some(),
                checkpoint_every.max(1),
                eval_trials,
            )?;
        }
        Command::Validate { lens, args } => validate(&lens, &args)?,
        Command::Demo {
            out, optics: true, ..
        } => demo(&out)?,
        Command::Demo { out, extra, .. } => {
            #[derive(Parser)]
            struct DemoArgs {
                #[command(flatten)]
                a: deep::DeepArgs,
            }
            let out_s = out.to_string_lossy().into_owned();
            let mut argv = vec!["demo", "lens1", "--out", out_s.as_str()];
            argv.extend(extra.iter().map(String::as_str));
            let d = DemoArgs::try_parse_from(argv)?;
            deep::deep(&d.a)?
        }
        Command::Deep(a) => deep::deep(&a)?,
        Command::Evaluate(a) => deep::evaluate_cmd(&a)?,
        Command::MergeEval(a) => deep::merge_eval(&a)?,
        Command::Render(a) => deep::render_cmd(&a)?,
        Command::Glass {
            name,
            glass_catalog,
            wavelengths,
        } => emit(&glass_text(&name, &glass_catalog, &wavelengths)?),
        Command::Convert {
            input,
            output,
            glass_catalog,
            glass_fallback,
            perturb,
        } => {
            let catalogs = load_catalogs(&glass_catalog, &glass_fallback)?;
            let in_path = Path::new(&input);
            let (mut lens, extras) = if zemax::is_zmx_path(in_path) && in_path.exists() {
                let z = zemax::read_file(in_path, &catalogs)?;
                for w in &z.warnings {
                    eprintln!("warning: {w}");
                }
                (z.lens, Some(z.extras))
            } else {
                (Lens::load_with_catalogs(&input, &catalogs)?.0, None)
            };
            if let Some(p) = perturb {
                let (perturbed, adj) = Perturbation::read(&p)?.apply(&lens)?;
                lens = perturbed
                    .with_adjustments(&adj)
                    .with_context(|| format!("{}: cannot write this perturbation", p.display()))?;
            }
            if zemax::is_zmx_path(&output) {
                zemax::write_file(&lens, extras.as_ref(), &output)?;
            } else {
                json::write_file(&lens, &output)?;
            }
            eprintln!("wrote {}", output.display());
        }
    }
    Ok(())
}

#[cfg(not(feature = "embree"))]
fn validate(_lens: &LensArgs, _args: &ValidateArgs) -> anyhow::Result<()> {
    bail!(
        "`validate --embree` needs tolray built with the `embree` feature; rebuild with \
         `cargo build --release --features embree` (or `cargo run --release --features embree \
         -- validate ...`). The feature needs libclang (apt-get install libclang1-14 \
         libclang-common-14-dev); its build finds Intel Embree 4 or fetches it from PyPI."
    )
}

#[cfg(feature = "embree")]
fn validate(lens: &LensArgs, args: &ValidateArgs) -> anyhow::Result<()> {
    use tolray::embree::{validate, CheckOptions, Device, Frame, ValidateOptions};
    let l = lens.load()?;
    let spec = match &args.tolerance_spec {
        Some(p) => ToleranceSpec::read(p)?,
        None => ToleranceSpec::default(),
    };
    spec.validate(&l).map_err(|e| {
        e.context(
            args.tolerance_spec
                .as_ref()
                .map_or("default spec".into(), |p| p.display().to_string()),
        )
    })?;
    if !(args.chord > 0.0 && args.chord.is_finite()) {
        usage!("--chord {}: give a positive bound in mm", args.chord);
    }
    if !(args.bound_scale > 0.0 && args.bound_scale.is_finite()) {
        usage!("--bound-scale {}: must be positive", args.bound_scale);
    }
    if !(args.spot_bound_um >= 0.0) {
        usage!(
            "--spot-bound-um {}: must be non-negative",
            args.spot_bound_um
        );
    }
    let (fields, wavelengths_nm, pupil) = args.rays.parse(&l, args.seed)?;
    let opts = ValidateOptions {
        check: CheckOptions {
            chord_mm: args.chord,
            frame: if args.frame == "global" {
                Frame::Global
            } else {
                Frame::Local
            },
            fields,
            wavelengths_nm,
            pupil,
            bound_scale: args.bound_scale,
            spot_bound_um: args.spot_bound_um,
        },
        trials: args.trials,
        seed: args.seed,
        spec,
    };
    let device = Device::shared()?;
    eprintln!(
        "Embree {} cross-check of {}: nominal + {} tolerance patterns (seed {}), chord bound {:e} mm, {} frame",
        device.version_string(),
        lens.lens,
        args.trials,
        args.seed,
        args.chord,
        args.frame
    );
    let report = with_progress(args.trials as u64 + 1, "cases", |tick| {
        validate(device, &l, &lens.lens, &opts, tick)
    })?;
    emit(&validate_text(&report));
    if let Some(p) = &args.json {
        write_text(p, &(serde_json::to_string_pretty(&report)? + "\n"))?;
        eprintln!("wrote {}", p.display());
    }
    if !report.pass {
        let first: Vec<String> = report
            .cases
            .iter()
            .flat_map(|c| {
                let case = c
                    .trial
                    .map_or("nominal".to_string(), |k| format!("trial {k}"));
                c.failures.iter().map(move |f| format!("{case}: {f}"))
            })
            .take(5)
            .collect();
        bail!(
            "validation failed: {} of {} cases exceed a bound; first:\n  {}",
            report.summary.failed_cases,
            report.summary.cases,
            first.join("\n  ")
        );
    }
    Ok(())
}

#[cfg(feature = "embree")]
fn validate_text(r: &tolray::embree::ValidationReport) -> String {
    use std::fmt::Write;
    let s = &r.summary;
    let c = &r.options.check;
    let mut t = String::new();
    let rays: usize = r.cases[0].fields.iter().map(|f| f.rays).sum();
    let _ = writeln!(
        t,
        "Embree {} cross-check of {}: {} cases (nominal + {} patterns of seed {}), chord bound {:e} mm, \
         {} frame, {} rays per case",
        r.embree_version,
        r.lens,
        s.cases,
        r.options.trials,
        r.options.seed,
        c.chord_mm,
        match c.frame {
            tolray::embree::Frame::Local => "local",
            tolray::embree::Frame::Global => "global",
        },
        rays
    );
    let _ = writeln!(
        t,
        "\nper surface, worst over all cases (hit = |P_embree - P_analytic|; hit/bound <= {} passes):",
        1
    );
    let _ = writeln!(
        t,
        "{:>4} {:>15} {:>9} {:>10} {:>10} {:>10} {:>10} {:>9} {:>9} {:>6}",
        "surf",
        "disk/aper. mm",
        "triangles",
        "bound mm",
        "mesh dev",
        "max hit",
        "rms hit",
        "hit/bound",
        "f32 err",
        "leaks"
    );
    for x in &s.surfaces {
        let _ = writeln!(
            t,
            "{:>4} {:>15} {:>9} {:>10.3e} {:>10.3e} {:>10.3e} {:>10.3e} {:>9.3} {:>9.1e} {:>6}",
            x.surface,
            format!("{:.2}/{:.2}", x.disk_mm, x.semi_aperture_mm),
            x.triangles,
            x.chord_bound_mm,
            x.mesh_deviation_mm,
            x.max_hit_distance_mm,
            x.rms_hit_distance_mm,
            x.max_bound_ratio,
            x.max_f32_error_mm,
            x.leaks + x.uncovered
        );
    }
    let _ = writeln!(
        t,
        "\nRMS spots, nominal lens (µm), and the worst difference over all cases:"
    );
    let _ = writeln!(
        t,
        "{:>8} {:>8} {:>11} {:>11} {:>10} {:>12} {:>12} {:>12}",
        "field", "nm", "analytic", "embree", "diff", "worst diff", "worst point", "mesh-normal"
    );
    let nf = r.cases[0].fields.len();
    for f in 0..nf {
        let n = &r.cases[0].fields[f];
        let worst = |g: &dyn Fn(&tolray::embree::FieldCheck) -> f64| {
            r.cases.iter().map(|c| g(&c.fields[f])).fold(0.0, f64::max)
        };
        let _ = writeln!(
            t,
            "{:>8} {:>8.2} {:>11.4} {:>11.4} {:>10.2e} {:>12.2e} {:>12.2e} {:>12.2e}",
            n.field.label(),
            n.wavelength_nm,
            n.rms_analytic_um,
            n.rms_embree_um,
            n.rms_diff_um,
            worst(&|x| x.rms_diff_um),
            worst(&|x| x.max_point_diff_um),
            worst(&|x| x.rms_diff_mesh_normal_um)
        );
    }
    let _ = writeln!(
        t,
        "(worst point: largest image-point distance between the traces; mesh-normal: RMS difference \
         when refracting with interpolated mesh normals. {} rays compared; {} reached the image in one \
         trace only, by crossing an aperture rim on different sides.)",
        s.rays_compared, s.status_mismatches
    );
    let tm = &s.timing;
    let [e, k, rf] = s.median_mrs_per_s;
    let _ = writeln!(
        t,
        "\nthroughput, one thread, the same rays (median over cases of {} ray-surfaces each; every \
         scene is traced right after its build):\n  Embree trace      {:>8.2} M ray-surfaces/s  (intersection + refraction)\n  analytic kernel   {:>8.2} M ray-surfaces/s  (f64)\n  scalar reference  {:>8.2} M ray-surfaces/s  (f64)\n  scene builds: {:.2} s for {:.1} M triangles ({:.1} M triangles/s)",
        tm.ray_surfaces / s.cases.max(1) as u64,
        e,
        k,
        rf,
        tm.build_s,
        tm.triangles as f64 * 1e-6,
        tm.triangles as f64 * 1e-6 / tm.build_s
    );
    let _ = writeln!(
        t,
        "\nresult: {} ({} of {} cases exceed a bound; spot bound {} µm, bound scale {})",
        if r.pass { "PASS" } else { "FAIL" },
        s.failed_cases,
        s.cases,
        c.spot_bound_um,
        c.bound_scale
    );
    t
}

fn save_checkpoint(state: &TrainState, out: &Path) -> anyhow::Result<()> {
    write_text(
        &out.join("checkpoint.json"),
        &(serde_json::to_string(state)? + "\n"),
    )?;
    write_text(&out.join("lens-latest.json"), &state.lens_json)?;
    Ok(())
}

/// Runs (or continues) training, with a progress bar, a JSON-lines log, checkpoints, Ctrl-C
/// handling and the final report.
fn train(
    mut state: TrainState,
    out: &Path,
    resumed: bool,
    every: usize,
    eval_trials: usize,
) -> anyhow::Result<()> {
    use std::io::Write;
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create directory", out.display()))?;
    let log_path = out.join("log.jsonl");
    // The log holds exactly one line per finished iteration: on resume, cut it to the checkpoint.
    let mut logs: Vec<IterLog> = if resumed {
        std::fs::read_to_string(&log_path)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .take(state.next_iter)
            .collect()
    } else {
        Vec::new()
    };
    let body: String = logs
        .iter()
        .map(|l| serde_json::to_string(l).unwrap_or_default() + "\n")
        .collect();
    write_text(&log_path, &body)?;
    let mut log = std::fs::OpenOptions::new()
        .append(true)
        .open(&log_path)
        .with_context(|| format!("{}: cannot open", log_path.display()))?;
    // Ctrl-C now asks for a stop at the end of the iteration (an exact checkpoint), instead of
    // main's default of removing partial files and exiting at once.
    GRACEFUL_STOP.store(true, Ordering::SeqCst);
    let stop = &STOP_REQUESTED;
    let total = state.total_iters();
    let bar = indicatif::ProgressBar::new(total as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} (ETA {eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_position(state.next_iter as u64);
    while state.next_iter < total {
        let l = step(&mut state)?;
        writeln!(log, "{}", serde_json::to_string(&l)?)
            .with_context(|| format!("{}: cannot write", log_path.display()))?;
        bar.set_message(format!(
            "{:?} loss {:.5} spot {:.2} µm{}",
            l.stage,
            l.loss,
            l.spot_um,
            l.psf_similarity
                .map_or(String::new(), |s| format!(" sim {s:.4}"))
        ));
        bar.inc(1);
        logs.push(l);
        let done = state.next_iter == total;
        if done || state.next_iter % every == 0 || stop.load(Ordering::SeqCst) {
            save_checkpoint(&state, out)?;
            write_text(
                &out.join(format!("lens-iter{}.json", state.next_iter)),
                &state.lens_json,
            )?;
        }
        if stop.load(Ordering::SeqCst) && !done {
            bar.abandon();
            eprintln!(
                "interrupted: checkpoint at iteration {} in {}; continue with --resume {}",
                state.next_iter,
                out.display(),
                out.display()
            );
            std::process::exit(130);
        }
    }
    bar.finish_and_clear();
    figures::save(
        &figures::training_figure(&logs, "Training"),
        &out.join("training.png"),
    )?;
    // Final report: initial, stage-1 and final designs; held-out patterns with another seed.
    let initial = json::read_file(&out.join("lens-initial.json")).or_else(|_| state.lens())?;
    let final_lens = state.lens()?;
    let stage1 = state
        .stage1_lens_json
        .as_deref()
        .map(json::from_str)
        .transpose()?;
    let cfg = &state.config;
    let eval_seed = cfg.seed.wrapping_add(1_000_003);
    let mut designs: Vec<(&str, &Lens)> = vec![("initial", &initial)];
    if let (Some(s1), true) = (&stage1, cfg.pretrain_iters > 0 && cfg.tolerance_iters > 0) {
        designs.push(("stage 1", s1));
    }
    designs.push(("final", &final_lens));
    let mut text = format!("Training report ({} iterations: {} pretrain + {} tolerance-aware, {} patterns per iteration, seed {})\n\n", total, cfg.pretrain_iters, cfg.tolerance_iters, cfg.samples, cfg.seed);
    let mut evals = Vec::new();
    text.push_str(&format!("Held-out evaluation: {eval_trials} tolerance patterns of seed {eval_seed} (training used seed {}); RMS spot in µm, mean over the fields, with the sensor where the design puts it and with each lens refocused to its best focus (the assembly's focus compensator)\n", cfg.seed));
    text.push_str(&format!(
        "{:>10} {:>28} {:>10} {:>10} {:>11} {:>10} {:>10} {:>11} {:>10}\n",
        "design",
        "nominal RMS per field",
        "MC mean",
        "MC std",
        "90 % below",
        "refoc mean",
        "refoc std",
        "refoc 90 %",
        "PSF sim"
    ));
    for (name, l) in &designs {
        let h = held_out(l, cfg, eval_trials, eval_seed)?;
        text.push_str(&format!(
            "{name:>10} {:>28} {:>10.3} {:>10.3} {:>11.3} {:>10.3} {:>10.3} {:>11.3} {:>10.4}\n",
            fmt_list(&h.nominal_rms_um),
            h.rms_mean_um,
            h.rms_std_um,
            h.rms_yield90_um,
            h.refocused_rms_mean_um,
            h.refocused_rms_std_um,
            h.refocused_rms_yield90_um,
            h.psf_similarity_mean
        ));
        evals.push(serde_json::json!({"design": name, "held_out": h, "lens": json::to_value(l)}));
    }
    text.push_str("\nPrescription (radius / gap in mm): initial -> final\n");
    for (i, (a, b)) in initial
        .surfaces
        .iter()
        .zip(&final_lens.surfaces)
        .enumerate()
    {
        let r = |c: f64| {
            if c == 0.0 {
                "inf".to_string()
            } else {
                format!("{:.4}", 1.0 / c)
            }
        };
        text.push_str(&format!(
            "  {i:>3}  R {:>12} -> {:>12}   gap {:>9.4} -> {:>9.4}\n",
            r(a.c),
            r(b.c),
            a.d_next_mm,
            b.d_next_mm
        ));
    }
    emit(&text);
    write_text(&out.join("report.txt"), &text)?;
    write_text(
        &out.join("report.json"),
        &(serde_json::to_string_pretty(&serde_json::json!({"config": cfg, "designs": evals}))?
            + "\n"),
    )?;
    json::write_file(&final_lens, &out.join("lens-final.json"))?;
    eprintln!(
        "wrote {}/report.txt, report.json, lens-final.json, training.png, log.jsonl",
        out.display()
    );
    Ok(())
}

fn parse_shard(s: &str) -> anyhow::Result<(usize, usize)> {
    let bad = || anyhow::anyhow!("--shard \"{s}\": expected K/N with 0 <= K < N");
    let (k, n) = s.split_once('/').ok_or_else(bad)?;
    let (k, n): (usize, usize) = (
        k.trim().parse().map_err(|_| bad())?,
        n.trim().parse().map_err(|_| bad())?,
    );
    if n == 0 || k >= n {
        return Err(bad());
    }
    Ok((k, n))
}

/// Runs `f` with a progress bar of `n` steps on stderr (hidden when stderr is not a terminal).
fn with_progress<T>(n: u64, what: &str, f: impl FnOnce(&(dyn Fn() + Sync)) -> T) -> T {
    let bar = indicatif::ProgressBar::new(n);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{{bar:40}} {{pos}}/{{len}} {what} ({{per_sec}}, ETA {{eta}})"
        ))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let out = f(&|| bar.inc(1));
    bar.finish_and_clear();
    out
}

fn fmt_list(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn stats_row(name: &str, s: &Stats) -> String {
    let y: Vec<String> = s
        .yield_below
        .iter()
        .map(|r| format!("{:.3}", r[1]))
        .collect();
    format!(
        "{name:>14} {:>10.3} {:>10.3} {:>10.3} {:>10.3}   {}\n",
        s.mean,
        s.std,
        s.min,
        s.max,
        y.join("  ")
    )
}

fn tolerance_text(r: &McReport) -> String {
    let o = &r.options;
    let mut s = format!(
        "Monte Carlo tolerance analysis of {}: {} trials (seed {}){}, pupil {:?}, {} nm{}\n",
        r.lens,
        o.trials,
        o.seed,
        r.shard.map_or(String::new(), |[k, n]| format!(
            ", shard {k}/{n}: trials {}..{}",
            k * o.trials / n,
            (k + 1) * o.trials / n
        )),
        o.pupil.pattern,
        fmt_list(&o.wavelengths_nm),
        if o.compensate_focus {
            ", compensator: best focus"
        } else {
            ""
        }
    );
    let fields: Vec<String> = o.fields.iter().map(|f| f.label()).collect();
    s.push_str(&format!(
        "nominal RMS spot per field ({}): {} µm\n",
        fields.join(", "),
        fmt_list(&r.nominal_rms_um)
    ));
    let Some(sm) = &r.summary else {
        s.push_str(&format!(
            "partial report: {} trials; merge the shards with `tolray merge` for statistics\n",
            r.trials.len()
        ));
        return s;
    };
    s.push_str(&format!("\nRMS spot (µm)    {:>10} {:>10} {:>10} {:>10}   yield: 90 % / 70 % / 50 % / 10 % of lenses have RMS below\n", "mean", "std", "min", "max"));
    for (f, st) in o.fields.iter().zip(&sm.per_field) {
        s.push_str(&stats_row(&format!("field {}", f.label()), st));
    }
    s.push_str(&stats_row("field mean", &sm.mean_over_fields));
    if let Some(fs) = &sm.focus_shift_mm {
        s.push_str(&format!(
            "refocus (mm): mean {:.4}, std {:.4}, min {:.4}, max {:.4} (nominal {:.4})\n",
            fs.mean,
            fs.std,
            fs.min,
            fs.max,
            r.nominal_focus_shift_mm.unwrap_or(0.0)
        ));
    }
    s
}

/// The main job on built-in defaults.
fn demo(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create directory", out.display()))?;
    for name in tolray::lens::builtin_names() {
        let l = Lens::load(name)?;
        let p = l.paraxial(l.primary_wavelength_nm)?;
        emit_line(&format!("==================== {name} ===================="));
        emit(&paraxial_text(&l, &p).to_string());
        let opts = SpotOptions {
            fields: [0.0, 0.5, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: l.rgb_wavelengths_nm.to_vec(),
            pupil: Pupil::grid(64),
            trace: TraceOptions::default(),
        };
        let spots = spot_diagram(&l, &l.compile(), &opts)?;
        emit_line("\nSpots (64x64 grid over the entrance pupil, apertures on, RGB)");
        emit(&spot_table(&spots).to_string());
        let spot_png = out.join(format!("{name}-spots.png"));
        figures::save(
            &figures::spot_figure(&spots, &format!("Spot diagram: {name}")),
            &spot_png,
        )?;
        let layout_png = out.join(format!("{name}-layout.png"));
        let fields = [0.0, 0.7, 1.0].map(Field::fraction);
        figures::save(
            &figures::layout_figure(&l, &l.compile(), &p, &fields, l.primary_wavelength_nm, 7)?,
            &layout_png,
        )?;
        write_text(
            &out.join(format!("{name}-spots.json")),
            &(serde_json::to_string_pretty(&spots)? + "\n"),
        )?;
        // Tolerances: the paper's Table A1, 200 Monte Carlo trials with a refocus compensator.
        let mc = McOptions {
            spec: ToleranceSpec::default(),
            trials: 200,
            seed: 7,
            fields: [0.0, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: vec![l.primary_wavelength_nm],
            pupil: Pupil::grid(32),
            compensate_focus: true,
            apertures: true,
        };
        emit_line("");
        let report = with_progress(mc.trials as u64, "trials", |tick| {
            monte_carlo(&l, name, &mc, None, tick)
        })?;
        emit(&tolerance_text(&report));
        let hist_png = out.join(format!("{name}-tolerance.png"));
        figures::save(&figures::tolerance_figure(&report), &hist_png)?;
        write_text(
            &out.join(format!("{name}-tolerance.json")),
            &(serde_json::to_string_pretty(&report)? + "\n"),
        )?;
        let (_, rows) = sensitivity(&l, &mc)?;
        emit_line("most sensitive operands (worst change of RMS spot, µm):");
        for r in rows.iter().take(5) {
            let axis = if r.operand.axes() == 1 {
                String::new()
            } else {
                format!(" {}", ["x", "y", "z"][r.axis])
            };
            let target = if r.operand.per_element() {
                "element"
            } else {
                "surface"
            };
            emit_line(&format!(
                "  {:?}{axis} of {target} {} at +-{} {}: {:.3}",
                r.operand,
                r.target,
                r.max,
                r.operand.unit(),
                r.worst_delta_um
            ));
        }
        emit_line(&format!(
            "wrote {}, {}, {}\n",
            spot_png.display(),
            layout_png.display(),
            hist_png.display()
        ));
    }
    Ok(())
}

/// Writes to stdout; a closed pipe (e.g. `| head`) ends the program quietly.
fn emit(s: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(s.as_bytes()).and_then(|_| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to stdout: {e}");
        std::process::exit(1);
    }
}

fn emit_line(s: &str) {
    emit(&format!("{s}\n"));
}

/// The exit code of an error: 2 for usage errors (a bad flag value, or a library argument error,
/// which every command raises only for values given on the command line), else 1.
fn exit_code(e: &anyhow::Error) -> u8 {
    let usage = e.chain().any(|c| {
        c.is::<Usage>()
            || c.downcast_ref::<tolray::Error>()
                .is_some_and(|t| t.kind == tolray::ErrorKind::Argument)
    });
    if usage {
        2
    } else {
        1
    }
}

/// Set by Ctrl-C when a command stops gracefully (`train`).
static STOP_REQUESTED: AtomicBool = AtomicBool::new(false);
/// Whether the running command stops gracefully on Ctrl-C.
static GRACEFUL_STOP: AtomicBool = AtomicBool::new(false);

/// Ctrl-C: a graceful command (`train`) is asked to stop; any other exits at once with code 130,
/// after deleting the temporary files of writes in progress (outputs are written through a
/// temporary file and a rename, so no half-written output exists, and now no hidden partial file
/// either).
fn install_interrupt_handler() {
    let _ = ctrlc::set_handler(|| {
        if GRACEFUL_STOP.load(Ordering::SeqCst) {
            STOP_REQUESTED.store(true, Ordering::SeqCst);
        } else {
            tolray::error::remove_partial_files();
            std::process::exit(130);
        }
    });
}

/// Checks the output paths of the command line before any work: a file's directory must exist
/// and the file must not be a directory; an output directory (`--out` of `train`, `deep`,
/// `demo`) must not be a file. Names the flag and the path.
fn check_outputs(m: &clap::ArgMatches) -> anyhow::Result<()> {
    let Some((name, sub)) = m.subcommand() else {
        return Ok(());
    };
    for id in ["png", "exr", "json", "html", "output", "out"] {
        let Ok(Some(p)) = sub.try_get_one::<PathBuf>(id) else {
            continue;
        };
        let flag = if id == "output" {
            "OUTPUT".to_string()
        } else {
            format!("--{id}")
        };
        if id == "out" && name != "trace" {
            if p.exists() && !p.is_dir() {
                bail!("{flag} {}: exists and is not a directory", p.display());
            }
            continue;
        }
        let dir = p
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !dir.is_dir() {
            bail!(
                "{flag} {}: the directory {} does not exist",
                p.display(),
                dir.display()
            );
        }
        if p.is_dir() {
            bail!("{flag} {}: is a directory, not a file", p.display());
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    use clap::{CommandFactory, FromArgMatches};
    let m = Cli::command().get_matches();
    let checked = check_outputs(&m).and_then(|()| Ok(Cli::from_arg_matches(&m)?));
    install_interrupt_handler();
    match checked.and_then(run) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(exit_code(&e))
        }
    }
}
