//! Diffractive phase surfaces (OpticStudio BINARY_2): optiland's rays at three wavelengths,
//! the optical path against Hamilton's characteristic function, a diffractive lens whose
//! wavefront is flat, the paraxial power, errors and round trips.

use super::*;
use tolray::lens::phase::RadialPhase;
use tolray::lens::Surface;

fn binary2() -> Lens {
    zemax::read_file(&fixture("binary2.zmx"), &GlassCatalogs::builtin())
        .unwrap()
        .lens
}

/// A hand-made singlet with a Binary 2 front (a conic with an r⁴ term; three phase terms in
/// first order, normalization radius 10 mm) traces every ray as optiland 0.6.3's phase
/// interaction does with the file's numbers (tests/data/zemax/binary2_reference.json,
/// scripts/zmxref/binary2_reference.py; 147 rays in three directions at the F, d and C lines,
/// where only the phase disperses: the index is constant): image positions to 1e-9 mm,
/// directions to 1e-11. The phase survives .zmx and JSON.
#[test]
fn binary_2_traces_as_optiland_ray_by_ray() {
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("binary2_reference.json")).unwrap())
            .unwrap();
    let z = zemax::read_file(&fixture("binary2.zmx"), &GlassCatalogs::builtin()).unwrap();
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    let lens = &z.lens;
    let front = &lens.surfaces[1];
    assert_eq!(
        front.phase,
        Some(RadialPhase {
            order: 1.0,
            norm_radius_mm: 10.0,
            coefficients: vec![-1133.35, 341.92, -25.0]
        })
    );
    assert_eq!((front.c, front.k, front.asph[1]), (0.04, -0.5, -2e-5));
    let mut spread = 0.0f64;
    let mut first: Option<Vec3<f64>> = None;
    for (wl, rays) in doc["wavelengths"].as_object().unwrap() {
        let wl: f64 = wl.parse().unwrap();
        let rays = rays.as_array().unwrap();
        let (worst, b) = worst_against(lens, wl, rays, "binary2.zmx");
        assert!(
            worst.0 < 1e-9 && worst.1 < 1e-11,
            "{wl} nm: worst position {:e} mm, direction {:e}",
            worst.0,
            worst.1
        );
        let last = b.get(rays.len() - 1).o;
        spread = spread.max(first.map_or(0.0, |f| (f - last).norm()));
        first.get_or_insert(last);
    }
    // The phase's dispersion is what the comparison sees: the marginal ray moves by 0.07 mm
    // from the F to the C line through a constant index.
    assert!(spread > 0.05, "{spread}");
    let back = parse(&zemax::to_string(lens, None)).unwrap().lens;
    let j = json::from_str(&json::to_string(lens)).unwrap();
    for other in [&back, &j] {
        assert_eq!(other.surfaces[1].phase, front.phase);
        assert_eq!(other.surfaces[1].asph, front.asph);
    }
}

/// The path a phase adds (λ Φ / 2π) is the one its bending implies: for rays leaving a plane
/// wavefront (collimated, from one plane), the optical path to a plane is Hamilton's point
/// characteristic, whose derivative along the plane is n' times the ray's direction cosine. On
/// the singlet with its image plane moved 10 mm behind the lens (so that the image heights
/// spread), central differences of the path over neighbouring rays' heights give the direction
/// cosine to 1e-7, at three wavelengths; the phase's path with the opposite sign is off by
/// over 1e-3.
#[test]
fn binary_2_path_is_hamiltons_characteristic() {
    let mut lens = binary2();
    let last = lens.surfaces.len() - 1;
    lens.surfaces[last].d_next_mm = 10.0;
    let sys = lens.compile();
    for wl in [LAMBDA_F_NM, LAMBDA_D_NM, LAMBDA_C_NM] {
        let dy = 1e-4;
        let ys: Vec<f64> = (-30..=30).map(|k| k as f64 * 0.1).collect();
        let mut b = RayBatch::<f64>::new();
        for &y in &ys {
            for s in [-dy, 0.0, dy] {
                b.push(Vec3::cst(0.0, y + s, -1.0), Vec3::cst(0.0, 0.0, 1.0));
            }
        }
        trace(&sys, wl, &mut b, TraceOptions { apertures: false });
        // The phase's path at each ray's crossing of the front (the reference tracer's point
        // there), to see what the opposite sign would give.
        let n = sys.indices(wl);
        let phase_path = |i: usize| {
            let start = Vec3::cst(0.0, ys[i / 3] + [-dy, 0.0, dy][i % 3], -1.0);
            let r = tolray::trace::reference::trace_ray(
                &sys,
                &n,
                wl,
                start,
                Vec3::cst(0.0, 0.0, 1.0),
                false,
                Some(1),
            );
            let (phi, _, _) = sys.rows[1].phase.as_ref().unwrap().eval(r.o.x, r.o.y);
            wl * 1e-6 * phi / std::f64::consts::TAU
        };
        let (mut worst, mut flipped) = (0.0f64, 0.0f64);
        for k in 0..ys.len() {
            let (m, c, p) = (b.get(3 * k), b.get(3 * k + 1), b.get(3 * k + 2));
            assert!(m.status.is_alive() && c.status.is_alive() && p.status.is_alive());
            let slope = (p.opl - m.opl) / (p.o.y - m.o.y);
            worst = worst.max((slope - c.d.y).abs());
            let (pm, pp) = (phase_path(3 * k), phase_path(3 * k + 2));
            let wrong = ((p.opl - 2.0 * pp) - (m.opl - 2.0 * pm)) / (p.o.y - m.o.y);
            flipped = flipped.max((wrong - c.d.y).abs());
        }
        assert!(
            worst < 1e-7,
            "{wl} nm: dOPL/dy off the direction cosine by {worst:e}"
        );
        assert!(
            flipped > 1e-3,
            "{wl} nm: the opposite sign is off by only {flipped:e}"
        );
    }
}

