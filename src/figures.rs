//! Pictures: spot diagrams and lens layouts, drawn on a [`Canvas`].

use crate::analysis::SpotResult;
use crate::error::{Error, Result};
use crate::lens::{Lens, Paraxial, SurfaceRole, System};
use crate::math::Vec3;
use crate::plot::{Canvas, PALETTE};
use crate::trace::reference::trace_ray;
use crate::trace::{Field, Pupil, PupilPattern, RaySet};
use std::path::Path;

/// Writes `canvas` as PNG atomically.
///
/// # Errors
/// [`crate::ErrorKind::Io`] naming the path.
pub fn save(canvas: &Canvas, path: &Path) -> Result<()> {
    canvas.save_png(path).map_err(|e| Error::io(path, e))
}

/// A spot diagram: one panel per field, every wavelength overlaid in its own colour, in
/// micrometres about the field's polychromatic (or only) centroid, same scale in every panel.
pub fn spot_figure(results: &[SpotResult], title: &str) -> Canvas {
    let mut fields: Vec<Field> = Vec::new();
    for r in results {
        if !fields.contains(&r.field) {
            fields.push(r.field);
        }
    }
    let per_field = |f: &Field| {
        let f = *f;
        results.iter().filter(move |r| r.field == f)
    };
    // Centre per field, and a common half-width in µm.
    let centre = |f: &Field| {
        let all: Vec<&SpotResult> = per_field(f).collect();
        let poly = all
            .iter()
            .find(|r| r.wavelength_nm.is_none())
            .or(all.first());
        poly.map_or([0.0, 0.0], |r| r.stats.centroid_mm)
    };
    let mut half = 1e-3f64;
    for f in &fields {
        let c = centre(f);
        for r in per_field(f).filter(|r| r.wavelength_nm.is_some()) {
            for p in &r.points {
                half = half.max(((p[0] - c[0]).abs()).max((p[1] - c[1]).abs()) * 1e3);
            }
        }
    }
    half *= 1.05;
    let cols = fields.len().clamp(1, 4);
    let rows = fields.len().div_ceil(cols).max(1);
    let (pw, ph) = (300u32, 300u32);
    let mut cv = Canvas::new(cols as u32 * (pw + 80) + 20, rows as u32 * (ph + 90) + 60);
    cv.set_view(
        (0, 0, cv.image().width(), 40),
        (0.0, 1.0),
        (0.0, 1.0),
        false,
    );
    cv.title(title);
    for (k, f) in fields.iter().enumerate() {
        let (col, row) = ((k % cols) as u32, (k / cols) as u32);
        let rect = (70 + col * (pw + 80), 80 + row * (ph + 90), pw, ph);
        cv.set_view(rect, (-half, half), (-half, half), true);
        let c = centre(f);
        let mut legend = Vec::new();
        for (w, r) in per_field(f)
            .filter(|r| r.wavelength_nm.is_some())
            .enumerate()
        {
            let colour = PALETTE[w % PALETTE.len()];
            for p in &r.points {
                cv.dot(((p[0] - c[0]) * 1e3, (p[1] - c[1]) * 1e3), 0.0, colour);
            }
            legend.push((format!("{:.1} nm", r.wavelength_nm.unwrap_or(0.0)), colour));
        }
        cv.axes("x (um)", "y (um)");
        let rms = per_field(f)
            .find(|r| r.wavelength_nm.is_none())
            .or_else(|| per_field(f).next())
            .map_or(0.0, |r| r.stats.rms_um);
        cv.text_px(
            rect.0 as i32,
            rect.1 as i32 - 30,
            &format!("field {}  RMS {:.2} um", f.label(), rms),
            1,
            [0, 0, 0],
        );
        let mut y = rect.1 as i32 + 4;
        for (label, colour) in legend {
            cv.text_px(
                (rect.0 + pw) as i32 - Canvas::text_width(&label, 1) as i32 - 4,
                y,
                &label,
                1,
                colour,
            );
            y += 10;
        }
    }
    cv
}

