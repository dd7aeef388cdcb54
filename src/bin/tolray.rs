//! The `tolray` command-line tool. Exit codes: 0 success, 1 runtime error, 2 usage error.

use anyhow::{bail, Context};
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use tolray::analysis::{spot_diagram, SpotOptions, SpotResult};
use tolray::lens::material::{LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use tolray::lens::{json, Paraxial};
use tolray::trace::raw::{parse_csv, parse_json, to_csv, trace_raw};
use tolray::trace::{Field, Pupil, TraceOptions};
use tolray::{figures, Lens, Object};

#[derive(Parser)]
#[command(
    name = "tolray",
    version,
    about = "Tolerance-aware lens design: exact ray tracing, spots and tolerances for refractive lenses.\n\nLengths in mm, spot sizes in um, wavelengths in nm, angles in degrees. Surfaces are counted from 0.\nA LENS is a DeepLens JSON file or a built-in name: lens1, lens2, cooke-triplet."
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
    /// The main job on built-in defaults: info, spots and pictures for every built-in lens.
    Demo {
        /// Output directory for the pictures and JSON reports.
        #[arg(long, default_value = "out")]
        out: PathBuf,
    },
}

#[derive(Args)]
struct LensArgs {
    /// Lens JSON file or built-in name (lens1, lens2, cooke-triplet).
    lens: String,
    /// Object distance from the first vertex in mm, or "inf" (default: from the lens file).
    #[arg(long, value_name = "MM|inf")]
    object: Option<String>,
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

impl LensArgs {
    fn load(&self) -> anyhow::Result<Lens> {
        let mut lens = Lens::load(&self.lens)?;
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
                Ok(v) if v > 100.0 && v < 20_000.0 => out.push(v),
                _ => bail!("wavelength \"{s}\": give nanometres (e.g. 587.56) or d, F, C, rgb"),
            },
        }
    }
    Ok(out)
}

impl RayArgs {
    fn options(&self, lens: &Lens) -> anyhow::Result<SpotOptions> {
        let fields = self
            .fields
            .iter()
            .map(|f| Field::parse(f))
            .collect::<tolray::Result<Vec<_>>>()?;
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
        "  {:<46} {:>14.4} mm ({} x {} px, pitch {:.3} um)\n\nPrescription (surfaces from 0; radius and gaps in mm)\n",
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
        "RMS (um)",
        "RMS/chief",
        "geo (um)",
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
                emit_line(&format!("{}", serde_json::to_string_pretty(&v)?));
            } else {
                emit(&format!("{}", paraxial_text(&l, &p)));
            }
        }
        Command::Spot {
            lens,
            rays,
            json,
            png,
        } => {
            let l = lens.load()?;
            let opts = rays.options(&l)?;
            let results = spot_diagram(&l, &l.compile(), &opts)?;
            if json {
                emit_line(&format!("{}", serde_json::to_string_pretty(&results)?));
            } else {
                emit(&format!("{}", spot_table(&results)));
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
            let l = lens.load()?;
            let p = l.paraxial(l.primary_wavelength_nm)?;
            let fields = fields
                .iter()
                .map(|f| Field::parse(f))
                .collect::<tolray::Result<Vec<_>>>()?;
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
        Command::Demo { out } => demo(&out)?,
    }
    Ok(())
}

/// The main job on built-in defaults.
fn demo(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create directory", out.display()))?;
    for name in tolray::lens::builtin_names() {
        let l = Lens::load(name)?;
        let p = l.paraxial(l.primary_wavelength_nm)?;
        emit_line(&format!("==================== {name} ===================="));
        emit(&format!("{}", paraxial_text(&l, &p)));
        let opts = SpotOptions {
            fields: [0.0, 0.5, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: l.rgb_wavelengths_nm.to_vec(),
            pupil: Pupil::grid(64),
            trace: TraceOptions::default(),
        };
        let spots = spot_diagram(&l, &l.compile(), &opts)?;
        emit_line(&format!(
            "\nSpots (64x64 grid over the entrance pupil, apertures on, RGB)"
        ));
        emit(&format!("{}", spot_table(&spots)));
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
        emit_line(&format!(
            "wrote {}, {}\n",
            spot_png.display(),
            layout_png.display()
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
