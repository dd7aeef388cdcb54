//! The wave-optics commands: `tolray wavefront` and `tolray mtf`.

use crate::args::{fields_or, parse_wavelengths, perturbed_system, LensArgs};
use crate::report::emit_line;
use crate::usage;
use clap::Args;
use std::path::PathBuf;
use tolray::figures;
use tolray::trace::{Field, TraceOptions};
use tolray::wave::psf::FftOptions;
use tolray::wave::{self, PupilCoords, Reference, Sampling, WaveOptions};
use tolray::Lens;

/// Fields, wavelengths and ray options shared by the wave commands.
#[derive(Args)]
pub struct WaveRayArgs {
    /// Fields: fraction of the full field (0.7), angle (5deg), object height (2.5mm), image
    /// height (14mm@image, 14mm@real-image); x:y pairs allowed [default: the lens file's
    /// fields, else 0,0.7,1].
    #[arg(long, value_delimiter = ',')]
    pub fields: Option<Vec<String>>,
    /// Wavelengths in nm, or primary, d, F, C, rgb (one row each).
    #[arg(long, value_delimiter = ',', default_value = "primary")]
    pub wavelengths: Vec<String>,
    /// Aim rays at the real stop (default: as the lens says; a .zmx file's RAIM).
    #[arg(long, conflicts_with = "no_aim")]
    pub aim: bool,
    /// Aim rays at the paraxial entrance pupil even where the lens asks for ray aiming.
    #[arg(long)]
    pub no_aim: bool,
    /// Ignore clear apertures and the stop.
    #[arg(long)]
    pub no_apertures: bool,
    /// Trace the lens perturbed by this tolerance pattern.
    #[arg(long, value_name = "PATTERN.json")]
    pub perturb: Option<PathBuf>,
}

impl WaveRayArgs {
    /// The fields (with the text each was given as) and wavelengths.
    pub(crate) fn fields(&self, file: Option<Vec<Field>>) -> anyhow::Result<Vec<(String, Field)>> {
        let f = fields_or(&self.fields, file, "0,0.7,1")?;
        Ok(match &self.fields {
            Some(given) => given.iter().cloned().zip(f).collect(),
            None => f.into_iter().map(|f| (f.label(), f)).collect(),
        })
    }

    pub(crate) fn options(&self, lens: &Lens, sampling: Sampling) -> WaveOptions {
        WaveOptions {
            sampling,
            aim: self.aim || (lens.ray_aiming && !self.no_aim),
            trace: TraceOptions {
                apertures: !self.no_apertures,
            },
            ..WaveOptions::default()
        }
    }
}

/// Arguments of `tolray wavefront`.
#[derive(Args)]
pub struct WavefrontArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    #[command(flatten)]
    pub rays: WaveRayArgs,
    /// Zernike Standard (Noll) terms to fit (1 to 231); the Fringe fit takes at most 37.
    #[arg(long, default_value_t = 37)]
    pub zernike_terms: usize,
    /// Pupil coordinates of the Zernike fits: entrance (the launch points, optiland's) or exit
    /// (the points on the reference sphere, OpticStudio's).
    #[arg(long, default_value = "entrance", value_parser = ["entrance", "exit"])]
    pub zernike_pupil: String,
    /// Centre of the reference sphere: the chief ray's image point or the spot's centroid.
    #[arg(long, default_value = "chief", value_parser = ["chief", "centroid"])]
    pub reference: String,
    /// Radial Gauss nodes of the pupil quadrature.
    #[arg(long, default_value_t = 16)]
    pub rings: usize,
    /// Angular nodes of the pupil quadrature.
    #[arg(long, default_value_t = 48)]
    pub spokes: usize,
    /// Print JSON (one object per field and wavelength) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write the OPD map of the first field and wavelength (PNG, or SVG for .svg), 128x128
    /// pupil grid.
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
    /// Write a bar chart of the Zernike Standard coefficients of every row (PNG or SVG).
    #[arg(long, value_name = "FILE.png")]
    pub zernike_png: Option<PathBuf>,
}