/// Meridional layout: surface profiles, element edges, stop, image plane, and a fan of
/// `rays_per_field` meridional rays for each field (aimed at the paraxial entrance pupil).
///
/// # Errors
/// Paraxial or ray-generation errors.
pub fn layout_figure(
    lens: &Lens,
    sys: &System<f64>,
    para: &Paraxial,
    fields: &[Field],
    wavelength_nm: f64,
    rays_per_field: usize,
) -> Result<Canvas> {
    let z = lens.vertex_z_mm();
    let track = *z.last().unwrap_or(&1.0);
    let ymax = lens
        .surfaces
        .iter()
        .map(|s| s.semi_aperture_mm)
        .fold(lens.sensor.half_diagonal_mm(), f64::max);
    let zmin = -0.08 * track;
    let mut cv = Canvas::new(1100, 560);
    cv.set_view(
        (60, 50, 1020, 460),
        (zmin, track * 1.03),
        (-ymax * 1.1, ymax * 1.1),
        true,
    );
    // Rays first, so the glass outlines stay visible.
    let n = sys.indices(wavelength_nm);
    let fan = Pupil {
        pattern: PupilPattern::Grid(rays_per_field.max(1)),
        scale: 1.0,
        aim: false,
    };
    for (k, &f) in fields.iter().enumerate() {
        let set = RaySet::generate(
            lens,
            para,
            f,
            &Pupil {
                pattern: PupilPattern::Grid(1),
                ..fan
            },
            wavelength_nm,
        )?;
        let colour = PALETTE[k % PALETTE.len()];
        let r_ep = 0.5 * para.entrance_pupil_diameter_mm;
        let m = rays_per_field.max(1);
        for j in 0..m {
            let py = if m == 1 {
                0.0
            } else {
                (2.0 * j as f64 / (m - 1) as f64 - 1.0) * r_ep * 0.999
            };
            let (o0, d0) = set.chief;
            // Shift the chief ray's pupil point along y (same object point or direction).
            let (o, d) = match lens.object {
                crate::Object::Finite { .. } => {
                    let target = o0
                        + d0 * ((para.entrance_pupil_z_mm - o0.z) / d0.z)
                        + Vec3::new(0.0, py, 0.0);
                    (o0, (target - o0).normalized())
                }
                crate::Object::Infinite => (o0 + Vec3::new(0.0, py, 0.0), d0),
            };
            let mut pts = vec![(o.z.max(zmin), o.y + d.y * ((o.z.max(zmin) - o.z) / d.z))];
            for i in 0..=lens.surfaces.len() {
                let upto = (i < lens.surfaces.len()).then_some(i);
                let r = trace_ray(sys, &n, o, d, true, upto);
                if !r.status.is_alive() {
                    break;
                }
                pts.push((r.o.z, r.o.y));
            }
            cv.polyline(&pts, colour);
        }
    }
    let black = [0, 0, 0];
    let profile = |i: usize| -> Vec<(f64, f64)> {
        let s = &lens.surfaces[i];
        let r = s.semi_aperture_mm;
        (0..=60)
            .filter_map(|j| {
                let y = -r + 2.0 * r * j as f64 / 60.0;
                s.sag(y).map(|sz| (z[i] + sz, y))
            })
            .collect()
    };
    for (i, s) in lens.surfaces.iter().enumerate() {
        if s.role == SurfaceRole::Aperture || s.is_stop {
            let r = s.semi_aperture_mm;
            let zs = z[i] + s.sag(r).unwrap_or(0.0);
            cv.line((zs, r), (zs, r + 0.15 * ymax), black);
            cv.line((zs, -r), (zs, -r - 0.15 * ymax), black);
        }
        if s.role == SurfaceRole::Refractive {
            cv.polyline(&profile(i), black);
        }
        // Element edges: join this surface to the next through the glass.
        if !s.material.is_air() && i + 1 < lens.surfaces.len() {
            let (a, b) = (profile(i), profile(i + 1));
            for (pa, pb) in [(a.first(), b.first()), (a.last(), b.last())] {
                if let (Some(pa), Some(pb)) = (pa, pb) {
                    let edge = if pa.1.abs() > pb.1.abs() {
                        (pb.0, pa.1)
                    } else {
                        (pa.0, pb.1)
                    };
                    cv.polyline(&[*pa, edge, *pb], black);
                }
            }
        }
    }
    let h = lens.sensor.half_diagonal_mm();
    cv.line((track, -h), (track, h), [200, 0, 0]);
    cv.line((zmin, 0.0), (track * 1.02, 0.0), [160, 160, 160]);
    cv.axes("z (mm)", "y (mm)");
    cv.title(&format!(
        "{}  EFL {:.2} mm  F/{:.2}",
        short(&lens.info),
        para.efl_mm,
        para.fnum
    ));
    Ok(cv)
}

