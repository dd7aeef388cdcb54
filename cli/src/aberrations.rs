//! `tolray aberrations`: field curvature, distortion (and grid distortion), lateral colour,
//! relative illumination, ray fans and OPD fans.

use crate::args::{parse_wavelengths, perturbed_system, LensArgs};
use crate::report::emit_line;
use crate::usage;
use crate::wave::WaveRayArgs;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::analysis::aberrations::{self as ab, DistortionKind};
use tolray::figures;
use tolray::trace::Field;
use tolray::wave::{Sampling, MAX_SAMPLES};
use tolray::Object;

/// Arguments of `tolray aberrations`.
#[derive(Args)]
pub struct AberrationsArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Fields of the ray and OPD fans, and wavelengths (distortion and relative illumination
    /// are at the lens' primary wavelength when it is among them, else at the first; lateral
    /// colour is against the primary wavelength).
    #[command(flatten)]
    pub rays: WaveRayArgs,
    /// Points from the axis to the full field (along y) of the curves against field.
    #[arg(long, default_value_t = 11)]
    pub points: usize,
    /// Points across the pupil of each ray and OPD fan.
    #[arg(long, default_value_t = 41)]
    pub fan_points: usize,
    /// Points a side of the grid-distortion grid (fields over the sensor's rectangle).
    #[arg(long, default_value_t = 11)]
    pub grid_points: usize,
    /// Print JSON instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Write the pictures as PREFIX-field-curvature.png, -distortion, -grid-distortion,
    /// -lateral-colour, -relative-illumination, -ray-fan and -opd-fan (SVG when PREFIX ends in
    /// .svg).
    #[arg(long, value_name = "PREFIX")]
    pub png: Option<PathBuf>,
}