/// A diffractive lens from its closed form: a flat phase plate in air whose phase is the
/// series of an ideal lens of focal length f at λ0, Φ = −(2π/λ0)(√(r² + f²) − f) to r⁸
/// (the truncation below 1e-9 waves at the rim), with the image plane at f: its paraxial focal
/// length is f, the axial wavefront is flat to 1e-6 waves RMS at λ0, and at another wavelength
/// the paraxial focal length scales as λ0/λ (the phase is the same in radians).
#[test]
fn a_diffractive_lens_focuses_as_its_closed_form() {
    let (f, r, l0): (f64, f64, f64) = (100.0, 5.0, LAMBDA_D_NM);
    let k = std::f64::consts::TAU / (l0 * 1e-6);
    // √(r² + f²) − f = r²/(2f) − r⁴/(8f³) + r⁶/(16f⁵) − 5 r⁸/(128 f⁷).
    let series = [
        1.0 / (2.0 * f),
        -1.0 / (8.0 * f.powi(3)),
        1.0 / (16.0 * f.powi(5)),
        -5.0 / (128.0 * f.powi(7)),
    ];
    let coefficients: Vec<f64> = (0..4)
        .map(|i| -k * series[i] * r.powi(2 * (i as i32 + 1)))
        .collect();
    let mut lens = binary2();
    let mut plate = Surface::sphere(0.0, r, f, Material::Air);
    plate.is_stop = true;
    plate.phase = Some(RadialPhase {
        order: 1.0,
        norm_radius_mm: r,
        coefficients,
    });
    lens.surfaces = vec![plate];
    lens.object = Object::Infinite;
    lens.validate().unwrap();
    let p = lens.paraxial(l0).unwrap();
    assert!(
        (p.efl_mm.unwrap() - f).abs() < 1e-9,
        "EFL {}",
        p.efl_mm.unwrap()
    );
    let w = tolray::wave::wavefront(
        &lens,
        &lens.compile(),
        Field::angle(0.0),
        l0,
        &tolray::wave::WaveOptions::default(),
    )
    .unwrap();
    let rms = w.stats(15).unwrap().rms_to_chief_waves;
    assert!(rms < 1e-6, "RMS {rms} waves");
    let pc = lens.paraxial(LAMBDA_C_NM).unwrap().efl_mm.unwrap();
    assert!((pc - f * l0 / LAMBDA_C_NM).abs() < 1e-9, "EFL at C {pc}");
}

