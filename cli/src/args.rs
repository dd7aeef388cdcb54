//! Argument groups shared by several commands, and the parsing of their values.

use crate::usage;
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::analysis::SpotOptions;
use tolray::lens::material::{self, LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use tolray::lens::GlassCatalogs;
use tolray::psf::{PsfCentre, PsfOptions};
use tolray::tolerance::{Criterion, McOptions, Perturbation, ToleranceSpec};
use tolray::trace::{Field, Pupil, TraceOptions};
use tolray::{Lens, Object};

#[derive(Args)]
pub struct LensArgs {
    /// Lens JSON or Zemax .zmx file, or a built-in name (lens1, lens2, cooke-triplet).
    pub lens: String,
    /// Object distance in front of the first vertex in mm (0: on the vertex's plane), "inf",
    /// or "virtual:MM" (a beam converging on a point MM behind the first vertex) (default: from the lens file).
    #[arg(long, value_name = "MM|inf|virtual:MM")]
    pub object: Option<String>,
    /// A Zemax AGF glass catalog, searched before the built-in glasses (repeatable).
    #[arg(long = "glass-catalog", value_name = "FILE.agf")]
    pub glass_catalog: Vec<PathBuf>,
    /// When a .zmx GLAS names a glass in no catalog: "refuse" (default: an error naming the
    /// line) or "file-values" (use the n_d and V_d on the GLAS line as a model glass;
    /// OpticStudio's 1.5 / 40 placeholder is still refused).
    #[arg(long = "glass-fallback", value_name = "refuse|file-values", default_value = "refuse", value_parser = ["refuse", "file-values"])]
    pub glass_fallback: String,
    /// Clip rays at every surface's semi-diameter, as DeepLens does (a .zmx DIAM alone clips
    /// nothing, as in OpticStudio; hard apertures such as CLAP and the stop always clip).
    #[arg(long)]
    pub clip_at_semi_diameter: bool,
    /// Trace the file's fields over the whole pupil, without their vignetting factors
    /// (OpticStudio's VDX, VDY, VCX, VCY, which are applied by default).
    #[arg(long)]
    pub ignore_vignetting: bool,
}

impl LensArgs {
    pub fn load(&self) -> anyhow::Result<Lens> {
        Ok(self.load_with_fields()?.0)
    }

    /// The lens and the field points its file defines (a .zmx file's, or JSON `"fields"`):
    /// the default fields of the commands that trace fields when `--fields` is not given.
    pub fn load_with_fields(&self) -> anyhow::Result<(Lens, Option<Vec<Field>>)> {
        let catalogs = load_catalogs(&self.glass_catalog, &self.glass_fallback)?;
        let tolray::lens::Loaded { mut lens, warnings } = Lens::load_file(&self.lens, &catalogs)?;
        for w in warnings {
            eprintln!("warning: {w}");
        }
        if let Some(o) = &self.object {
            lens.object = Object::parse(o)?;
        }
        if self.clip_at_semi_diameter {
            lens.clip_at_semi_diameters();
        }
        if self.ignore_vignetting {
            for p in &mut lens.fields {
                p.vignetting = tolray::trace::Vignetting::default();
            }
        }
        // A field given as an object height needs the file's finite object.
        let file_fields = (!lens.fields.is_empty()
            && (self.object.is_none() || lens.object != Object::Infinite))
            .then(|| lens.fields.iter().map(|p| p.field).collect());
        Ok((lens, file_fields))
    }
}

/// The fields of `--fields`, or when it is not given, the lens file's fields, else `default`.
pub fn fields_or(
    given: &Option<Vec<String>>,
    file: Option<Vec<Field>>,
    default: &str,
) -> tolray::Result<Vec<Field>> {
    match (given, file) {
        (Some(g), _) => parse_fields(g),
        (None, Some(f)) => Ok(f),
        (None, None) => parse_fields(&default.split(',').map(String::from).collect::<Vec<_>>()),
    }
}

/// Accepts an output lens path ending in .zmx or .json.
pub fn lens_output_path(s: &str) -> Result<PathBuf, String> {
    let p = PathBuf::from(s);
    match p.extension().map(|e| e.to_ascii_lowercase()) {
        Some(e) if e == "zmx" || e == "json" => Ok(p),
        _ => Err(format!(
            "\"{s}\": give an output file ending in .zmx or .json"
        )),
    }
}

/// Reads the user's AGF catalogs; their warnings go to stderr.
pub fn load_catalogs(paths: &[PathBuf], fallback: &str) -> anyhow::Result<GlassCatalogs> {
    let (mut catalogs, warnings) = GlassCatalogs::from_files(paths)?;
    catalogs.file_values_fallback = fallback == "file-values";
    for w in warnings {
        eprintln!("warning: {w}");
    }
    Ok(catalogs)
}

#[derive(Args)]
pub struct RayArgs {
    /// Fields: fraction of the full field (0.7), angle (5deg: the object 5° above the axis,
    /// OpticStudio's -5°), object height (2.5mm), paraxial image height (14mm@image) or real
    /// image height (14mm@real-image: the chief ray lands there); x:y pairs allowed [default:
    /// the lens file's fields, else 0,0.5,0.7,1].
    #[arg(long, value_delimiter = ',')]
    pub fields: Option<Vec<String>>,
    /// Wavelengths in nm, or primary (the lens' primary wavelength: a .zmx file's PWAV, d for
    /// the built-in lenses), d, F, C, rgb (the lens' RGB wavelengths).
    #[arg(long, value_delimiter = ',', default_value = "primary")]
    pub wavelengths: Vec<String>,
    /// Pupil sampling over the paraxial entrance pupil: grid:N, hex:N or random:N.
    #[arg(long, default_value = "grid:64")]
    pub pupil: String,
    /// Seed for random pupil sampling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Aim rays at the real stop instead of the paraxial entrance pupil (default: as the lens
    /// says; a .zmx file's RAIM).
    #[arg(long, conflicts_with = "no_aim")]
    pub aim: bool,
    /// Aim rays at the paraxial entrance pupil even where the lens asks for ray aiming.
    #[arg(long)]
    pub no_aim: bool,
    /// Ignore clear apertures and the stop.
    #[arg(long)]
    pub no_apertures: bool,
}

impl RayArgs {
    /// The analysis options; `file_fields` (a .zmx file's) are the fields when `--fields` is not
    /// given.
    pub fn options(
        &self,
        lens: &Lens,
        file_fields: Option<Vec<Field>>,
    ) -> anyhow::Result<SpotOptions> {
        let fields = fields_or(&self.fields, file_fields, "0,0.5,0.7,1")?;
        let mut pupil = Pupil::parse(&self.pupil, self.seed)?;
        pupil.aim = self.aim || (lens.ray_aiming && !self.no_aim);
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

#[derive(Args)]
pub struct PsfArgs {
    /// Kernel size, pixels (odd; diffraction PSFs: the central --ks x --ks pixels of the FFT,
    /// the Huygens grid side).
    #[arg(long, default_value_t = 51)]
    pub ks: usize,
    /// Rays per PSF (uniform random over the entrance pupil).
    #[arg(long, default_value_t = 8192)]
    pub spp: usize,
    /// Pixel pitch in µm (default: the sensor's).
    #[arg(long, value_name = "UM")]
    pub pitch_um: Option<f64>,
    /// Centre the PSF on the chief ray or on the centroid.
    #[arg(long, default_value = "chief", value_parser = ["chief", "centroid"])]
    pub centre: String,
    /// Seed of the pupil samples.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl PsfArgs {
    pub fn options(&self, lens: &Lens) -> anyhow::Result<PsfOptions> {
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

/// The compiled lens, perturbed by the tolerance pattern in the file `perturb` if given.
pub fn perturbed_system(
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
pub struct RaySampleArgs {
    /// Fields (fractions, 5deg angles, 2.5mm object heights, 14mm@image or 14mm@real-image image
    /// heights) [default: the lens file's fields, else 0,0.7,1].
    #[arg(long, value_delimiter = ',')]
    pub fields: Option<Vec<String>>,
    /// Wavelengths in nm, or primary (the lens' primary wavelength), d, F, C, rgb.
    #[arg(long, value_delimiter = ',', default_value = "primary")]
    pub wavelengths: Vec<String>,
    /// Pupil sampling: grid:N, hex:N or random:N (random points seeded by --seed).
    #[arg(long, default_value = "grid:32")]
    pub pupil: String,
}

impl RaySampleArgs {
    /// The fields (`file_fields`, a .zmx file's, when `--fields` is not given), wavelengths (nm)
    /// and pupil.
    pub fn parse(
        &self,
        lens: &Lens,
        seed: u64,
        file_fields: Option<Vec<Field>>,
    ) -> anyhow::Result<(Vec<Field>, Vec<f64>, Pupil)> {
        Ok((
            fields_or(&self.fields, file_fields, "0,0.7,1")?,
            parse_wavelengths(&self.wavelengths, lens)?,
            Pupil::parse(&self.pupil, seed)?,
        ))
    }
}

#[derive(Args)]
pub struct TolArgs {
    /// Tolerance spec (JSON); default: the paper's Table A1 (decenter 0.04 mm, tilt 0.05 deg,
    /// axial shift 0.04 mm per element, curvature 0.3 % per surface; N(0, (max/3)^2) clamped).
    #[arg(long, value_name = "SPEC.json")]
    pub spec: Option<PathBuf>,
    #[command(flatten)]
    pub rays: RaySampleArgs,
    /// Compensator: "focus" refocuses the sensor per trial to the focus that optimises the
    /// criterion (the best RMS focus for rms-spot).
    #[arg(long, value_parser = ["focus"])]
    pub compensate: Option<String>,
    /// What each trial is judged by: rms-spot (µm, the paper's), rms-wavefront (waves, to
    /// centroid), strehl, or mtf@FREQ[:t|s|mean] (diffraction MTF at FREQ cycles/mm,
    /// tangential, sagittal or their mean). Wave criteria are averaged over the wavelengths.
    #[arg(long, default_value = "rms-spot", value_name = "CRITERION")]
    pub criterion: String,
    /// Ignore clear apertures and the stop.
    #[arg(long)]
    pub no_apertures: bool,
}

impl TolArgs {
    pub fn options(
        &self,
        lens: &Lens,
        trials: usize,
        seed: u64,
        file_fields: Option<Vec<Field>>,
    ) -> anyhow::Result<McOptions> {
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
        let (fields, wavelengths_nm, pupil) = self.rays.parse(lens, seed, file_fields)?;
        Ok(McOptions {
            spec,
            trials,
            seed,
            fields,
            wavelengths_nm,
            pupil,
            compensate_focus: self.compensate.is_some(),
            apertures: !self.no_apertures,
            criterion: Criterion::parse(&self.criterion).context("--criterion")?,
        })
    }
}

/// Parses fields: fractions of the full field, `5deg` angles, `2.5mm` object heights,
/// `14mm@image` or `14mm@real-image` image heights ([`Field::parse`]).
pub fn parse_fields(list: &[String]) -> tolray::Result<Vec<Field>> {
    list.iter().map(|f| Field::parse(f)).collect()
}

/// Parses wavelengths: nanometres, or primary (the lens' primary wavelength), d, F, C, rgb (the
/// lens' RGB wavelengths).
pub fn parse_wavelengths(list: &[String], lens: &Lens) -> anyhow::Result<Vec<f64>> {
    let mut out = Vec::new();
    for w in list {
        match w.trim() {
            "primary" => out.push(lens.primary_wavelength_nm),
            "d" => out.push(LAMBDA_D_NM),
            "F" => out.push(LAMBDA_F_NM),
            "C" => out.push(LAMBDA_C_NM),
            "rgb" => out.extend(lens.rgb_wavelengths_nm),
            s => match s.parse::<f64>() {
                Ok(v) => {
                    material::check_wavelength_nm(v)
                        .with_context(|| format!("wavelength \"{s}\""))?;
                    if v > material::DEFINED_MEDIA_BEYOND_NM {
                        lens.check_indices(v)
                            .with_context(|| format!("wavelength \"{s}\" nm"))?;
                    }
                    out.push(v);
                }
                _ => usage!(
                    "wavelength \"{s}\": give nanometres (e.g. 587.56) or primary, d, F, C, rgb"
                ),
            },
        }
    }
    Ok(out)
}

/// Parses `--shard K/N` (0 <= K < N).
pub fn parse_shard(s: &str) -> anyhow::Result<(usize, usize)> {
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