fn picture(prefix: &Path, name: &str, f: &figures::Figure) -> anyhow::Result<()> {
    let s = prefix.to_string_lossy();
    let path = match s.strip_suffix(".svg") {
        Some(stem) => PathBuf::from(format!("{stem}-{name}.svg")),
        None => PathBuf::from(format!("{}-{name}.png", s.trim_end_matches(".png"))),
    };
    figures::save(f, &path)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// Runs `tolray aberrations`.
pub fn run(a: AberrationsArgs) -> anyhow::Result<()> {
    if !(2..=1001).contains(&a.points) {
        usage!("--points {}: give 2 to 1001", a.points);
    }
    if !(3..=MAX_SAMPLES).contains(&a.fan_points) {
        usage!("--fan-points {}: give 3 to {MAX_SAMPLES}", a.fan_points);
    }
    if !(2..=101).contains(&a.grid_points) {
        usage!("--grid-points {}: give 2 to 101", a.grid_points);
    }
    let (l, file_fields) = a.lens.load_with_fields()?;
    let fan_fields = a.rays.fields(file_fields)?;
    let wls = parse_wavelengths(&a.rays.wavelengths, &l)?;
    let sys = perturbed_system(&l, a.rays.perturb.as_deref())?;
    let opts = a.rays.options(&l, Sampling::default());
    let aim = opts.aim;
    let h: Vec<f64> = (0..a.points)
        .map(|i| i as f64 / (a.points - 1) as f64)
        .collect();
    let fields: Vec<Field> = h.iter().map(|&y| Field::fraction(y)).collect();
    // Distortion and relative illumination at the primary wavelength when it is given.
    let wl0 = wls
        .iter()
        .copied()
        .find(|w| (w - l.primary_wavelength_nm).abs() < 1e-6)
        .unwrap_or(wls[0]);
    let i0 = wls.iter().position(|&w| w == wl0).unwrap_or(0);
    let curvature = wls
        .iter()
        .map(|&wl| {
            fields
                .iter()
                .map(|&f| ab::field_curvature(&l, &sys, f, wl, aim))
                .collect::<tolray::Result<Vec<_>>>()
        })
        .collect::<tolray::Result<Vec<_>>>()?;
    let f_tan = ab::distortion(&l, &sys, &fields, wl0, DistortionKind::FTan, aim)?;
    let f_theta = match l.object {
        Object::Infinite => Some(ab::distortion(
            &l,
            &sys,
            &fields,
            wl0,
            DistortionKind::FTheta,
            aim,
        )?),
        Object::Finite { .. } => None,
    };
    let grid = ab::grid_distortion(&l, &sys, a.grid_points, wl0, DistortionKind::FTan, aim)?;
    let colour = ab::lateral_colour(&l, &sys, &fields, &wls, aim)?;
    let ri = ab::relative_illumination(&l, &sys, &fields, wl0, aim)?;
    let mut fans = Vec::new();
    for (label, f) in &fan_fields {
        for &wl in &wls {
            fans.push((
                label.clone(),
                ab::fans(&l, &sys, *f, wl, a.fan_points, &opts)?,
            ));
        }
    }
    if a.json {
        let v = serde_json::json!({
            "field_fraction": h,
            "wavelengths_nm": wls,
            "primary_wavelength_nm": l.primary_wavelength_nm,
            "field_curvature": wls.iter().zip(&curvature).map(|(wl, c)| serde_json::json!({
                "wavelength_nm": wl,
                "tangential_mm": c.iter().map(|v| v[0]).collect::<Vec<_>>(),
                "sagittal_mm": c.iter().map(|v| v[1]).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "distortion_wavelength_nm": wl0,
            "distortion_f_tan_percent": f_tan,
            "distortion_f_theta_percent": f_theta,
            "grid_distortion": grid,
            "lateral_colour": wls.iter().enumerate().map(|(k, wl)| serde_json::json!({
                "wavelength_nm": wl,
                "um": colour.iter().map(|c| c[k]).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "relative_illumination": ri,
            "fans": fans.iter().map(|(label, f)| serde_json::json!({
                "field": label,
                "wavelength_nm": f.wavelength_nm,
                "pupil": f.pupil,
                "tangential_um": f.tangential_um,
                "sagittal_um": f.sagittal_um,
                "opd_tangential_waves": f.opd_tangential_waves,
                "opd_sagittal_waves": f.opd_sagittal_waves,
            })).collect::<Vec<_>>(),
        });
        emit_line(&serde_json::to_string_pretty(&v)?);
    } else {
        emit_line(&format!(
            "Aberrations against field (fraction of the full field along y), {wl0:.2} nm; focus in mm \
             from the image plane, lateral colour in µm against {:.2} nm:",
            l.primary_wavelength_nm
        ));
        let mut head = format!(
            "{:>6} {:>11} {:>11} {:>10} {:>10} {:>8}",
            "field", "T focus", "S focus", "f-tan %", "f-θ %", "rel. ill."
        );
        for wl in &wls {
            head.push_str(&format!(" {:>12}", format!("lat {wl:.1}")));
        }
        emit_line(&head);
        for (k, y) in h.iter().enumerate() {
            let mut row = format!(
                "{y:>6.3} {:>11.6} {:>11.6} {:>10.5} {:>10} {:>8.4}",
                curvature[i0][k][0],
                curvature[i0][k][1],
                f_tan[k],
                f_theta
                    .as_ref()
                    .map_or("-".to_string(), |v| format!("{:.5}", v[k])),
                ri[k]
            );
            for c in &colour[k] {
                row.push_str(&format!(" {c:>12.4}"));
            }
            emit_line(&row);
        }
        let worst = grid
            .distortion_pct
            .iter()
            .position(|&d| d == grid.max_distortion_pct)
            .unwrap_or(0);
        emit_line(&format!(
            "\nGrid distortion ({n} x {n} fields over the sensor, f-tan θ, {wl0:.2} nm): largest \
             {:.5} % at field ({:.3}, {:.3})",
            grid.max_distortion_pct,
            grid.fields[worst][0],
            grid.fields[worst][1],
            n = grid.n
        ));
        emit_line(&format!(
            "\nRay fans (transverse error, µm, against the chief ray at {:.2} nm) and OPD fans (waves), \
             {} points across the pupil; the edges and the largest |error|:",
            l.primary_wavelength_nm, a.fan_points
        ));
        emit_line(&format!(
            "{:>16} {:>9} {:>12} {:>12} {:>12} {:>12}",
            "field", "λ nm", "max |ey| T", "max |ex| S", "max |OPD| T", "max |OPD| S"
        ));
        let max = |v: &[f64]| {
            v.iter()
                .filter(|x| x.is_finite())
                .fold(0.0f64, |m, x| m.max(x.abs()))
        };
        for (label, f) in &fans {
            emit_line(&format!(
                "{label:>16} {:>9.2} {:>12.4} {:>12.4} {:>12.5} {:>12.5}",
                f.wavelength_nm,
                max(&f.tangential_um),
                max(&f.sagittal_um),
                max(&f.opd_tangential_waves),
                max(&f.opd_sagittal_waves)
            ));
        }
    }
    if let Some(prefix) = &a.png {
        let name = &a.lens.lens;
        let by_field = |v: &dyn Fn(usize) -> f64| -> Vec<(f64, f64)> {
            h.iter().enumerate().map(|(k, &y)| (v(k), y)).collect()
        };
        let mut s = Vec::new();
        for (i, wl) in wls.iter().enumerate() {
            s.push((
                format!("T {wl:.1} nm"),
                i,
                false,
                by_field(&|k| curvature[i][k][0]),
            ));
            s.push((
                format!("S {wl:.1} nm"),
                i,
                true,
                by_field(&|k| curvature[i][k][1]),
            ));
        }
        picture(
            prefix,
            "field-curvature",
            &figures::curves_figure(
                &format!("Field curvature of {name}"),
                "focus from the image plane (mm)",
                "field (fraction of full field)",
                Some(0.0..1.02),
                &s,
            ),
        )?;
        let mut s = vec![("f-tan θ".to_string(), 0, false, by_field(&|k| f_tan[k]))];
        if let Some(v) = &f_theta {
            s.push(("f-θ".to_string(), 1, true, by_field(&|k| v[k])));
        }
        picture(
            prefix,
            "distortion",
            &figures::curves_figure(
                &format!("Distortion of {name} at {wl0:.1} nm"),
                "distortion (%)",
                "field (fraction of full field)",
                Some(0.0..1.02),
                &s,
            ),
        )?;
        picture(
            prefix,
            "grid-distortion",
            &figures::grid_distortion_figure(
                &grid,
                &format!(
                    "Grid distortion of {name} at {wl0:.1} nm: largest {:.3} %",
                    grid.max_distortion_pct
                ),
            ),
        )?;
        let s: Vec<_> = wls
            .iter()
            .enumerate()
            .map(|(i, wl)| (format!("{wl:.1} nm"), i, false, by_field(&|k| colour[k][i])))
            .collect();
        picture(
            prefix,
            "lateral-colour",
            &figures::curves_figure(
                &format!(
                    "Lateral colour of {name} against {:.1} nm",
                    l.primary_wavelength_nm
                ),
                "chief ray's image height minus the primary wavelength's (µm)",
                "field (fraction of full field)",
                Some(0.0..1.02),
                &s,
            ),
        )?;
        let pts: Vec<(f64, f64)> = h.iter().copied().zip(ri.iter().copied()).collect();
        picture(
            prefix,
            "relative-illumination",
            &figures::curves_figure(
                &format!("Relative illumination of {name} at {wl0:.1} nm"),
                "field (fraction of full field)",
                "relative illumination",
                Some(0.0..1.02),
                &[("relative illumination".to_string(), 0, false, pts)],
            ),
        )?;
        for (kind, unit, opd) in [
            ("ray-fan", "transverse ray error (µm)", false),
            ("opd-fan", "OPD (waves)", true),
        ] {
            let rows: Vec<figures::FanRow> = fan_fields
                .iter()
                .map(|(label, _)| {
                    let curves = fans
                        .iter()
                        .filter(|(l2, _)| l2 == label)
                        .map(|(_, f)| {
                            let pts = |v: &[f64]| {
                                f.pupil
                                    .iter()
                                    .copied()
                                    .zip(v.iter().copied())
                                    .collect::<Vec<_>>()
                            };
                            let (t, s) = if opd {
                                (pts(&f.opd_tangential_waves), pts(&f.opd_sagittal_waves))
                            } else {
                                (pts(&f.tangential_um), pts(&f.sagittal_um))
                            };
                            (format!("{:.1} nm", f.wavelength_nm), t, s)
                        })
                        .collect();
                    (label.clone(), curves)
                })
                .collect();
            let what = if opd { "OPD fans" } else { "Ray fans" };
            picture(
                prefix,
                kind,
                &figures::fan_figure(&format!("{what} of {name}"), unit, &rows),
            )?;
        }
    }
    Ok(())
}