/// The paraxial power of the phase (−M λ A_1 / (π R²)) is the real rays' limit: on the singlet,
/// a collimated ray 1e-3 mm off the axis leaves at the paraxial EFL's slope at three
/// wavelengths (to 1e-7); without the phase's power the EFL differs by over 1 mm.
#[test]
fn binary_2_paraxial_power_is_the_real_rays_limit() {
    let lens = binary2();
    for wl in [LAMBDA_F_NM, LAMBDA_D_NM, LAMBDA_C_NM] {
        let efl = lens.paraxial(wl).unwrap().efl_mm.unwrap();
        let h = 1e-3;
        let mut b = RayBatch::<f64>::new();
        b.push(Vec3::cst(0.0, h, -1.0), Vec3::cst(0.0, 0.0, 1.0));
        trace(
            &lens.compile(),
            wl,
            &mut b,
            TraceOptions { apertures: false },
        );
        let r = b.get(0);
        let real = -h / (r.d.y / r.d.z);
        assert!(
            (real - efl).abs() < 1e-7 * efl,
            "{wl} nm: real {real} vs paraxial {efl}"
        );
        let mut plain = lens.clone();
        plain.surfaces[1].phase = None;
        let other = plain.paraxial(wl).unwrap().efl_mm.unwrap();
        assert!((other - efl).abs() > 1.0, "{wl} nm: {other} vs {efl}");
    }
}

/// What the reader and the lens check refuse or warn about, naming the line or surface.
#[test]
fn binary_2_errors_name_the_line() {
    let text = std::fs::read_to_string(fixture("binary2.zmx")).unwrap();
    for (from, to, want) in [
        (
            "XDAT 1 3 0 0 1 0 0 \"\"",
            "XDAT 1 241 0 0 1 0 0 \"\"",
            "XDAT 1 = 241: the number of phase terms must be a whole number from 0 to 240",
        ),
        (
            "XDAT 2 10 0 0 1 0 0 \"\"",
            "XDAT 2 0 0 0 1 0 0 \"\"",
            "XDAT 2 = 0: the phase terms need a positive normalization radius",
        ),
    ] {
        assert!(text.contains(from), "{from}");
        let e = parse(&text.replacen(from, to, 1)).unwrap_err();
        assert!(
            e.to_string().contains(want) && e.to_string().contains("line "),
            "{e}"
        );
    }
    let z = parse(&text.replacen("  PARM 0 1\n", "", 1)).unwrap();
    assert!(
        z.warnings
            .iter()
            .any(|w| w.contains("no diffraction order (PARM 0)")),
        "{:?}",
        z.warnings
    );
    assert_eq!(z.lens.surfaces[1].phase.as_ref().unwrap().order, 0.0);
    let mut lens = binary2();
    lens.surfaces[1].shape = tolray::lens::Shape::Odd;
    let e = lens.validate().unwrap_err().to_string();
    assert!(
        e.contains("surface 1: a diffractive phase sits on an even asphere"),
        "{e}"
    );
    let mut lens = binary2();
    lens.surfaces[1].phase.as_mut().unwrap().order = f64::NAN;
    let e = lens.validate().unwrap_err().to_string();
    assert!(e.contains("diffraction order NaN"), "{e}");
}

/// A real OpticStudio design: the short-course sample `sc_diffract2.zmx` (a BK7 singlet whose
/// Binary 2 front achromatizes it; its numbers in tests/data/zemax/sc-diffract2.zmx, the glass
/// read as N-BK7) matches OpticStudio's own figures: the EFL its F/2 solve on the back radius
/// (`CURV ... 11 2`, at EPD 20 mm) fixes, 40 mm, to 1e-9; and the semi-diameters OpticStudio
/// computed from its marginal rays at the three wavelengths, 8.923065012065 mm on the back
/// surface and 0.04693575984866 mm on the image, to 1e-10 mm (tolray's marginal rays at the
/// pupil's rim, the largest over F, d and C).
#[test]
fn opticstudios_diffractive_achromat_keeps_its_numbers() {
    let lens = zemax::read_file(&fixture("sc-diffract2.zmx"), &GlassCatalogs::builtin())
        .unwrap()
        .lens;
    let efl = lens.paraxial(LAMBDA_D_NM).unwrap().efl_mm.unwrap();
    assert!((efl - 40.0).abs() < 1e-9, "EFL {efl}");
    let sys = lens.compile();
    let (mut back, mut image) = (0.0f64, 0.0f64);
    for wl in [LAMBDA_F_NM, LAMBDA_D_NM, LAMBDA_C_NM] {
        let n = sys.indices(wl);
        let start = Vec3::cst(0.0, 10.0, -1.0);
        let d = Vec3::cst(0.0, 0.0, 1.0);
        let at = |upto| tolray::trace::reference::trace_ray(&sys, &n, wl, start, d, true, upto);
        back = back.max(at(Some(1)).o.y.abs());
        let r = at(None);
        assert!(r.status.is_alive());
        image = image.max(r.o.y.abs());
    }
    assert!((back - 8.923065012065).abs() < 1e-10, "back surface {back}");
    assert!((image - 4.693575984866e-2).abs() < 1e-10, "image {image}");
}