fn short(s: &str) -> &str {
    s.split(':').next().unwrap_or(s).trim()
}

/// Histogram and cumulative distribution of Monte Carlo RMS spots (mean over fields), with the
/// nominal value and the 90 % / 50 % yield lines marked.
pub fn tolerance_figure(report: &crate::tolerance::McReport) -> Canvas {
    let v: Vec<f64> = report.trials.iter().map(|t| t.mean_rms_um).collect();
    let nominal =
        report.nominal_rms_um.iter().sum::<f64>() / report.nominal_rms_um.len().max(1) as f64;
    let (lo, hi) = v
        .iter()
        .fold((nominal, nominal), |(a, b), &x| (a.min(x), b.max(x)));
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        (lo - 1.0, hi + 1.0)
    };
    let bins = (v.len() as f64).sqrt().clamp(5.0, 60.0) as usize;
    let w = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for x in &v {
        counts[(((x - lo) / w) as usize).min(bins - 1)] += 1;
    }
    let top = *counts.iter().max().unwrap_or(&1) as f64;
    let mut cv = Canvas::new(900, 480);
    cv.set_view(
        (70, 50, 800, 370),
        (lo - w, hi + w),
        (0.0, top * 1.1),
        false,
    );
    for (b, &c) in counts.iter().enumerate() {
        let x0 = lo + b as f64 * w;
        let (p0, p1) = (cv.to_px(x0, c as f64), cv.to_px(x0 + w, 0.0));
        let (x, y) = (p0.0.round() as i32, p0.1.round() as i32);
        cv.rect_px(
            x,
            y,
            (p1.0 - p0.0).max(1.0) as u32,
            (p1.1 - p0.1).max(1.0) as u32,
            [120, 160, 220],
            true,
        );
    }
    // CDF on the same axes, scaled to the histogram's height.
    let mut s = v.clone();
    s.sort_by(f64::total_cmp);
    let cdf: Vec<(f64, f64)> = s
        .iter()
        .enumerate()
        .map(|(i, &x)| (x, (i + 1) as f64 / s.len() as f64 * top * 1.1))
        .collect();
    cv.polyline(&cdf, [200, 60, 30]);
    cv.line((nominal, 0.0), (nominal, top * 1.1), [0, 150, 0]);
    if let Some(sm) = &report.summary {
        for r in &sm.mean_over_fields.yield_below {
            if r[0] == 0.9 || r[0] == 0.5 {
                cv.line((r[1], 0.0), (r[1], top * 1.1), [90, 90, 90]);
            }
        }
    }
    cv.axes(
        "mean RMS spot over fields (um)",
        "trials (bars); CDF (line, full height = 100 %)",
    );
    cv.title(&format!(
        "Monte Carlo {}: {} trials (green nominal, grey 50/90 % yield)",
        report.lens,
        v.len()
    ));
    cv
}

/// A PSF (or a mosaic of PSFs) as a heat map, each tile normalized to its own peak.
/// `tiles` are `ks x ks` row-major images laid out `cols` per row.
pub fn psf_figure(tiles: &[Vec<f64>], ks: usize, cols: usize, title: &str) -> Canvas {
    let cols = cols.max(1);
    let rows = tiles.len().div_ceil(cols).max(1);
    let scale = (600 / (cols * ks)).clamp(1, 12) as u32;
    let tile = ks as u32 * scale;
    let mut cv = Canvas::new(cols as u32 * (tile + 2) + 40, rows as u32 * (tile + 2) + 70);
    cv.set_view(
        (0, 0, cv.image().width(), 40),
        (0.0, 1.0),
        (0.0, 1.0),
        false,
    );
    cv.title(title);
    for (k, t) in tiles.iter().enumerate() {
        let (c, r) = ((k % cols) as u32, (k / cols) as u32);
        let peak = t.iter().copied().fold(0.0, f64::max);
        cv.heatmap_px(
            (20 + c * (tile + 2), 50 + r * (tile + 2), tile, tile),
            t,
            ks,
            ks,
            peak,
        );
    }
    cv
}