/// Runs `tolray wavefront`.
pub fn run_wavefront(a: WavefrontArgs) -> anyhow::Result<()> {
    let (l, file_fields) = a.lens.load_with_fields()?;
    let fields = a.rays.fields(file_fields)?;
    let wls = parse_wavelengths(&a.rays.wavelengths, &l)?;
    let sys = perturbed_system(&l, a.rays.perturb.as_deref())?;
    wave::zernike::check_terms(wave::zernike::Ordering::Standard, a.zernike_terms)?;
    let sampling = Sampling::Quadrature {
        rings: a.rings,
        spokes: a.spokes,
    };
    if let Err(e) = sampling.check() {
        usage!("--rings {} --spokes {}: {}", a.rings, a.spokes, e.message());
    }
    let mut opts = a.rays.options(&l, sampling);
    opts.reference = if a.reference == "centroid" {
        Reference::Centroid
    } else {
        Reference::Chief
    };
    let coords = if a.zernike_pupil == "exit" {
        PupilCoords::Exit
    } else {
        PupilCoords::Entrance
    };
    let mut rows = Vec::new();
    let mut bars = Vec::new();
    for (label, field) in &fields {
        for &wl in &wls {
            let w = wave::wavefront(&l, &sys, *field, wl, &opts)?;
            let s = w.stats_in(a.zernike_terms, coords)?;
            bars.push((
                format!("{label}, {wl:.1} nm"),
                s.zernike_standard.coefficients.clone(),
            ));
            rows.push(serde_json::json!({
                "field": label,
                "wavelength_nm": wl,
                "rms_to_chief_waves": s.rms_to_chief_waves,
                "rms_to_centroid_waves": s.rms_to_centroid_waves,
                "pv_to_chief_waves": s.pv_to_chief_waves,
                "pv_to_centroid_waves": s.pv_to_centroid_waves,
                "strehl_marechal": s.strehl_marechal,
                "zernike_standard_waves": s.zernike_standard.coefficients,
                "zernike_standard_residual_waves": s.zernike_standard.residual_rms,
                "zernike_fringe_waves": s.zernike_fringe.coefficients,
                "zernike_fringe_residual_waves": s.zernike_fringe.residual_rms,
                "zernike_pupil": a.zernike_pupil,
                "reference": a.reference,
                "reference_sphere_radius_mm": w.radius_mm,
                "reference_centre_mm": w.centre_image_mm,
                "rays": w.opd_waves.len(),
                "rays_launched": w.n_launched,
            }));
        }
    }
    if a.json {
        emit_line(&serde_json::to_string_pretty(&rows)?);
    } else {
        emit_line(&format!(
            "{:>16} {:>9} {:>10} {:>10} {:>9} {:>9} {:>8} {:>9} {:>9} {:>9}",
            "field",
            "λ nm",
            "RMS chief",
            "RMS cent.",
            "PV chief",
            "Strehl≈",
            "rays",
            "Z4 (std)",
            "Z11",
            "resid."
        ));
        for r in &rows {
            let z = r["zernike_standard_waves"]
                .as_array()
                .cloned()
                .unwrap_or_default();
            let zj = |j: usize| z.get(j - 1).and_then(|v| v.as_f64()).unwrap_or(f64::NAN);
            emit_line(&format!(
                "{:>16} {:>9.2} {:>10.5} {:>10.5} {:>9.4} {:>9.4} {:>8} {:>9.5} {:>9.5} {:>9.2e}",
                r["field"].as_str().unwrap_or(""),
                r["wavelength_nm"].as_f64().unwrap_or(f64::NAN),
                r["rms_to_chief_waves"].as_f64().unwrap_or(f64::NAN),
                r["rms_to_centroid_waves"].as_f64().unwrap_or(f64::NAN),
                r["pv_to_chief_waves"].as_f64().unwrap_or(f64::NAN),
                r["strehl_marechal"].as_f64().unwrap_or(f64::NAN),
                r["rays"],
                zj(4),
                zj(11),
                r["zernike_standard_residual_waves"]
                    .as_f64()
                    .unwrap_or(f64::NAN),
            ));
        }
        emit_line("OPD in waves against the reference sphere; Zernike Standard (Noll) coefficients in waves.");
    }
    if let Some(p) = &a.png {
        let (label, field) = &fields[0];
        let mut o = opts;
        o.sampling = Sampling::Grid(128);
        let w = wave::wavefront(&l, &sys, *field, wls[0], &o)?;
        figures::save(
            &figures::opd_map_figure(
                &w,
                128,
                &format!("OPD {} field {label}, {:.1} nm", a.lens.lens, wls[0]),
            ),
            p,
        )?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(p) = &a.zernike_png {
        figures::save(
            &figures::zernike_figure(&bars, &format!("Zernike Standard: {}", a.lens.lens)),
            p,
        )?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

/// Arguments of `tolray mtf`.
#[derive(Args)]
pub struct MtfArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    #[command(flatten)]
    pub rays: WaveRayArgs,
    /// Spatial frequencies, cycles (line pairs) per mm [default: 10,20,40 and the plot from 0
    /// to the cutoff].
    #[arg(long = "freq-lpmm", value_delimiter = ',', default_value = "10,20,40")]
    pub freq_lpmm: Vec<f64>,
    /// fft: diffraction MTF (the pupil's autocorrelation, the FFT of the FFT PSF); direct: the
    /// same autocorrelation summed over exactly traced, sheared pupils (no FFT grid, no
    /// aliasing; a trace per frequency); geometric: the rays' spot transformed and multiplied by
    /// the diffraction limit.
    #[arg(long, default_value = "fft", value_parser = ["fft", "direct", "geometric"])]
    pub method: String,
    /// Add a polychromatic row per field: the wavelengths' OTFs (direct method, equal weights)
    /// summed about the primary wavelength's chief ray, so lateral colour counts.
    #[arg(long)]
    pub polychromatic: bool,
    /// Pupil samples across the diameter (FFT).
    #[arg(long, default_value_t = 64)]
    pub pupil_samples: usize,
    /// FFT grid side (at least twice the pupil samples).
    #[arg(long, default_value_t = 256)]
    pub grid: usize,
    /// Through focus: the sensor moved by -MM .. +MM in STEPS steps (an odd count includes 0).
    #[arg(long, value_name = "MM,STEPS")]
    pub through_focus: Option<String>,
    /// Print JSON (one object per field, wavelength and focus) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write MTF curves from 0 to the cutoff, tangential solid and sagittal dashed, the
    /// diffraction limit in grey (PNG, or SVG for .svg); through focus, MTF against focus at the
    /// first frequency.
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
}

/// Runs `f` with a wavefront traced on a pupil grid of `samples` (and an FFT grid in the same
/// ratio to it), doubling both while the wavefront is too steep for the grid (an aliased FFT),
/// up to 1024 samples; says so on stderr. Returns the result and the samples used.
pub fn with_fine_enough_pupil<T>(
    samples: usize,
    grid: usize,
    what: &str,
    f: &mut dyn FnMut(&FftOptions) -> tolray::Result<T>,
) -> anyhow::Result<(T, usize)> {
    let mut fft = FftOptions {
        pupil_samples: samples,
        grid,
    };
    loop {
        match f(&fft) {
            Err(e)
                if e.message().contains("undersampled")
                    && fft.pupil_samples < 1024
                    && fft.grid * 2 <= tolray::wave::psf::MAX_GRID =>
            {
                let next = FftOptions {
                    pupil_samples: fft.pupil_samples * 2,
                    grid: fft.grid * 2,
                };
                eprintln!(
                    "note: {what}: {} pupil samples alias ({}); trying {} in a {} grid",
                    fft.pupil_samples,
                    e.message(),
                    next.pupil_samples,
                    next.grid
                );
                fft = next;
            }
            Err(e) => return Err(e.into()),
            Ok(v) => return Ok((v, fft.pupil_samples)),
        }
    }
}

/// The lens with its sensor moved by `dz_mm` along the axis.
fn refocused(l: &Lens, dz_mm: f64) -> Lens {
    let mut m = l.clone();
    if let Some(s) = m.surfaces.last_mut() {
        let t = l.travel_directions();
        s.d_next_mm += dz_mm * t[t.len() - 1];
    }
    m
}

/// Runs `tolray mtf`.
pub fn run_mtf(a: MtfArgs) -> anyhow::Result<()> {
    let (l, file_fields) = a.lens.load_with_fields()?;
    let fields = a.rays.fields(file_fields)?;
    let wls = parse_wavelengths(&a.rays.wavelengths, &l)?;
    let fft = FftOptions {
        pupil_samples: a.pupil_samples,
        grid: a.grid,
    };
    if let Err(e) = fft.check() {
        usage!(
            "--pupil-samples {} --grid {}: {}",
            a.pupil_samples,
            a.grid,
            e.message()
        );
    }
    let focus: Vec<f64> = match &a.through_focus {
        None => vec![0.0],
        Some(s) => {
            let parts: Vec<&str> = s.split(',').collect();
            let (Some(mm), Some(steps), 2) = (
                parts.first().and_then(|v| v.trim().parse::<f64>().ok()),
                parts.get(1).and_then(|v| v.trim().parse::<usize>().ok()),
                parts.len(),
            ) else {
                usage!("--through-focus {s}: give MM,STEPS (e.g. 0.05,11)");
            };
            if !(mm > 0.0 && mm.is_finite() && (2..=201).contains(&steps)) {
                usage!("--through-focus {s}: give a positive range in mm and 2 to 201 steps");
            }
            (0..steps)
                .map(|k| -mm + 2.0 * mm * k as f64 / (steps - 1) as f64)
                .collect()
        }
    };
    let grid_opts = a.rays.options(&l, Sampling::Grid(a.pupil_samples));
    let quad_opts = a.rays.options(&l, Sampling::default());
    let mut rows = Vec::new();
    let mut curves = Vec::new();
    for (label, field) in &fields {
        for &wl in &wls {
            for &dz in &focus {
                let lf = if dz == 0.0 {
                    l.clone()
                } else {
                    refocused(&l, dz)
                };
                let sys = perturbed_system(&lf, a.rays.perturb.as_deref())?;
                let what = format!(
                    "field {label}, {} nm, focus {} mm",
                    (wl * 1e4).round() / 1e4,
                    (dz * 1e6).round() / 1e6
                );
                let quad = if a.method == "geometric" {
                    Some(wave::wavefront(&lf, &sys, *field, wl, &quad_opts)?)
                } else {
                    None
                };
                let direct = a.method == "direct";
                let plot = a.png.is_some() && focus.len() == 1;
                let ((m, curve), used) =
                    with_fine_enough_pupil(a.pupil_samples, a.grid, &what, &mut |fft| {
                        let g = WaveOptions {
                            sampling: Sampling::Grid(fft.pupil_samples),
                            ..grid_opts
                        };
                        let limit = wave::wavefront(&lf, &sys, *field, wl, &g)?;
                        let at = |freqs: &[f64]| match &quad {
                            None if direct => {
                                wave::mtf::direct_mtf(&lf, &sys, *field, wl, &g, freqs)
                            }
                            None => wave::mtf::fft_mtf(&limit, fft, freqs),
                            Some(w) => wave::mtf::geometric_mtf(w, &limit, fft, freqs),
                        };
                        let m = at(&a.freq_lpmm)?;
                        let curve = if plot {
                            let c = m.cutoff_lpmm[0].min(m.cutoff_lpmm[1]);
                            let f: Vec<f64> =
                                (0..=100).map(|k| c * 0.995 * k as f64 / 100.0).collect();
                            Some(at(&f)?)
                        } else {
                            None
                        };
                        Ok((m, curve))
                    })?;
                if let Some(c) = curve {
                    curves.push((format!("{label}, {wl:.1} nm"), c));
                }
                let mut row = serde_json::json!({
                    "field": label,
                    "wavelength_nm": wl,
                    "method": a.method,
                    "freq_lpmm": m.freq_lpmm,
                    "tangential": m.tangential,
                    "sagittal": m.sagittal,
                    "diffraction_limit": m.diffraction_limit,
                    "diffraction_limit_sagittal": m.diffraction_limit_sagittal,
                    "cutoff_lpmm": m.cutoff_lpmm,
                    "pupil_samples": used,
                });
                if a.through_focus.is_some() {
                    row["focus_shift_mm"] = serde_json::json!(dz);
                }
                rows.push(row);
            }
        }
        if a.polychromatic {
            let weighted: Vec<(f64, f64)> = wls.iter().map(|&w| (w, 1.0)).collect();
            for &dz in &focus {
                let lf = if dz == 0.0 {
                    l.clone()
                } else {
                    refocused(&l, dz)
                };
                let sys = perturbed_system(&lf, a.rays.perturb.as_deref())?;
                let poly = |freqs: &[f64]| {
                    wave::mtf::polychromatic_mtf(&lf, &sys, *field, &weighted, &grid_opts, freqs)
                };
                let m = poly(&a.freq_lpmm)?;
                if a.png.is_some() && focus.len() == 1 {
                    let c = m.cutoff_lpmm[0].min(m.cutoff_lpmm[1]);
                    let f: Vec<f64> = (0..=100).map(|k| c * 0.995 * k as f64 / 100.0).collect();
                    curves.push((format!("{label}, polychromatic"), poly(&f)?));
                }
                let mut row = serde_json::json!({
                    "field": label,
                    "wavelength_nm": null,
                    "polychromatic": true,
                    "wavelengths_nm": wls,
                    "method": "direct",
                    "freq_lpmm": m.freq_lpmm,
                    "tangential": m.tangential,
                    "sagittal": m.sagittal,
                    "diffraction_limit": m.diffraction_limit,
                    "diffraction_limit_sagittal": m.diffraction_limit_sagittal,
                    "cutoff_lpmm": m.cutoff_lpmm,
                    "pupil_samples": a.pupil_samples,
                });
                if a.through_focus.is_some() {
                    row["focus_shift_mm"] = serde_json::json!(dz);
                }
                rows.push(row);
            }
        }
    }
    if a.json {
        emit_line(&serde_json::to_string_pretty(&rows)?);
    } else {
        let tf = a.through_focus.is_some();
        let head = format!(
            "{:>16} {:>9}{} {:>10} {:>8} {:>8} {:>8}",
            "field",
            "λ nm",
            if tf { "  focus mm" } else { "" },
            "ν c/mm",
            "tang.",
            "sag.",
            "limit"
        );
        emit_line(&head);
        for r in &rows {
            let v = |k: &str| -> Vec<f64> {
                r[k].as_array()
                    .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
                    .unwrap_or_default()
            };
            let (f, t, s, d) = (
                v("freq_lpmm"),
                v("tangential"),
                v("sagittal"),
                v("diffraction_limit"),
            );
            for k in 0..f.len() {
                emit_line(&format!(
                    "{:>16} {:>9}{} {:>10.2} {:>8.4} {:>8.4} {:>8.4}",
                    r["field"].as_str().unwrap_or(""),
                    r["wavelength_nm"]
                        .as_f64()
                        .map_or("poly".to_string(), |w| format!("{w:.2}")),
                    if tf {
                        format!("{:>10.4}", r["focus_shift_mm"].as_f64().unwrap_or(0.0))
                    } else {
                        String::new()
                    },
                    f[k],
                    t[k],
                    s[k],
                    d[k]
                ));
            }
        }
    }
    if let Some(p) = &a.png {
        let fig = if focus.len() > 1 {
            let series: Vec<figures::FocusRow> = fields
                .iter()
                .flat_map(|(label, _)| wls.iter().map(move |&wl| (label.clone(), wl)))
                .map(|(label, wl)| {
                    let pick = |k: &str| -> Vec<(f64, f64)> {
                        rows.iter()
                            .filter(|r| r["field"] == label.as_str() && r["wavelength_nm"] == wl)
                            .map(|r| {
                                (
                                    r["focus_shift_mm"].as_f64().unwrap_or(0.0),
                                    r[k][0].as_f64().unwrap_or(f64::NAN),
                                )
                            })
                            .collect()
                    };
                    (
                        format!("{label}, {wl:.1} nm"),
                        pick("tangential"),
                        pick("sagittal"),
                    )
                })
                .collect();
            figures::through_focus_figure(
                &series,
                a.freq_lpmm[0],
                &format!(
                    "Through-focus MTF at {} cycles/mm: {}",
                    a.freq_lpmm[0], a.lens.lens
                ),
            )
        } else {
            figures::mtf_figure(&curves, &format!("{} MTF: {}", a.method, a.lens.lens))
        };
        figures::save(&fig, p)?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
