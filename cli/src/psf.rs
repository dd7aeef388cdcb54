//! The PSF commands: `tolray psf` and `psf-map`.

use crate::args::{parse_wavelengths, perturbed_system, LensArgs, PsfArgs};
use crate::report::emit_line;
use crate::usage;
use clap::Args;
use std::path::PathBuf;
use tolray::figures;
use tolray::trace::Field;

/// Arguments of `tolray psf`.
#[derive(Args)]
pub struct PsfCmdArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Field (fraction, 5deg angle, 2.5mm object height, 14mm@image or 14mm@real-image image
    /// height; x:y pairs allowed).
    #[arg(long, default_value = "0")]
    pub field: String,
    /// Wavelengths in nm, or primary (the lens' primary wavelength), d, F, C, rgb (one PSF each).
    #[arg(long, value_delimiter = ',', default_value = "primary")]
    pub wavelengths: Vec<String>,
    #[command(flatten)]
    pub psf: PsfArgs,
    /// Trace the lens perturbed by this tolerance pattern.
    #[arg(long, value_name = "PATTERN.json")]
    pub perturb: Option<PathBuf>,
    /// Write the PSF picture (PNG at 2 pixels per point, or SVG if FILE ends in .svg).
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
    /// Write the linear PSF(s) as OpenEXR.
    #[arg(long, value_name = "FILE.exr")]
    pub exr: Option<PathBuf>,
    /// Print the PSF values as JSON.
    #[arg(long)]
    pub json: bool,
    /// geometric: rays splatted at the pixel pitch (unit sum); fft: the pupil function's FFT;
    /// huygens: the direct sum of wavelets from the reference sphere (any pitch, tilted planes,
    /// wide fields). Diffraction PSFs are relative to the unaberrated peak.
    #[arg(long, default_value = "geometric", value_parser = ["geometric", "fft", "huygens"])]
    pub method: String,
    /// Pupil samples across the diameter (fft, huygens).
    #[arg(long, default_value_t = 64)]
    pub pupil_samples: usize,
    /// FFT grid side, at least twice the pupil samples (fft: pixels of λ N_w pupil-samples /
    /// grid; the central --ks x --ks pixels are written).
    #[arg(long, default_value_t = 256)]
    pub grid: usize,
    /// With --method huygens, add the polychromatic PSF: the wavelengths' PSFs (equal weights,
    /// each relative to its own unaberrated peak) summed on one grid centred on the primary
    /// wavelength's chief ray (the first wavelength's when the primary is not listed), so that
    /// lateral colour spreads it; its pitch is that wavelength's unless --pitch-um is given.
    #[arg(long)]
    pub polychromatic: bool,
}

/// Runs `tolray psf`.
pub fn run(a: PsfCmdArgs) -> anyhow::Result<()> {
    let PsfCmdArgs {
        lens,
        field,
        wavelengths,
        psf,
        perturb,
        png,
        exr,
        json,
        method: a_method,
        pupil_samples,
        grid,
        polychromatic,
    } = a;
    if polychromatic && a_method != "huygens" {
        usage!(
            "--polychromatic needs --method huygens: the {a_method} PSFs of different wavelengths \
             have different pixels"
        );
    }
    if a_method != "geometric" {
        return run_diffraction(DiffractionArgs {
            lens: &lens,
            field: &field,
            wavelengths: &wavelengths,
            perturb: perturb.as_deref(),
            png: png.as_deref(),
            exr: exr.as_deref(),
            json,
            method: &a_method,
            pupil_samples,
            grid,
            pitch_um: psf.pitch_um,
            image_samples: psf.ks,
            polychromatic,
        });
    }
    let l = lens.load()?;
    warn_afocal(&l);
    let opts = psf.options(&l)?;
    let field = Field::parse(&field)?;
    let wls = parse_wavelengths(&wavelengths, &l)?;
    let sys = perturbed_system(&l, perturb.as_deref())?;
    // Each PSF's rays are generated, traced and splatted a chunk at a time on every core.
    let psfs: Vec<Vec<f64>> = wls
        .iter()
        .map(|&w| Ok(tolray::psf::psf_streamed(&l, &sys, field, w, &opts)?.0))
        .collect::<tolray::Result<_>>()?;
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
    Ok(())
}

