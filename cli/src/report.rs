//! Text shared by several commands: paraxial data, spot tables, Monte Carlo statistics, and
//! writing to stdout and files.

use std::path::Path;
use tolray::analysis::SpotResult;
use tolray::lens::Paraxial;
use tolray::tolerance::monte_carlo::Stats;
use tolray::tolerance::McReport;
use tolray::{Lens, Object};

/// The paraxial data and the prescription of `lens` (what `tolray info` prints).
pub fn paraxial_text(lens: &Lens, p: &Paraxial) -> String {
    let obj = match lens.object {
        Object::Infinite => "infinity".to_string(),
        Object::Finite { distance_mm } if distance_mm < 0.0 => format!(
            "{} mm behind the first vertex: a virtual object",
            -distance_mm
        ),
        Object::Finite { distance_mm } => format!("{distance_mm} mm"),
    };
    let medium = if lens.object_medium.is_air() {
        String::new()
    } else {
        format!(
            ", in {} (n = {:.6})",
            lens.object_medium.json_name(),
            lens.object_medium.index(p.wavelength_nm)
        )
    };
    let mut s = format!(
        "{}\n\nParaxial data at {:.4} nm (object at {obj}{medium})\n",
        lens.info, p.wavelength_nm
    );
    // None: an afocal lens' focal quantities (and its image of an object at infinity).
    let mut rows: Vec<(&str, Option<f64>, &str)> = vec![
        ("effective focal length (in air, 1/Φ)", p.efl_mm, "mm"),
        (
            "effective focal length (in image space, n'/Φ)",
            p.efl_image_space_mm,
            "mm",
        ),
        ("back focal distance", p.bfd_mm, "mm"),
        (
            "paraxial image distance (from last vertex)",
            p.image_distance_mm,
            "mm",
        ),
        (
            "prescribed image distance (from last vertex)",
            Some(lens.image_distance_mm()),
            "mm",
        ),
        (
            "entrance pupil position (z)",
            Some(p.entrance_pupil_z_mm),
            "mm",
        ),
        (
            "entrance pupil diameter",
            Some(p.entrance_pupil_diameter_mm),
            "mm",
        ),
        ("exit pupil position (z)", Some(p.exit_pupil_z_mm), "mm"),
        ("exit pupil diameter", Some(p.exit_pupil_diameter_mm), "mm"),
        ("F-number (infinity)", p.fnum, ""),
        ("working F-number", p.working_fnum, ""),
        ("paraxial magnification", Some(p.magnification), ""),
    ];
    // Only an afocal lens has an angular magnification.
    if let Some(m) = p.angular_magnification {
        rows.push(("angular magnification (afocal)", Some(m), ""));
    }
    rows.extend([
        ("half field of view (sensor)", p.half_fov_deg, "deg"),
        ("total track", Some(p.total_track_mm), "mm"),
    ]);
    for (name, v, unit) in rows {
        match v {
            Some(v) => s.push_str(&format!("  {name:<46} {v:>14.6} {unit}\n")),
            None => s.push_str(&format!("  {name:<46} {:>14}\n", "afocal")),
        }
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
        use tolray::lens::{Shape, SurfaceRole};
        let ty = match (sf.role, sf.is_stop, sf.is_aspheric()) {
            (SurfaceRole::Aperture, _, _) => "stop",
            (SurfaceRole::Mirror, _, _) => match sf.shape {
                Shape::Toroidal { .. } => "tor. mirror",
                Shape::Zernike { .. } => "Zern. mirr.",
                _ => "mirror",
            },
            _ if sf.phase.is_some() => "binary 2",
            (_, _, true) => match sf.shape {
                Shape::Odd => "odd asph.",
                Shape::Toroidal { c_rot: 0.0 } => "cylinder",
                Shape::Toroidal { .. } => "toroid",
                Shape::Paraxial { .. } => "thin lens",
                Shape::Qbfs { .. } | Shape::Qcon { .. } => "Q asphere",
                Shape::Zernike { .. } => "Zernike",
                Shape::Even => "asphere",
            },
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
        if let Shape::Paraxial { focal_mm } = sf.shape {
            s.push_str(&format!(
                "  {:>4} {:>10} ideal thin lens, focal length {focal_mm:.4} mm\n",
                "", ""
            ));
        }
        if let tolray::lens::Material::Gradient(g) = &sf.material {
            let terms = |c: &[f64], var: &str, step: usize| -> String {
                (c.iter().enumerate())
                    .filter(|(_, v)| **v != 0.0)
                    .map(|(j, v)| format!(" {v:+e} {var}^{}", step * (j + 1)))
                    .collect()
            };
            let lhs = match g.form {
                tolray::lens::GradientForm::Index => "n = n0",
                tolray::lens::GradientForm::IndexSquared => "n² = n0²",
            };
            s.push_str(&format!(
                "  {:>4} {:>10} gradient index after it ({}): {lhs}{}{}, n0 = {}, r and z in mm from this vertex; steps of {} mm\n",
                "",
                "",
                g.zemax_type(),
                terms(&g.radial, "r", 2),
                terms(&g.axial, "z", 1),
                g.n0,
                g.step_mm
            ));
        }
        if let Some(g) = sf.grating {
            s.push_str(&format!(
                "  {:>4} {:>10} grating: {} lines/µm (grooves along local x), order {}\n",
                "", "", g.lines_per_um, g.order
            ));
        }
        if sf.pos_xy_mm != [0.0, 0.0] {
            s.push_str(&format!(
                "  {:>4} {:>10} decentred ({:.6}, {:.6}) mm\n",
                "", "", sf.pos_xy_mm[0], sf.pos_xy_mm[1]
            ));
        }
        let [a, b, _] = sf.vec_local;
        if a != 0.0 || b != 0.0 {
            let n = sf.vec_local;
            let tilt = (n[2] / (a * a + b * b + n[2] * n[2]).sqrt())
                .acos()
                .to_degrees();
            s.push_str(&format!(
                "  {:>4} {:>10} tilted {tilt:.6} degrees: axis ({a:.8}, {b:.8}, {:.8})\n",
                "", "", n[2]
            ));
        }
        if let Some(f) = sf.fold {
            let [a, b, g] = f.tilt_deg;
            s.push_str(&format!(
                "  {:>4} {:>10} fold mirror: the axis after it turns by tilts ({a:.6}, {b:.6}, {g:.6}) degrees about x, y, z, {:.6} mm past the vertex (the prescription stays unfolded)\n",
                "", "", f.pivot_mm
            ));
        }
        if sf.roll_deg != 0.0 {
            s.push_str(&format!(
                "  {:>4} {:>10} rolled {:.6} degrees about its axis\n",
                "", "", sf.roll_deg
            ));
        }
        if let Some(norm_radius_mm) = sf.shape.norm_radius_mm() {
            let n = sf.asph.iter().rposition(|&a| a != 0.0).map_or(0, |j| j + 1);
            let terms: Vec<String> = sf.asph[..n].iter().map(|a| format!("{a:.6e}")).collect();
            s.push_str(&format!(
                "  {:>4} {:>10} {} on the conic above: normalization radius {norm_radius_mm:.4} mm, a_0.. = [{}] mm (paraxial radius {:.4} mm)\n",
                "",
                "",
                if matches!(sf.shape, Shape::Qbfs { .. }) { "Qbfs" } else { "Qcon" },
                terms.join(", "),
                1.0 / sf.paraxial_curvature()
            ));
        }
        if let Shape::Zernike {
            ordering,
            norm_radius_mm,
            decenter_mm,
            extrapolate,
        } = sf.shape
        {
            let nonzero = sf.zernike.iter().filter(|a| **a != 0.0).count();
            s.push_str(&format!(
                "  {:>4} {:>10} {nonzero} of {} Zernike {ordering:?} terms on the asphere above: normalization radius {norm_radius_mm:.4} mm, centred at ({}, {}) mm, {} (paraxial radius in y {:.4} mm)\n",
                "",
                "",
                sf.zernike.len(),
                decenter_mm[0],
                decenter_mm[1],
                if extrapolate { "extrapolated beyond it" } else { "0 beyond it" },
                1.0 / sf.paraxial_curvature()
            ));
        }
        if let Some(p) = &sf.phase {
            let terms: Vec<String> = p.coefficients.iter().map(|a| format!("{a:.6e}")).collect();
            s.push_str(&format!(
                "  {:>4} {:>10} diffractive phase (Binary 2) in order {}: normalization radius {:.4} mm, A_1.. = [{}] rad (paraxial focal length at {:.1} nm {})\n",
                "",
                "",
                p.order,
                p.norm_radius_mm,
                terms.join(", "),
                lens.primary_wavelength_nm,
                match p.power_per_mm(lens.primary_wavelength_nm) {
                    k if k != 0.0 => format!("{:.4} mm", 1.0 / k),
                    _ => "none".to_string(),
                }
            ));
        }
        if let Shape::Toroidal { c_rot } = sf.shape {
            let rr = if c_rot == 0.0 {
                "inf".to_string()
            } else {
                format!("{:.4}", 1.0 / c_rot)
            };
            s.push_str(&format!(
                "  {:>4} {:>10} radius in y above; radius of rotation (x) {rr} mm\n",
                "", ""
            ));
        }
    }
    let ip = &lens.image_plane;
    if ip.is_moved() {
        s.push_str(&format!(
            "  image plane: centre ({:.6}, {:.6}) mm from the axis, normal ({:.8}, {:.8}, {:.8}), roll {:.6} degrees (spots are in its own frame)\n",
            ip.decenter_mm[0], ip.decenter_mm[1], ip.normal[0], ip.normal[1], ip.normal[2], ip.roll_deg
        ));
    }
    if ip.is_curved() {
        s.push_str(&format!(
            "  image surface: curved, radius {:.6} mm, conic {} (spots are the x, y of each ray's crossing)\n",
            1.0 / ip.curvature_per_mm,
            ip.conic
        ));
    }
    if !lens.fields.is_empty() {
        s.push_str(&format!(
            "\nFields of the lens file (the commands' default fields; tolray's sign: {})\n  {:>5} {:>22} {:>7} {:>8} {:>8} {:>8} {:>8}\n",
            "a positive angle puts the object above the axis",
            "field", "value", "weight", "VDX", "VDY", "VCX", "VCY"
        ));
        for (k, f) in lens.fields.iter().enumerate() {
            let v = f.vignetting;
            s.push_str(&format!(
                "  {:>5} {:>22} {:>7.3} {:>8.4} {:>8.4} {:>8.4} {:>8.4}\n",
                k + 1,
                f.field.label(),
                f.weight,
                v.decenter_x,
                v.decenter_y,
                v.compress_x,
                v.compress_y
            ));
        }
    }
    for w in lens.warnings() {
        s.push_str(&format!("warning: {w}\n"));
    }
    s
}

/// One row per spot result: field, wavelength, rays, RMS and geometric radii, vignetting,
/// centroid.
pub fn spot_table(results: &[SpotResult]) -> String {
    // The field column fits its longest label (`12.000mm@real-image`).
    let w = results
        .iter()
        .map(|r| r.field.label().chars().count())
        .fold(14, usize::max);
    // Afocal image space: angles, µrad sizes and mrad centroids.
    let angular = results.iter().any(|r| r.angular);
    let (size, cx, cy) = if angular {
        ("µrad", "cx (mrad)", "cy (mrad)")
    } else {
        ("µm", "centroid x", "centroid y")
    };
    let mut s = format!(
        "{:>w$} {:>12} {:>8} {:>12} {:>12} {:>12} {:>10} {:>12} {:>12}\n",
        "field",
        "wavelength",
        "rays",
        format!("RMS ({size})"),
        "RMS/chief",
        format!("geo ({size})"),
        "vignetted",
        cx,
        cy
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
            "{:>w$} {:>12} {:>8} {:>12.4} {:>12} {:>12.4} {:>9.2}% {:>12.6} {:>12.6}\n",
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

pub use tolray::optim::train::fmt_list;

/// A row of statistics (mean, std, min, max, yields: the values 90/70/50/10 % of lenses stay
/// below, or reach when higher is better) named `name`. `width` is the name column's width
/// (the header's too).
pub fn stats_row(name: &str, s: &Stats, width: usize) -> String {
    let table = if s.yield_above.is_empty() {
        &s.yield_below
    } else {
        &s.yield_above
    };
    let y: Vec<String> = table.iter().map(|r| format!("{:.3}", r[1])).collect();
    format!(
        "{name:<width$} {:>10.3} {:>10.3} {:>10.3} {:>10.3}   {}\n",
        s.mean,
        s.std,
        s.min,
        s.max,
        y.join("  ")
    )
}

/// The text report of a Monte Carlo study (or of one shard of it).
pub fn tolerance_text(r: &McReport) -> String {
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
        if !o.compensate_focus {
            String::new()
        } else if o.criterion != Default::default() {
            format!(
                ", compensator: the focus of best {}",
                o.criterion.spelling()
            )
        } else {
            ", compensator: best focus".to_string()
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
    let names: Vec<String> = o
        .fields
        .iter()
        .map(|f| format!("field {}", f.label()))
        .collect();
    let w = names
        .iter()
        .map(|n| n.chars().count())
        .max()
        .unwrap_or(0)
        .max(14);
    s.push_str(&format!(
        "\n{:<w$} {:>10} {:>10} {:>10} {:>10}   yield: 90 % / 70 % / 50 % / 10 % of lenses have RMS below\n",
        "RMS spot (µm)", "mean", "std", "min", "max"
    ));
    for (name, st) in names.iter().zip(&sm.per_field) {
        s.push_str(&stats_row(name, st, w));
    }
    s.push_str(&stats_row("field mean", &sm.mean_over_fields, w));
    if let Some(c) = &sm.criterion {
        let better = if o.criterion.higher_is_better() {
            "at least"
        } else {
            "below"
        };
        s.push_str(&format!(
            "\n{:<w$} {:>10} {:>10} {:>10} {:>10}   yield: 90 % / 70 % / 50 % / 10 % of lenses have {better}\n",
            "criterion", "mean", "std", "min", "max"
        ));
        s.push_str(&format!(
            "({}; nominal per field: {})\n",
            c.label,
            r.nominal_criterion
                .as_deref()
                .map_or(String::new(), fmt_list)
        ));
        for (name, st) in names.iter().zip(&c.per_field) {
            s.push_str(&stats_row(name, st, w));
        }
        s.push_str(&stats_row("field mean", &c.mean_over_fields, w));
    }
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

/// Runs `f` with a progress bar of `n` steps on stderr. When stderr is not a terminal (a log
/// file, a batch job), progress is written as plain lines instead: at each tenth of the steps,
/// and at least every 30 s while steps complete, e.g. `cases: 3/31 (9 %), 45 s, ETA 7 min`.
pub fn with_progress<T>(n: u64, what: &str, f: impl FnOnce(&(dyn Fn() + Sync)) -> T) -> T {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        let log = ProgressLog::new(n, what);
        return f(&|| log.tick());
    }
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

/// Progress as log lines (see [`with_progress`]).
struct ProgressLog {
    n: u64,
    what: String,
    start: std::time::Instant,
    /// Steps done and when the last line was written (s since `start`).
    state: std::sync::Mutex<(u64, f64)>,
}

impl ProgressLog {
    fn new(n: u64, what: &str) -> ProgressLog {
        ProgressLog {
            n,
            what: what.to_string(),
            start: std::time::Instant::now(),
            state: std::sync::Mutex::new((0, 0.0)),
        }
    }

    fn tick(&self) {
        let Ok(mut st) = self.state.lock() else {
            return;
        };
        st.0 += 1;
        let (done, n) = (st.0, self.n.max(1));
        let now = self.start.elapsed().as_secs_f64();
        let tenth = done * 10 / n != (done - 1) * 10 / n;
        if tenth || now - st.1 >= 30.0 {
            st.1 = now;
            let eta = now / done as f64 * n.saturating_sub(done) as f64;
            eprintln!(
                "{}: {done}/{n} ({:.0} %), {}, ETA {}",
                self.what,
                100.0 * done as f64 / n as f64,
                duration(now),
                duration(eta)
            );
        }
    }
}

/// `45 s`, `7 min`, `2.5 h`.
fn duration(s: f64) -> String {
    if s < 90.0 {
        format!("{s:.0} s")
    } else if s < 5400.0 {
        format!("{:.0} min", s / 60.0)
    } else {
        format!("{:.1} h", s / 3600.0)
    }
}

/// Writes to stdout; a closed pipe (e.g. `| head`) ends the program quietly.
pub fn emit(s: &str) {
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

/// [`emit`] with a newline.
pub fn emit_line(s: &str) {
    emit(&format!("{s}\n"));
}

/// Writes `text` to `path` atomically (a temporary file and a rename).
pub fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    tolray::files::write_atomic(path, text.as_bytes())?;
    Ok(())
}
