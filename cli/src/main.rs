//! The `tolray` command-line tool. Exit codes: 0 success, 1 runtime error, 2 usage error.
//!
//! This file parses the command line and dispatches; each command lives in its own module with
//! its arguments and a `run` function. Shared argument groups are in [`args`], shared text in
//! [`report`], exit codes, Ctrl-C and the check of output paths in [`app`].
// `!(x >= 0.0)` refuses NaN too, on purpose (as in the library).
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use clap::{Parser, Subcommand};
use std::process::ExitCode;

mod aberrations;
mod app;
mod args;
mod bench;
mod convert;
mod deep;
mod demo;
mod glass;
mod info;
mod layout;
mod psf;
mod report;
mod spot;
mod tolerance;
mod trace;
mod train;
mod validate;
mod wave;

#[derive(Parser)]
#[command(
    name = "tolray",
    version,
    about = "Tolerance-aware deep optics: exact, differentiable ray tracing of real lenses; spots, wave optics, tolerances and yield; lenses designed together with their image decoders.\n\nLengths in mm, spot sizes in µm, wavelengths in nm, angles in degrees. Surfaces are counted from 0.\nA LENS is a DeepLens JSON file, a Zemax .zmx file or a built-in name: lens1, lens2, cooke-triplet."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Paraxial data and prescription of a lens.
    Info(info::InfoArgs),
    /// Spot diagrams and RMS spot radii per field and wavelength.
    Spot(spot::SpotArgs),
    /// Monte Carlo tolerance analysis: RMS spot statistics and yield over random fabricated lenses.
    Tolerance(tolerance::ToleranceArgs),
    /// Sensitivity: each tolerance operand alone at -max and +max, worst first.
    Sensitivity(tolerance::SensitivityArgs),
    /// PSF of one field: geometric (bilinear splat at the sensor pixel pitch, unit sum; the
    /// default), or diffraction (--method fft|huygens, relative to the unaberrated peak, with the
    /// Strehl ratio).
    Psf(psf::PsfCmdArgs),
    /// Wavefront error per field and wavelength: OPD against the reference sphere (waves), RMS
    /// and PV to chief and centroid, Maréchal Strehl, Zernike Standard (Noll) and Fringe fits.
    Wavefront(wave::WavefrontArgs),
    /// MTF per field and wavelength, tangential and sagittal: diffraction (FFT) or geometric,
    /// with the diffraction limit, optionally through focus.
    Mtf(wave::MtfArgs),
    /// Aberration curves: field curvature, distortion (f-tan θ, f-θ), lateral colour and relative
    /// illumination against field; ray and OPD fans per field and wavelength.
    Aberrations(aberrations::AberrationsArgs),
    /// PSF map: PSFs over a grid of fields covering the sensor.
    PsfMap(psf::PsfMapArgs),
    /// Two-stage optimization: stage 1 (pretrain) minimizes the RMS spot without tolerances;
    /// stage 2 (tolerance) samples tolerance patterns each iteration and minimizes the spot and
    /// PSF-similarity losses. With --decoder, the image stage: lens and decoder trained together
    /// on simulated captures, stage 1 without and stage 2 with tolerances, and evaluated.
    Train(train::TrainArgs),
    /// Merge shard reports of one Monte Carlo study into the report a single run gives.
    Merge(tolerance::MergeArgs),
    /// Raw ray trace: rays from a CSV/JSON file to the image plane.
    Trace(trace::TraceArgs),
    /// Meridional lens drawing with a ray fan per field.
    Layout(layout::LayoutArgs),
    /// Look a glass up in the built-in vendor catalogs (and --glass-catalog files): its vendor,
    /// dispersion formula and coefficients, valid range, catalog n_d / V_d and indices.
    Glass(glass::GlassArgs),
    /// Convert a lens between Zemax .zmx and DeepLens JSON (the formats follow the extensions).
    Convert(convert::ConvertArgs),
    /// Cross-check the analytic tracer against an independent engine: every surface, nominal and
    /// under Monte Carlo tolerance patterns, is tessellated within a chord bound and traced with
    /// Intel Embree 4; hits must lie within the bound of the analytic hits and RMS spots must
    /// agree. Exits with 1 when any deviation exceeds its bound. Needs a build with
    /// `--features embree`.
    Validate(validate::ValidateArgs),
    /// The main job: the deep-optics study on lens1 with the built-in defaults (`deep lens1`),
    /// or with --optics the tour of the optics half (paraxial data, spots, Monte Carlo).
    Demo(demo::DemoArgs),
    /// Deep optics: lens and decoder trained jointly, conventionally and tolerance-aware, and
    /// evaluated over random fabricated units (PSNR/SSIM, manufacturing yield).
    Deep(deep::DeepArgs),
    /// Evaluates saved designs (lens + decoder) over random fabricated units.
    Evaluate(deep::EvaluateArgs),
    /// Combines `evaluate --shard` reports into the single-run report.
    MergeEval(deep::MergeEvalArgs),
    /// Pools the evaluations of studies that differ only in their training seed: per-seed and pooled PSNR differences with two-level bootstrap intervals (seeds and units resampled).
    PoolEval(deep::PoolEvalArgs),
    /// Simulates a capture: an image blurred by the lens' spatially variant RGB PSF map, plus noise.
    Render(deep::RenderArgs),
    /// The kernel's and the commands' speed on this machine (ray-surfaces/s per core and on all
    /// cores in f32, f64 and dual numbers, the spot analysis, a PSF, a PSF map, a deep-optics
    /// iteration), with the instruction set in use.
    Bench(bench::BenchArgs),
}

