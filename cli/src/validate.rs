//! `tolray validate`: the cross-check of the analytic tracer against Intel Embree 4.

use crate::args::{LensArgs, RaySampleArgs};
use anyhow::bail;
use clap::Args;
use std::path::PathBuf;
#[cfg(feature = "embree")]
use {
    crate::report::{emit, with_progress, write_text},
    crate::usage,
    tolray::tolerance::ToleranceSpec,
};

/// Arguments of `tolray validate`.
#[derive(Args)]
pub struct ValidateArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Use Intel Embree 4 as the reference engine (the only one so far).
    #[arg(long, required = true)]
    pub embree: bool,
    /// Monte Carlo tolerance patterns after the nominal lens.
    #[arg(long, default_value_t = 100)]
    pub trials: usize,
    /// Seed; trial k is pattern k of this seed (as in `tolray tolerance`).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Tolerance spec (JSON); default: the paper's Table A1.
    #[arg(long, value_name = "SPEC.json")]
    pub tolerance_spec: Option<PathBuf>,
    /// Write the full report (every case, surface and field) as JSON.
    #[arg(long, value_name = "FILE.json")]
    pub json: Option<PathBuf>,
    /// Chord bound of the tessellation, mm: no mesh point is farther than this from its surface.
    #[arg(long, default_value_t = 1e-4, value_name = "MM")]
    pub chord: f64,
    #[command(flatten)]
    pub rays: RaySampleArgs,
    /// Frame of the meshes: each surface's own (small f32 coordinates) or the global frame.
    #[arg(long, default_value = "local", value_parser = ["local", "global"])]
    pub frame: String,
    /// Assert hits and meshes within this multiple of the chord bound instead of the bound
    /// itself (values below 1 assert more than the theorem guarantees).
    #[arg(long, default_value_t = 1.0)]
    pub bound_scale: f64,
    /// Largest allowed RMS spot difference between the traces, µm.
    #[arg(long, default_value_t = 0.1, value_name = "UM")]
    pub spot_bound_um: f64,
    /// What each surface's mesh covers: the triangles the traced rays can meet (footprint: the
    /// same hits, a fraction of the scene builds) or the whole disk.
    #[arg(long, default_value = "footprint", value_parser = ["footprint", "disk"])]
    pub mesh_cover: String,
}

/// Runs `tolray validate`: without the `embree` feature, an error saying how to rebuild.
#[cfg(not(feature = "embree"))]
pub fn run(_args: ValidateArgs) -> anyhow::Result<()> {
    bail!(
        "`validate --embree` needs tolray built with the `embree` feature; rebuild with \
         `cargo build --release --features embree` (or `cargo run --release --features embree \
         -- validate ...`). The feature needs libclang (apt-get install libclang1-14 \
         libclang-common-14-dev); its build finds Intel Embree 4 or fetches it from PyPI."
    )
}

/// Runs `tolray validate`.
#[cfg(feature = "embree")]
pub fn run(args: ValidateArgs) -> anyhow::Result<()> {
    let (lens, args) = (&args.lens, &args);
    use tolray_embree::{validate, CheckOptions, Cover, Device, Frame, ValidateOptions};
    let (l, file_fields) = lens.load_with_fields()?;
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
    let (fields, wavelengths_nm, pupil) = args.rays.parse(&l, args.seed, file_fields)?;
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
            cover: if args.mesh_cover == "disk" {
                Cover::Disk
            } else {
                Cover::Footprint
            },
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
fn validate_text(r: &tolray_embree::ValidationReport) -> String {
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
            tolray_embree::Frame::Local => "local",
            tolray_embree::Frame::Global => "global",
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
            "{:>4} {:>15} {:>9} {:>10.3e} {:>10.3e} {:>10.3e} {:>10.3e} {:>9.3} {:>9.1e} {:>6}{}",
            x.surface,
            format!("{:.2}/{:.2}", x.disk_mm, x.semi_aperture_mm),
            x.triangles,
            x.chord_bound_mm,
            x.mesh_deviation_mm,
            x.max_hit_distance_mm,
            x.rms_hit_distance_mm,
            x.max_bound_ratio,
            x.max_f32_error_mm,
            x.leaks + x.uncovered,
            if x.sharp { "" } else { " *" }
        );
    }
    let blunt: Vec<String> = s
        .surfaces
        .iter()
        .filter(|x| !x.sharp)
        .map(|x| x.surface.to_string())
        .collect();
    if !blunt.is_empty() {
        let _ = writeln!(
            t,
            "* not sharp on surface{} {}: Embree's f32 rounding allowance (up to {:.1e} mm) is more \
             than {:.0} % of the chord bound there (or the surface is flat, bound 0), so a deviation \
             somewhat beyond the bound can pass; a larger --chord, or a smaller surface, makes it \
             sharp",
            if blunt.len() > 1 { "s" } else { "" },
            blunt.join(", "),
            s.surfaces
                .iter()
                .filter(|x| !x.sharp)
                .map(|x| x.max_f32_allowance_mm)
                .fold(0.0, f64::max),
            100.0 * tolray_embree::check::SHARP_FRACTION
        );
    }
    let _ = writeln!(
        t,
        "\nRMS spots, nominal lens (µm), and the worst difference over all cases:"
    );
    let nf = r.cases[0].fields.len();
    // The field column fits its longest label (`12.000mm@real-image`).
    let w = r.cases[0]
        .fields
        .iter()
        .map(|f| f.field.label().chars().count())
        .fold(8, usize::max);
    let _ = writeln!(
        t,
        "{:>w$} {:>8} {:>11} {:>11} {:>10} {:>12} {:>12} {:>12}",
        "field", "nm", "analytic", "embree", "diff", "worst diff", "worst point", "mesh-normal"
    );
    for f in 0..nf {
        let n = &r.cases[0].fields[f];
        let worst = |g: &dyn Fn(&tolray_embree::FieldCheck) -> f64| {
            r.cases.iter().map(|c| g(&c.fields[f])).fold(0.0, f64::max)
        };
        let _ = writeln!(
            t,
            "{:>w$} {:>8.2} {:>11.4} {:>11.4} {:>10.2e} {:>12.2e} {:>12.2e} {:>12.2e}",
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
         trace only: crossing an aperture rim on different sides, or a leak or unmatched hit \
         (per surface in --json).)",
        s.rays_compared, s.status_mismatches
    );
    let tm = &s.timing;
    let [e, k, rf] = s.median_mrs_per_s;
    let _ = writeln!(
        t,
        "\nthroughput, one thread, the same rays (median over cases of {} ray-surfaces each; every \
         scene is traced right after its build):\n  Embree trace      {:>8.2} M ray-surfaces/s  (intersection + refraction)\n  analytic kernel   {:>8.2} M ray-surfaces/s  (f64)\n  scalar reference  {:>8.2} M ray-surfaces/s  (f64)\n  scene builds: {:.2} s for {:.1} M triangles ({:.1} M triangles/s; {})",
        tm.ray_surfaces / s.cases.max(1) as u64,
        e,
        k,
        rf,
        tm.build_s,
        tm.triangles as f64 * 1e-6,
        tm.triangles as f64 * 1e-6 / tm.build_s,
        if tm.disk_triangles > tm.triangles {
            format!(
                "the rays' footprints, {:.1} % of the whole disks' {:.1} M",
                100.0 * tm.triangles as f64 / tm.disk_triangles as f64,
                tm.disk_triangles as f64 * 1e-6
            )
        } else {
            "whole disks".to_string()
        }
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