/// Arguments of `tolray psf-map`.
#[derive(Args)]
pub struct PsfMapArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Fields per side of the grid.
    #[arg(long, default_value_t = 8)]
    pub grid: usize,
    /// Wavelength, nm (or primary, d, F, C).
    #[arg(long, default_value = "primary")]
    pub wavelength: String,
    #[command(flatten)]
    pub psf: PsfArgs,
    /// Write the map picture, each PSF normalized to its peak (PNG at 2 pixels per point, or SVG
    /// if FILE ends in .svg).
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
    /// Write the linear mosaic as OpenEXR.
    #[arg(long, value_name = "FILE.exr")]
    pub exr: Option<PathBuf>,
}

/// Runs `tolray psf-map`.
pub fn run_map(a: PsfMapArgs) -> anyhow::Result<()> {
    let PsfMapArgs {
        lens,
        grid,
        wavelength,
        psf,
        png,
        exr,
    } = a;
    let l = lens.load()?;
    warn_afocal(&l);
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
    Ok(())
}

/// Says on stderr that an afocal lens' PSF is its collimated beams' footprint on the image
/// plane, cropped to the PSF window (no focus forms there).
fn warn_afocal(l: &tolray::Lens) {
    if l.paraxial(l.primary_wavelength_nm)
        .is_ok_and(|p| p.is_afocal())
    {
        eprintln!(
            "warning: the lens is afocal: its beams leave collimated, so a PSF on the image \
             plane is each beam's footprint cropped to the PSF window; `tolray spot --afocal` \
             gives its angular spread"
        );
    }
}

/// What `tolray psf --method fft|huygens` needs.
struct DiffractionArgs<'a> {
    lens: &'a LensArgs,
    field: &'a str,
    wavelengths: &'a [String],
    perturb: Option<&'a std::path::Path>,
    png: Option<&'a std::path::Path>,
    exr: Option<&'a std::path::Path>,
    json: bool,
    method: &'a str,
    pupil_samples: usize,
    grid: usize,
    pitch_um: Option<f64>,
    image_samples: usize,
    polychromatic: bool,
}

/// The central `k x k` pixels of `p` (all of it when `k` is 0 or not smaller), pixel (k/2, k/2)
/// staying on the chief ray's image point.
fn crop(p: tolray::wave::psf::DiffractionPsf, k: usize) -> tolray::wave::psf::DiffractionPsf {
    if k == 0 || k >= p.n {
        return p;
    }
    let off = p.n / 2 - k / 2;
    let values = (0..k)
        .flat_map(|r| (0..k).map(move |c| (r, c)))
        .map(|(r, c)| p.values[(r + off) * p.n + c + off])
        .collect();
    tolray::wave::psf::DiffractionPsf { n: k, values, ..p }
}