/// Writes a single-channel linear image (e.g. a PSF map mosaic) as OpenEXR, atomically.
///
/// # Errors
/// [`crate::ErrorKind::Io`] naming the path.
pub fn save_exr(path: &Path, width: usize, height: usize, values: &[f64]) -> Result<()> {
    write_exr(path, width, height, |i| {
        let v = values.get(i).copied().unwrap_or(0.0) as f32;
        (v, v, v)
    })
}

/// Writes planar linear RGB (`3 · width · height` values, channel-major) as a 32-bit float
/// OpenEXR file, atomically.
///
/// # Errors
/// [`crate::ErrorKind::Io`] naming the path.
pub fn save_exr_rgb(path: &Path, width: usize, height: usize, planar: &[f32]) -> Result<()> {
    let n = width * height;
    write_exr(path, width, height, |i| {
        let g = |c: usize| planar.get(c * n + i).copied().unwrap_or(0.0);
        (g(0), g(1), g(2))
    })
}

/// Writes an RGB EXR whose pixel `i` (row-major) is `rgb(i)`, through a temporary file.
fn write_exr(
    path: &Path,
    width: usize,
    height: usize,
    rgb: impl Fn(usize) -> (f32, f32, f32) + Sync,
) -> Result<()> {
    crate::error::write_via_temp(path, |tmp| {
        exr::prelude::write_rgb_file(tmp, width, height, |x, y| rgb(y * width + x))
            .map_err(|e| std::io::Error::other(e.to_string()))
    })
}

/// Lays `tiles` (`ks x ks` each) out in a `cols`-wide mosaic: (width, height, values).
pub fn mosaic(tiles: &[Vec<f64>], ks: usize, cols: usize) -> (usize, usize, Vec<f64>) {
    let rows = tiles.len().div_ceil(cols.max(1));
    let (w, h) = (cols * ks, rows * ks);
    let mut out = vec![0.0; w * h];
    for (k, t) in tiles.iter().enumerate() {
        let (c, r) = (k % cols, k / cols);
        for j in 0..ks {
            for i in 0..ks {
                out[(r * ks + j) * w + c * ks + i] = t[j * ks + i];
            }
        }
    }
    (w, h, out)
}

/// Training curve: loss per iteration (and spot size on a second panel), stages marked.
pub fn training_figure(logs: &[crate::optim::train::IterLog], title: &str) -> Canvas {
    let mut cv = Canvas::new(900, 640);
    cv.set_view((0, 0, 900, 40), (0.0, 1.0), (0.0, 1.0), false);
    cv.title(title);
    let n = logs.len().max(2) as f64;
    let panel =
        |cv: &mut Canvas, rect: (u32, u32, u32, u32), ys: Vec<(f64, f64)>, label: &str, colour| {
            let (lo, hi) = ys
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                    (a.min(p.1), b.max(p.1))
                });
            let (lo, hi) = if lo.is_finite() && hi > lo {
                (lo, hi)
            } else {
                (0.0, 1.0)
            };
            cv.set_view(
                rect,
                (0.0, n),
                (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo)),
                false,
            );
            cv.polyline(&ys, colour);
            if let Some(b) = logs
                .iter()
                .position(|l| l.stage == crate::optim::train::Stage::Tolerance)
            {
                if b > 0 {
                    cv.line((b as f64, lo), (b as f64, hi), [150, 150, 150]);
                }
            }
            cv.axes("iteration", label);
        };
    panel(
        &mut cv,
        (80, 60, 780, 230),
        logs.iter().map(|l| (l.iter as f64, l.loss)).collect(),
        "loss",
        PALETTE[0],
    );
    panel(
        &mut cv,
        (80, 360, 780, 230),
        logs.iter().map(|l| (l.iter as f64, l.spot_um)).collect(),
        "spot (um): RMS in stage 1, mean distance in stage 2",
        PALETTE[1],
    );
    cv
}