fn run(cli: Cli) -> anyhow::Result<()> {
    // A forced instruction set this CPU cannot run is refused, not silently replaced.
    tolray::trace::simd::from_env()?;
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::Spot(a) => spot::run(a),
        Command::Tolerance(a) => tolerance::run(a),
        Command::Sensitivity(a) => tolerance::run_sensitivity(a),
        Command::Psf(a) => psf::run(a),
        Command::PsfMap(a) => psf::run_map(a),
        Command::Wavefront(a) => wave::run_wavefront(a),
        Command::Mtf(a) => wave::run_mtf(a),
        Command::Aberrations(a) => aberrations::run(a),
        Command::Train(a) => train::run(a),
        Command::Merge(a) => tolerance::run_merge(a),
        Command::Trace(a) => trace::run(a),
        Command::Layout(a) => layout::run(a),
        Command::Glass(a) => glass::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Validate(a) => validate::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Deep(a) => deep::deep(&a),
        Command::Evaluate(a) => deep::evaluate_cmd(&a),
        Command::MergeEval(a) => deep::merge_eval(&a),
        Command::PoolEval(a) => deep::pool_eval(&a),
        Command::Render(a) => deep::render_cmd(&a),
        Command::Bench(a) => bench::run(a),
    }
}

/// The command-line reference in Markdown, `docs/cli.md` (`tolray --markdown-help`, a hidden
/// flag; `cli/tests/cli/` fails when the file drifts from the parser).
fn markdown_help() -> String {
    use clap::CommandFactory;
    let opts = clap_markdown::MarkdownOptions::new()
        .title("Command-line reference".into())
        .show_footer(false);
    let intro =
        "Generated from the parser by `tolray --markdown-help` (`TOLRAY_BLESS=1 cargo test \
                 --release --test cli reference` rewrites it); the same text as `tolray COMMAND \
                 --help`. The guide to the commands is [usage.md](usage.md).\n\n";
    let md = clap_markdown::help_markdown_command_custom(&Cli::command(), &opts);
    match md.split_once("\n\n") {
        Some((title, rest)) => format!("{title}\n\n{intro}{rest}"),
        None => md,
    }
}

fn main() -> ExitCode {
    use clap::{CommandFactory, FromArgMatches};
    if std::env::args().nth(1).as_deref() == Some("--markdown-help") {
        print!("{}", markdown_help());
        return ExitCode::SUCCESS;
    }
    let m = app::negative_numbers(Cli::command()).get_matches();
    let checked = app::check_outputs(&m).and_then(|()| Ok(Cli::from_arg_matches(&m)?));
    app::install_interrupt_handler();
    match checked.and_then(run) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(app::exit_code(&e))
        }
    }
}