/// `tolray psf --method fft|huygens`: one diffraction PSF per wavelength.
fn run_diffraction(a: DiffractionArgs) -> anyhow::Result<()> {
    use tolray::wave::psf::{fft_psf, huygens_psf, FftOptions, HuygensOptions};
    use tolray::wave::{wavefront, Sampling, WaveOptions};
    let l = a.lens.load()?;
    let field = Field::parse(a.field)?;
    let wls = parse_wavelengths(a.wavelengths, &l)?;
    let sys = perturbed_system(&l, a.perturb)?;
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
    let opts = WaveOptions {
        sampling: Sampling::Grid(a.pupil_samples),
        aim: l.ray_aiming,
        ..WaveOptions::default()
    };
    let mut psfs = Vec::new();
    // Each wavelength's wavefront and Huygens pitch, for the polychromatic PSF.
    let mut waves = Vec::new();
    for &wl in &wls {
        // Rounded as the user writes wavelengths (the d line is 587.5618 nm, not ...6000001).
        let what = format!("field {}, {} nm", field.label(), (wl * 1e4).round() / 1e4);
        let trace = |fft: &FftOptions| {
            let o = WaveOptions {
                sampling: Sampling::Grid(fft.pupil_samples),
                ..opts
            };
            wavefront(&l, &sys, field, wl, &o)
        };
        let p = if a.method == "fft" {
            let p =
                crate::wave::with_fine_enough_pupil(a.pupil_samples, a.grid, &what, &mut |fft| {
                    fft_psf(&trace(fft)?, fft)
                })?
                .0;
            crop(p, a.image_samples)
        } else {
            if a.image_samples == 0 || a.image_samples > tolray::wave::psf::MAX_HUYGENS_SIDE {
                usage!(
                    "--ks {}: give 1 to {} image points per side",
                    a.image_samples,
                    tolray::wave::psf::MAX_HUYGENS_SIDE
                );
            }
            // The FFT PSF's pitch unless given, so that the two compare pixel for pixel.
            let ((p, w, pitch), _) =
                crate::wave::with_fine_enough_pupil(a.pupil_samples, a.grid, &what, &mut |fft| {
                    let w = trace(fft)?;
                    let pitch = match a.pitch_um {
                        Some(p) => p,
                        None => fft_psf(&w, fft)?.pitch_um[0],
                    };
                    let p = huygens_psf(
                        &w,
                        &HuygensOptions {
                            image_samples: a.image_samples,
                            pitch_um: pitch,
                        },
                    )?;
                    Ok((p, w, pitch))
                })?;
            if a.polychromatic {
                waves.push((w, pitch));
            }
            p
        };
        emit_line(&format!(
            "{} PSF at field {}, {wl:.2} nm: {}x{} px of {:.4} x {:.4} µm, Strehl {:.5}, peak pixel {:.5}",
            a.method,
            field.label(),
            p.n,
            p.n,
            p.pitch_um[0],
            p.pitch_um[1],
            p.strehl,
            p.values.iter().copied().fold(0.0, f64::max)
        ));
        psfs.push(p);
    }
    let poly = if a.polychromatic {
        // The primary wavelength first: the grid is centred on its chief ray.
        let first = wls
            .iter()
            .position(|&w| w == l.primary_wavelength_nm)
            .unwrap_or(0);
        let mut refs: Vec<(&tolray::wave::Wavefront, f64)> =
            waves.iter().map(|(w, _)| (w, 1.0)).collect();
        refs.swap(0, first);
        let p = tolray::wave::psf::polychromatic_huygens_psf(
            &refs,
            &HuygensOptions {
                image_samples: a.image_samples,
                pitch_um: a.pitch_um.unwrap_or(waves[first].1),
            },
        )?;
        emit_line(&format!(
            "polychromatic huygens PSF at field {} ({} wavelengths, equal weights, centred on \
             {:.2} nm): {}x{} px of {:.4} µm, Strehl {:.5}",
            field.label(),
            wls.len(),
            wls[first],
            p.n,
            p.n,
            p.pitch_um[0],
            p.strehl
        ));
        Some(p)
    } else {
        None
    };
    if a.json {
        let mut v = serde_json::json!({
            "method": a.method,
            "field": a.field,
            "wavelengths_nm": wls,
            "n": psfs[0].n,
            "pitch_um": psfs.iter().map(|p| p.pitch_um).collect::<Vec<_>>(),
            "strehl": psfs[0].strehl,
            "strehl_per_wavelength": psfs.iter().map(|p| p.strehl).collect::<Vec<_>>(),
            "psf": psfs.iter().map(|p| &p.values).collect::<Vec<_>>(),
        });
        if let Some(p) = &poly {
            v["polychromatic"] = serde_json::json!({
                "strehl": p.strehl,
                "pitch_um": p.pitch_um,
                "centre_image_mm": p.centre_image_mm,
                "psf": p.values,
            });
        }
        emit_line(&serde_json::to_string(&v)?);
    }
    psfs.extend(poly);
    let tiles: Vec<Vec<f64>> = psfs.iter().map(|p| p.values.clone()).collect();
    let n = psfs[0].n;
    if let Some(p) = a.png {
        figures::save(
            &figures::psf_figure(
                &tiles,
                n,
                tiles.len(),
                &format!("{} PSF {} field {}", a.method, a.lens.lens, field.label()),
            ),
            p,
        )?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(p) = a.exr {
        let (w, h, v) = figures::mosaic(&tiles, n, tiles.len());
        figures::save_exr(p, w, h, &v)?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