/// Training curves of a deep-optics study: the batch PSNR (light) and the validation PSNR
/// (dots) against the iteration (top), and the batch image loss on a log10 scale (bottom). Stage
/// 1, which the branches share, is drawn once in grey; a grey line marks where the branches
/// start.
pub fn deep_training_figure(
    branches: &[(String, Vec<crate::deep::DeepLog>)],
    title: &str,
) -> Canvas {
    use crate::deep::DeepLog;
    let mut cv = Canvas::new(900, 680);
    cv.set_view((0, 0, 900, 40), (0.0, 1.0), (0.0, 1.0), false);
    cv.title(title);
    let all = || branches.iter().flat_map(|b| b.1.iter());
    let n = all().map(|l| l.iter + 1).max().unwrap_or(2).max(2) as f64;
    // Where the branches part: the first iteration at which two branches differ in phase, or
    // the end of the common prefix.
    let split = branches.first().map_or(0, |b0| {
        b0.1.iter()
            .position(|l| {
                branches.iter().any(|b| {
                    b.1.iter()
                        .find(|m| m.iter == l.iter)
                        .map_or(true, |m| m.phase != l.phase || m.psnr_db != l.psnr_db)
                })
            })
            .map_or(b0.1.last().map_or(0, |l| l.iter + 1), |k| b0.1[k].iter)
    });
    const GREY: crate::plot::Rgb = [90, 90, 90];
    let mut series: Vec<(crate::plot::Rgb, Vec<&DeepLog>)> = Vec::new();
    if let Some(b0) = branches.first() {
        series.push((GREY, b0.1.iter().filter(|l| l.iter < split).collect()));
    }
    for (k, (_, logs)) in branches.iter().enumerate() {
        let c = PALETTE[k % PALETTE.len()];
        // Joined to the last shared point so that the curves continue.
        let from = split.saturating_sub(1);
        series.push((c, logs.iter().filter(|l| l.iter >= from).collect()));
    }
    let range = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v
            .filter(|x| x.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(x), b.max(x))
            });
        if lo.is_finite() && hi > lo {
            (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        } else {
            (lo.min(0.0), lo.max(0.0) + 1.0)
        }
    };
    // Top panel: PSNR.
    let yr = range(
        &mut all()
            .flat_map(|l| [Some(l.psnr_db), l.val_psnr_db])
            .flatten(),
    );
    cv.set_view((80, 70, 640, 260), (0.0, n), yr, false);
    if split > 0 {
        cv.line((split as f64, yr.0), (split as f64, yr.1), [170, 170, 170]);
    }
    for (c, logs) in &series {
        let faint = c.map(|v| ((u16::from(v) + 2 * 255) / 3) as u8);
        let pts: Vec<_> = logs.iter().map(|l| (l.iter as f64, l.psnr_db)).collect();
        cv.polyline(&pts, faint);
    }
    for (c, logs) in &series {
        let val: Vec<_> = logs
            .iter()
            .filter_map(|l| l.val_psnr_db.map(|v| (l.iter as f64, v)))
            .collect();
        cv.polyline(&val, *c);
        for &p in &val {
            cv.dot(p, 2.5, *c);
        }
    }
    cv.axes(
        "iteration",
        "PSNR (dB): training batch (light), held-out fabricated units (dots)",
    );
    // Legend.
    let names = std::iter::once("stage 1 (shared)").chain(branches.iter().map(|b| b.0.as_str()));
    for (k, (name, (c, _))) in names.zip(&series).enumerate() {
        let y = 80 + 16 * k as i32;
        cv.rect_px(732, y, 14, 8, *c, true);
        cv.text_px(752, y, name, 1, [0, 0, 0]);
    }
    // Bottom panel: log10 image loss.
    let yr = range(&mut all().map(|l| l.image_loss.max(1e-300).log10()));
    cv.set_view((80, 410, 640, 220), (0.0, n), yr, false);
    if split > 0 {
        cv.line((split as f64, yr.0), (split as f64, yr.1), [170, 170, 170]);
    }
    for (c, logs) in &series {
        let pts: Vec<_> = logs
            .iter()
            .map(|l| (l.iter as f64, l.image_loss.max(1e-300).log10()))
            .collect();
        cv.polyline(&pts, *c);
    }
    cv.axes("iteration", "log10 of the training batch's image loss");
    cv
}
