//! Zemax .zmx files and AGF glass catalogs: hand-written fixtures give the same prescriptions,
//! paraxial data and spots as their JSON lenses (and reproduce the independent reference spots),
//! JSON -> .zmx -> JSON is exact, perturbed lenses survive coordinate breaks, every encoding
//! OpticStudio writes is read, errors and warnings name their lines, and mutation fuzzers find no
//! panic.

use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use tolray::analysis::{spot_diagram, SpotOptions};
use tolray::lens::agf::AgfCatalog;
use tolray::lens::material::{LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use tolray::lens::zemax::{self, ZmxFieldType, ZmxLens};
use tolray::lens::{json, Adjustments, GlassCatalogs, Material, System};
use tolray::math::Vec3;
use tolray::tolerance::Perturbation;
use tolray::trace::{trace, Field, Pupil, PupilPattern, RayBatch, TraceOptions};
use tolray::{ErrorKind, Lens, Object};

mod binary2;
mod catalogs;
mod corpus;
mod errors;
mod fields;
mod fuzz;
mod geometry;
mod surfaces;
mod tilted;
mod zernike;
#[allow(unused_imports)]
use catalogs::*;
#[allow(unused_imports)]
use corpus::*;
#[allow(unused_imports)]
use errors::*;
#[allow(unused_imports)]
use fields::*;
#[allow(unused_imports)]
use fuzz::*;
#[allow(unused_imports)]
use geometry::*;
#[allow(unused_imports)]
use surfaces::*;
#[allow(unused_imports)]
use tilted::*;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/zemax")
        .join(name)
}

fn text(name: &str) -> String {
    std::fs::read_to_string(fixture(name)).unwrap()
}

fn read(name: &str) -> ZmxLens {
    zemax::read_file(&fixture(name), &GlassCatalogs::builtin())
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn parse(text: &str) -> tolray::Result<ZmxLens> {
    zemax::from_str(text, &GlassCatalogs::builtin())
}

fn err(text: &str) -> String {
    match parse(text) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.message().to_string(),
    }
}

fn rel(a: f64, b: f64) -> f64 {
    if a == b {
        0.0
    } else {
        ((a - b) / b).abs()
    }
}

/// 1-based number of the first line of `text` that starts (after indentation) with `start`.
fn line_of(text: &str, start: &str) -> usize {
    text.lines()
        .position(|l| l.trim_start().starts_with(start))
        .unwrap_or_else(|| panic!("no line starts with {start}"))
        + 1
}

/// `text` with the first line starting with `start` replaced by `new` (indentation kept).
fn replace_line(text: &str, start: &str, new: &str) -> String {
    let n = line_of(text, start);
    text.lines()
        .enumerate()
        .map(|(i, l)| {
            if i + 1 == n {
                new.to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn assert_paraxial_equal(a: &Lens, b: &Lens, what: &str) {
    for wl in [
        LAMBDA_D_NM,
        LAMBDA_F_NM,
        LAMBDA_C_NM,
        a.primary_wavelength_nm,
    ] {
        let (p, q) = (a.paraxial(wl).unwrap(), b.paraxial(wl).unwrap());
        // Afocal on both sides or on neither.
        assert_eq!(
            (p.is_afocal(), p.image_distance_mm.is_none()),
            (q.is_afocal(), q.image_distance_mm.is_none()),
            "{what}"
        );
        let or0 = |v: Option<f64>| v.unwrap_or(0.0);
        for (name, x, y) in [
            ("EFL", or0(p.efl_mm), or0(q.efl_mm)),
            ("BFD", or0(p.bfd_mm), or0(q.bfd_mm)),
            (
                "image distance",
                or0(p.image_distance_mm),
                or0(q.image_distance_mm),
            ),
            ("EP z", p.entrance_pupil_z_mm, q.entrance_pupil_z_mm),
            (
                "EPD",
                p.entrance_pupil_diameter_mm,
                q.entrance_pupil_diameter_mm,
            ),
            ("XP z", p.exit_pupil_z_mm, q.exit_pupil_z_mm),
            ("XPD", p.exit_pupil_diameter_mm, q.exit_pupil_diameter_mm),
            ("F/#", or0(p.fnum), or0(q.fnum)),
            ("working F/#", or0(p.working_fnum), or0(q.working_fnum)),
            ("magnification", p.magnification, q.magnification),
            (
                "angular magnification",
                or0(p.angular_magnification),
                or0(q.angular_magnification),
            ),
            ("total track", p.total_track_mm, q.total_track_mm),
        ] {
            assert!(rel(x, y) <= 1e-9, "{what} {name} at {wl} nm: {x} vs {y}");
        }
        assert_eq!(p.stop_surface, q.stop_surface, "{what}");
    }
}

fn spots(l: &Lens, apertures: bool) -> Vec<(f64, usize)> {
    let opts = SpotOptions {
        fields: [0.0, 0.5, 0.7, 1.0].map(Field::fraction).to_vec(),
        wavelengths_nm: vec![LAMBDA_D_NM, LAMBDA_F_NM],
        pupil: Pupil::grid(32),
        trace: TraceOptions { apertures },
    };
    spot_diagram(l, &l.compile(), &opts)
        .unwrap()
        .iter()
        .map(|s| (s.stats.rms_um, s.stats.n_valid))
        .collect()
}

fn json_lens(name: &str) -> Lens {
    match name {
        "asphere" => json::read_file(&fixture("asphere.json")).unwrap(),
        n => Lens::load(n).unwrap(),
    }
}

const FIXTURES: [(&str, &str); 5] = [
    ("lens1.zmx", "lens1"),
    ("lens2.zmx", "lens2"),
    ("cooke-triplet.zmx", "cooke-triplet"),
    ("cooke-triplet-utf16.zmx", "cooke-triplet"),
    ("asphere.zmx", "asphere"),
];

#[test]
fn fixtures_match_their_json_lenses() {
    for (file, name) in FIXTURES {
        let z = read(file);
        assert!(z.warnings.is_empty(), "{file}: {:?}", z.warnings);
        let j = json_lens(name);
        // The prescription is the same to the bit: surfaces, object, sensor, stop.
        assert_eq!(z.lens.surfaces, j.surfaces, "{file}");
        assert_eq!(z.lens.object, j.object, "{file}");
        assert_eq!(z.lens.sensor, j.sensor, "{file}");
        assert_eq!(z.lens.info, j.info, "{file}");
        assert_eq!(
            z.lens.primary_wavelength_nm, j.primary_wavelength_nm,
            "{file}"
        );
        assert_paraxial_equal(&z.lens, &j, file);
        for apertures in [false, true] {
            let (a, b) = (spots(&z.lens, apertures), spots(&j, apertures));
            for ((ra, na), (rb, nb)) in a.iter().zip(&b) {
                assert_eq!(na, nb, "{file}: valid rays");
                assert!(rel(*ra, *rb) <= 1e-9, "{file}: RMS {ra} vs {rb}");
            }
        }
    }
    // Fields and wavelengths are kept.
    let z = read("lens1.zmx");
    assert_eq!(z.extras.field_type, ZmxFieldType::AngleDeg);
    assert_eq!(
        z.extras.fields.iter().map(|f| f.y).collect::<Vec<_>>(),
        [0.0, 2.99, 4.18, 5.97],
        "FTYP says 4 of the 12 field slots are used"
    );
    assert_eq!(z.extras.wavelengths.len(), 3, "FTYP says 3 wavelengths");
    assert_eq!(z.extras.primary, 1);
    assert_eq!(
        z.lens.rgb_wavelengths_nm,
        [0.6562725 * 1e3, 0.5875618 * 1e3, 0.4861327 * 1e3]
    );
    let z = read("lens2.zmx");
    assert_eq!(
        z.lens.surfaces.len(),
        11,
        "the dummy surface is not a lens surface"
    );
    assert_eq!(
        z.extras.fields.iter().map(|f| f.y).collect::<Vec<_>>(),
        [0.0, 5.0, 7.06]
    );
}

/// The reference RMS spots (optiland, ray-optics and DeepLens agree) from the .zmx fixtures.
#[test]
fn zmx_fixtures_reproduce_the_reference_spots() {
    let v: serde_json::Value =
        serde_json::from_str(include_str!("../data/reference_values.json")).unwrap();
    for (key, file) in [
        ("Triplet", "cooke-triplet-utf16.zmx"),
        ("Lens1@inf", "lens1.zmx"),
    ] {
        let mut l = read(file).lens;
        l.object = Object::Infinite;
        let r = &v["rms_spot_um"][key];
        let floats = |x: &serde_json::Value| -> Vec<f64> {
            x.as_array()
                .unwrap()
                .iter()
                .map(|y| y.as_f64().unwrap())
                .collect()
        };
        let angles = floats(&r["field_angles_deg"]);
        let want = floats(&r["A:nominal"]);
        let opts = SpotOptions {
            fields: angles.iter().map(|&a| Field::angle(a)).collect(),
            wavelengths_nm: vec![LAMBDA_D_NM],
            pupil: Pupil {
                pattern: PupilPattern::Grid(64),
                scale: 1.0,
                aim: false,
            },
            trace: TraceOptions { apertures: false },
        };
        let got = spot_diagram(&l, &l.compile(), &opts).unwrap();
        for (s, w) in got.iter().zip(&want) {
            assert!(
                rel(s.stats.rms_um, *w) <= 1e-6,
                "{key}: {} vs {w}",
                s.stats.rms_um
            );
        }
    }
}

fn variants() -> Vec<(String, Lens)> {
    let mut out: Vec<(String, Lens)> = tolray::lens::builtin_names()
        .into_iter()
        .map(|n| (n.to_string(), Lens::load(n).unwrap()))
        .collect();
    out.push(("asphere".into(), json_lens("asphere")));
    let mut l = Lens::load("lens2").unwrap();
    l.object = Object::Infinite;
    l.surfaces[0].k = -0.5;
    l.surfaces[0].asph[1] = 1.5e-6;
    l.surfaces[0].asph[7] = -3e-21;
    l.surfaces[2].material = Material::parse("N-SF5").unwrap();
    l.surfaces[5].material = Material::Constant(1.7);
    l.surfaces[9].material = Material::parse("J-BK7A").unwrap();
    l.rgb_wavelengths_nm = [620.0, 530.0, 460.0];
    l.primary_wavelength_nm = 530.0;
    l.sensor.resolution = [4000, 3000];
    out.push(("lens2 variant".into(), l));
    // Immersion: a catalog glass in object space, a finite object.
    let mut l = Lens::load("lens1").unwrap();
    l.object = Object::Finite { distance_mm: 80.0 };
    l.object_medium = Material::parse("N-BK7").unwrap();
    out.push(("lens1 immersed".into(), l));
    // A grating (rolled with its surface) and a rolled rectangular aperture.
    let mut l = Lens::load("lens1").unwrap();
    l.surfaces[2].grating = Some(tolray::lens::Grating {
        lines_per_um: 0.075,
        order: -2.0,
    });
    l.surfaces[2].roll_deg = 20.0;
    l.surfaces[4].aperture = Some(tolray::lens::Aperture {
        shape: tolray::lens::ApertureShape::Rectangular {
            half_x_mm: 3.0,
            half_y_mm: 2.0,
        },
        decenter_mm: [0.0; 2],
        obscuration: false,
    });
    l.surfaces[4].roll_deg = -75.0;
    out.push(("lens1 grating, rolls".into(), l));
    out
}

#[test]
fn json_zmx_json_round_trip_is_exact() {
    for (name, l) in variants() {
        let text = zemax::to_string(&l, None);
        let z = parse(&text).unwrap_or_else(|e| panic!("{name}: {e}\n{text}"));
        assert!(z.warnings.is_empty(), "{name}: {:?}", z.warnings);
        // A lens without fields is written with paraxial image heights at 0, 0.5, 0.7 and 1 of
        // the sensor's half-diagonal (OpticStudio needs fields): read back, they are its fields.
        let mut l = l;
        if l.fields.is_empty() {
            let r = l.sensor.half_diagonal_mm();
            l.fields = [0.0, 0.5, 0.7, 1.0]
                .map(|f| tolray::trace::FieldPoint {
                    field: Field::ImageHeightMm { x: 0.0, y: f * r },
                    weight: 1.0,
                    vignetting: Default::default(),
                })
                .to_vec();
        }
        assert_eq!(z.lens, l, "{name}");
        assert_eq!(json::to_string(&z.lens), json::to_string(&l), "{name}");
        // Writing what was read gives the same file.
        assert_eq!(zemax::to_string(&z.lens, Some(&z.extras)), text, "{name}");
    }
    // A fixture read, written and read again keeps its lens, fields and wavelengths.
    for (file, _) in FIXTURES {
        let z = read(file);
        let again = parse(&zemax::to_string(&z.lens, Some(&z.extras))).unwrap();
        assert_eq!(again.lens, z.lens, "{file}");
        assert_eq!(again.extras.fields, z.extras.fields, "{file}");
        assert_eq!(again.extras.field_type, z.extras.field_type, "{file}");
        let kind = |a: &Option<zemax::ZmxAperture>| a.as_ref().map(std::mem::discriminant);
        assert_eq!(
            kind(&again.extras.aperture),
            kind(&z.extras.aperture),
            "{file}"
        );
        for w in &z.extras.wavelengths {
            assert!(again.extras.wavelengths.contains(w), "{file}: {w:?}");
        }
    }
}

/// Rays from several directions and heights, traced through `sys`; `dz` moves the global frame
/// (positions come back in the unmoved frame).
fn trace_fan(sys: &System<f64>, dz: f64) -> Vec<(Vec3<f64>, Vec3<f64>, bool)> {
    let mut b = RayBatch::<f64>::new();
    for a in [-0.12, -0.05, 0.0, 0.03, 0.1] {
        for k in -6..=6 {
            for j in [-2.0, 0.0, 3.0] {
                b.push(
                    Vec3::new(j, k as f64 * 1.4, -20.0 - dz),
                    Vec3::new(0.02 * j, a, 1.0),
                );
            }
        }
    }
    tolray::trace::trace(sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
    b.iter()
        .map(|r| (r.o + Vec3::new(0.0, 0.0, dz), r.d, r.status.is_alive()))
        .collect()
}

fn assert_same_trace(a: &System<f64>, b: &System<f64>, tol: f64, what: &str) {
    assert_same_trace_shifted(a, b, 0.0, tol, what)
}

/// As [`assert_same_trace`], with `b`'s global frame `dz` mm behind `a`'s.
fn assert_same_trace_shifted(a: &System<f64>, b: &System<f64>, dz: f64, tol: f64, what: &str) {
    let (ra, rb) = (trace_fan(a, 0.0), trace_fan(b, dz));
    let mut alive = 0;
    for (i, (x, y)) in ra.iter().zip(&rb).enumerate() {
        assert_eq!(x.2, y.2, "{what}: ray {i} status");
        if x.2 {
            alive += 1;
            assert!(
                (x.0 - y.0).norm() <= tol,
                "{what}: ray {i} {:?} vs {:?}",
                x.0,
                y.0
            );
            assert!((x.1 - y.1).norm() <= tol, "{what}: ray {i} direction");
        }
    }
    assert!(alive > 30, "{what}: only {alive} rays reach the image");
}

fn geometry_close(a: &Lens, b: &Lens, what: &str) {
    assert_eq!(a.surfaces.len(), b.surfaces.len(), "{what}");
    for (i, (s, t)) in a.surfaces.iter().zip(&b.surfaces).enumerate() {
        assert_eq!(
            (
                s.role,
                s.c,
                s.k,
                s.asph,
                s.semi_aperture_mm,
                &s.material,
                s.is_stop
            ),
            (
                t.role,
                t.c,
                t.k,
                t.asph,
                t.semi_aperture_mm,
                &t.material,
                t.is_stop
            ),
            "{what}: surface {i}"
        );
        assert_eq!(s.d_next_mm, t.d_next_mm, "{what}: surface {i} gap");
        assert_eq!(s.pos_xy_mm, t.pos_xy_mm, "{what}: surface {i} decenter");
        for k in 0..3 {
            assert!(
                (s.vec_local[k] - t.vec_local[k]).abs() <= 1e-15,
                "{what}: surface {i} axis {:?} vs {:?}",
                s.vec_local,
                t.vec_local
            );
        }
    }
    assert_eq!((a.object, a.sensor), (b.object, b.sensor), "{what}");
}

/// A fabricated lens (element and surface decenters, tilts, shifts, curvature errors) becomes
/// surfaces with decenters and tilts, .zmx coordinate-break pairs, and back: zmx -> tolray ->
/// zmx -> tolray gives the same lens and the same rays.
#[test]
fn perturbed_lenses_round_trip_through_coordinate_breaks() {
    let lens = Lens::load("lens2").unwrap();
    let pattern: Perturbation = serde_json::from_str(
        r#"{"elements": [
              {"element": 0, "decenter_mm": [0.01, 0.04], "tilt_deg": [0.05, -0.03, 0.2], "shift_mm": 0.02},
              {"element": 2, "decenter_mm": [-0.03, 0.0], "tilt_deg": [0.0, 0.08, 0.0], "thickness_mm": -0.01}],
            "surfaces": [
              {"surface": 2, "curvature_pct": 0.3, "decenter_mm": [0.02, 0.0], "tilt_deg": [0.0, 0.04]},
              {"surface": 8, "gap_mm": 0.015}]}"#,
    )
    .unwrap();
    let (perturbed, mut adj) = pattern.apply(&lens).unwrap();
    // The image plane tilted and moved sideways too (a sensor's assembly error, set through the
    // library): the baked lens holds it as its image plane.
    adj.image_motion = tolray::math::Rigid {
        rotation: tolray::math::Mat3::from_tilt_deg(0.3, -0.2, 0.0),
        translation: adj.image_motion.translation + Vec3::new(0.05, -0.02, 0.0),
    };
    let baked = perturbed.with_adjustments(&adj).unwrap();
    assert!(!baked.image_plane.is_default());
    assert!(baked
        .surfaces
        .iter()
        .any(|s| s.vec_local[0] != 0.0 && s.pos_xy_mm[1] != 0.0));
    assert_eq!(
        baked.surfaces[9].d_next_mm, lens.surfaces[9].d_next_mm,
        "untouched gaps stay exact (the image gap moves with the tilted image plane's centre)"
    );
    // The element's axial shift moves the first vertex: the baked lens keeps it at z = 0 and
    // moves away from the object instead.
    let Object::Finite { distance_mm } = baked.object else {
        panic!()
    };
    assert!((distance_mm - 2000.02).abs() < 1e-12, "{distance_mm}");
    // The baked prescription traces exactly like the nominal lens with the adjustments.
    let moved: System<f64> = System::compile(&perturbed, &adj, &|_, v| v);
    assert_same_trace_shifted(&moved, &baked.compile(), 0.02, 1e-9, "baked");

    let text1 = zemax::to_string(&baked, None);
    let moved_surfaces = baked
        .surfaces
        .iter()
        .filter(|s| s.pos_xy_mm != [0.0; 2] || s.vec_local[..2] != [0.0; 2])
        .count();
    assert_eq!(moved_surfaces, 5, "element 0, surface 2 and element 2");
    assert_eq!(
        text1.matches("TYPE COORDBRK").count(),
        2 * moved_surfaces + 1,
        "a pair per moved surface, one before the image"
    );
    let z1 = parse(&text1).unwrap();
    assert!(z1.warnings.is_empty(), "{:?}", z1.warnings);
    geometry_close(&z1.lens, &baked, "zmx -> tolray");
    assert_same_trace(&z1.lens.compile(), &baked.compile(), 1e-12, "read back");
    let z2 = parse(&zemax::to_string(&z1.lens, Some(&z1.extras))).unwrap();
    geometry_close(&z2.lens, &z1.lens, "zmx -> tolray -> zmx -> tolray");
    assert_same_trace(
        &z2.lens.compile(),
        &z1.lens.compile(),
        1e-12,
        "second round",
    );
    // And through JSON (pos_xy, vec_local) exactly.
    assert_eq!(json::from_str(&json::to_string(&z2.lens)).unwrap(), z2.lens);
    // A lens without adjustments is unchanged by baking.
    assert_eq!(lens.with_adjustments(&Adjustments::none(11)).unwrap(), lens);
    // A pattern that moves the image plane behind the last surface cannot be baked: the moved
    // system's rays end there going backward, a prescription with that gap would image
    // virtually (found by the fuzzer's baked-pattern check, `examples/fuzz.rs`).
    let behind: Perturbation =
        serde_json::from_str(r#"{"surfaces": [{"surface": 10, "gap_mm": -100}]}"#).unwrap();
    let (perturbed, adj) = behind.apply(&lens).unwrap();
    let err = perturbed.with_adjustments(&adj).unwrap_err();
    assert!(
        err.message()
            .contains("move the image plane to the other side of surface 10"),
        "{}",
        err.message()
    );
}

/// OpticStudio's own way to tilt an element (Tilt/Decenter Elements): a coordinate break at the
/// element's front vertex, the element, a dummy surface back to the vertex, the reverse break,
/// and a dummy for the rest of the gap. It must equal tolray's rigid element tilt about the front
/// vertex.
#[test]
fn opticstudio_element_tilt_equals_tolray_element_tilt() {
    let zmx = "MODE SEQ\nUNIT MM\nENPD 8\nWAVM 1 0.5875618 1\nPWAV 1\n\
        SURF 0\n DISZ INFINITY\n\
        SURF 1\n STOP\n TYPE STANDARD\n CURV 0\n DISZ 5\n DIAM 4 1\n\
        SURF 2\n TYPE COORDBRK\n DISZ 0\n PARM 1 -0.05\n PARM 2 0.1\n PARM 3 0.5\n PARM 4 -0.3\n PARM 5 0\n PARM 6 0\n\
        SURF 3\n TYPE STANDARD\n CURV 0.05\n DISZ 4\n GLAS N-BK7\n DIAM 8\n\
        SURF 4\n TYPE STANDARD\n CURV -0.01\n DISZ 0\n DIAM 8\n\
        SURF 5\n TYPE STANDARD\n CURV 0\n DISZ -4\n\
        SURF 6\n TYPE COORDBRK\n DISZ 0\n PARM 1 0.05\n PARM 2 -0.1\n PARM 3 -0.5\n PARM 4 0.3\n PARM 5 0\n PARM 6 1\n\
        SURF 7\n TYPE STANDARD\n CURV 0\n DISZ 44\n\
        SURF 8\n TYPE STANDARD\n CURV 0\n DIAM 5\n";
    let z = parse(zmx).unwrap();
    assert_eq!(
        z.lens.surfaces.len(),
        3,
        "the two dummies are construction surfaces"
    );
    let mut nominal = z.lens.clone();
    for s in &mut nominal.surfaces {
        s.pos_xy_mm = [0.0, 0.0];
        s.vec_local = [0.0, 0.0, 1.0];
    }
    nominal.surfaces[1].d_next_mm = 4.0;
    nominal.surfaces[2].d_next_mm = 40.0;
    // OpticStudio's order 0 (decenter, then tilt x then y about the moved axes) is
    // R = Rx Ry; tolray's element tilt is R = Rz Ry Rx, so compare against an explicit motion.
    let r = tolray::math::Mat3::rot_x(0.5f64.to_radians())
        * tolray::math::Mat3::rot_y((-0.3f64).to_radians());
    let m =
        tolray::math::Rigid::about_pivot(r, Vec3::new(0.0, 0.0, 5.0), Vec3::new(-0.05, 0.1, 0.0));
    let mut adj = Adjustments::none(3);
    adj.surface_motion[1] = m;
    adj.surface_motion[2] = m;
    let moved: System<f64> = System::compile(&nominal, &adj, &|_, v| v);
    assert_same_trace(&z.lens.compile(), &moved, 1e-11, "element tilt");
    // A pure x tilt is the tolerance model's element tilt exactly.
    let tilted = zmx
        .replace("PARM 4 -0.3", "PARM 4 0")
        .replace("PARM 4 0.3", "PARM 4 0");
    let z = parse(&tilted).unwrap();
    let pattern: Perturbation = serde_json::from_str(
        r#"{"elements": [{"element": 0, "decenter_mm": [-0.05, 0.1], "tilt_deg": [0.5, 0, 0]}]}"#,
    )
    .unwrap();
    let (p, adj) = pattern.apply(&nominal).unwrap();
    assert_same_trace(
        &z.lens.compile(),
        &System::compile(&p, &adj, &|_, v| v),
        1e-11,
        "pattern",
    );
}

/// The aspheric lens written in CM, IN and METER reads back to the same lens in mm.
#[test]
fn lens_units_are_converted_to_mm() {
    let base = text("asphere.zmx");
    let mm = read("asphere.zmx").lens;
    for (unit, s) in [("CM", 10.0), ("IN", 25.4), ("METER", 1000.0)] {
        let scaled: Vec<String> = base
            .lines()
            .map(|l| {
                let t: Vec<&str> = l.split_whitespace().collect();
                let num = |i: usize| t[i].parse::<f64>().unwrap();
                match t.first().copied() {
                    Some("UNIT") => format!("UNIT {unit} X W X CM MR CPMM"),
                    Some("ENPD") => format!("ENPD {:e}", num(1) / s),
                    Some("CURV") => format!("CURV {:e}", num(1) * s),
                    Some("DISZ") if t[1] != "INFINITY" => format!("DISZ {:e}", num(1) / s),
                    Some("DIAM") => format!("DIAM {:e} 0", num(1) / s),
                    Some("PARM") => {
                        let k = num(1) as i32;
                        format!("PARM {k} {:e}", num(2) * s.powi(2 * k - 1))
                    }
                    _ => l.to_string(),
                }
            })
            .collect();
        let l = parse(&scaled.join("\n")).unwrap().lens;
        for (a, b) in l.surfaces.iter().zip(&mm.surfaces) {
            for (x, y) in [
                (a.c, b.c),
                (a.semi_aperture_mm, b.semi_aperture_mm),
                (a.d_next_mm, b.d_next_mm),
            ]
            .into_iter()
            .chain(a.asph.iter().copied().zip(b.asph.iter().copied()))
            {
                assert!(rel(x, y) <= 1e-14, "{unit}: {x} vs {y}");
            }
        }
        assert!(rel(l.sensor.r_mm, mm.sensor.r_mm) <= 1e-14, "{unit}");
        let (p, q) = (
            l.paraxial(LAMBDA_D_NM).unwrap(),
            mm.paraxial(LAMBDA_D_NM).unwrap(),
        );
        assert!(
            rel(p.efl_mm.unwrap(), q.efl_mm.unwrap()) <= 1e-12
                && rel(p.bfd_mm.unwrap(), q.bfd_mm.unwrap()) <= 1e-12,
            "{unit}"
        );
    }
}

#[test]
fn every_encoding_reads_the_same_lens() {
    let ascii = text("cooke-triplet.zmx");
    let want = read("cooke-triplet.zmx").lens;
    let le: Vec<u8> = ascii.encode_utf16().flat_map(u16::to_le_bytes).collect();
    let be: Vec<u8> = ascii.encode_utf16().flat_map(u16::to_be_bytes).collect();
    let cases: Vec<(&str, Vec<u8>)> = vec![
        (
            "UTF-16 LE with BOM (fixture)",
            std::fs::read(fixture("cooke-triplet-utf16.zmx")).unwrap(),
        ),
        ("UTF-16 LE without BOM", le.clone()),
        (
            "UTF-16 BE with BOM",
            [vec![0xFE, 0xFF], be.clone()].concat(),
        ),
        ("UTF-16 BE without BOM", be),
        (
            "UTF-8 with BOM",
            [vec![0xEF, 0xBB, 0xBF], ascii.clone().into_bytes()].concat(),
        ),
        ("LF line ends", ascii.replace("\r\n", "\n").into_bytes()),
    ];
    for (what, bytes) in cases {
        let z = zemax::from_bytes(&bytes, &GlassCatalogs::builtin()).unwrap();
        assert_eq!(z.lens, want, "{what}");
    }
    // Lens::load dispatches on the extension, in any case.
    let dir = std::env::temp_dir().join(format!("tolray-zmx-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let upper = dir.join("TRIPLET.ZMX");
    std::fs::copy(fixture("cooke-triplet-utf16.zmx"), &upper).unwrap();
    assert_eq!(Lens::load(upper.to_str().unwrap()).unwrap(), want);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A stop between two media refracts like a flat interface, and `convert` keeps the optics
/// (defect 8: lens2 with the stop's medium set to 1.5/60 had EFL 29.21 mm as JSON and 38.19 mm
/// after .zmx).
#[test]
fn a_stop_between_two_media_refracts() {
    use tolray::lens::SurfaceRole;
    let mut l = Lens::load("lens2").unwrap();
    let stop = l.stop_index().unwrap();
    l.surfaces[stop].material = Material::Model { nd: 1.5, vd: 60.0 };
    l.surfaces[stop].d_next_mm = 3.8 * 1.5; // keep the glass path comparable
    let efl = l.paraxial(l.primary_wavelength_nm).unwrap().efl_mm.unwrap();
    // The same lens with the stop replaced by a flat refracting surface of that glass.
    let mut flat = l.clone();
    flat.surfaces[stop].role = SurfaceRole::Refractive;
    let efl_flat = flat
        .paraxial(flat.primary_wavelength_nm)
        .unwrap()
        .efl_mm
        .unwrap();
    assert!(
        (efl - efl_flat).abs() < 1e-12 * efl.abs(),
        "{efl} vs {efl_flat}"
    );
    // Real rays agree too.
    let (a, b) = (l.compile(), flat.compile());
    let mut ra = tolray::trace::RayBatch::<f64>::new();
    ra.push(Vec3::new(0.0, 3.0, -5.0), Vec3::new(0.0, 0.01, 1.0));
    let mut rb = ra.clone();
    let opts = tolray::trace::TraceOptions::default();
    tolray::trace::trace(&a, 587.5618, &mut ra, opts);
    tolray::trace::trace(&b, 587.5618, &mut rb, opts);
    assert!((ra.get(0).o.y - rb.get(0).o.y).abs() < 1e-12);
    // The .zmx round trip gives the same first-order optics.
    let z = parse(&zemax::to_string(&l, None)).unwrap();
    let efl_z = z
        .lens
        .paraxial(z.lens.primary_wavelength_nm)
        .unwrap()
        .efl_mm
        .unwrap();
    assert!(
        (efl - efl_z).abs() < 1e-9 * efl.abs(),
        "JSON {efl} vs .zmx {efl_z}"
    );
}

/// Both readers accept the same wavelengths (0.1 µm to 10 mm, exclusive), so `convert` never
/// writes a file that tolray then refuses (the JSON reader used to stop at 10 µm, the .zmx one at
/// 20). Beyond 20 µm only media defined there are traced: a lens of constant indices opens at
/// 3 mm, the same lens in N-BK7 or in a dispersive model glass is refused naming the medium.
#[test]
fn json_and_zmx_readers_accept_the_same_wavelengths() {
    let mut base = Lens::load("lens1").unwrap();
    for s in &mut base.surfaces {
        if s.material != Material::Air {
            s.material = Material::Constant(1.525); // HDPE at millimetre waves
        }
    }
    for (um, ok) in [
        (0.1, false),
        (0.1001, true),
        (12.0, true),
        (20.0, true),
        (3000.0, true),
        (9999.0, true),
        (10000.0, false),
    ] {
        let mut v: serde_json::Value = serde_json::from_str(&json::to_string(&base)).unwrap();
        v["primary_wvln"] = serde_json::json!(um);
        let from_json = json::from_str(&v.to_string());
        assert_eq!(from_json.is_ok(), ok, "JSON at {um} µm: {from_json:?}");
        let zmx = zemax::to_string(&base, None);
        let text = replace_line(&zmx, "WAVM 1 ", &format!("WAVM 1 {um} 1"));
        let from_zmx = parse(&text);
        assert_eq!(from_zmx.is_ok(), ok, "zmx at {um} µm: {:?}", from_zmx.err());
        if let (Ok(a), Ok(b)) = (from_json, from_zmx) {
            // And what one reads, the other writes and reads back.
            assert_eq!(
                json::from_str(&json::to_string(&b.lens))
                    .unwrap()
                    .primary_wavelength_nm,
                b.lens.primary_wavelength_nm
            );
            assert!(parse(&zemax::to_string(&a, None)).is_ok(), "{um} µm");
        }
    }
    // Beyond 20 µm, a glass fitted to 2.5 µm and a model glass fitted to the visible have no
    // index: refused naming the WAVM line and the medium (the same catches `WAVM 1 587.56`).
    for (glass, says) in [
        ("N-BK7", "N-BK7, defined from 0.3 to 2.5 µm"),
        ("1.5168/64.17", "a law fitted to the visible"),
    ] {
        let mut l = base.clone();
        let first_glass = l.surfaces.iter().position(|s| s.material != Material::Air);
        l.surfaces[first_glass.unwrap()].material = Material::parse(glass).unwrap();
        let text = zemax::to_string(&l, None);
        let at_3mm = replace_line(&text, "WAVM 1 ", "WAVM 1 3000 1");
        let e = err(&at_3mm);
        let line = line_of(&at_3mm, "WAVM 1 ");
        for want in [
            format!("line {line}: "),
            says.to_string(),
            "micrometres".into(),
        ] {
            assert!(e.contains(&want), "missing {want:?}: {e}");
        }
        assert!(parse(&text).is_ok(), "{glass} at its own wavelength");
        let mut v: serde_json::Value = serde_json::from_str(&json::to_string(&l)).unwrap();
        v["primary_wvln"] = serde_json::json!(3000.0);
        let e = json::from_str(&v.to_string()).unwrap_err();
        assert!(e.message().contains(says), "{}", e.message());
    }
    // A millimetre-wave singlet: its focal length at 3 mm is the thick-lens closed form.
    let mut v: serde_json::Value = serde_json::from_str(&json::to_string(&base)).unwrap();
    v["primary_wvln"] = serde_json::json!(3000.0);
    let l = json::from_str(&v.to_string()).unwrap();
    let p = l.paraxial(3.0e6).unwrap();
    let p_d = l.paraxial(LAMBDA_D_NM).unwrap();
    assert_eq!(
        p.efl_mm, p_d.efl_mm,
        "constant indices: the same lens at every wavelength"
    );
}

/// A lens with no marked stop is written with STOP on the surface tolray's paraxial model takes
/// as the stop (the one limiting the axial beam), so the read-back keeps its pupils (it used to
/// be written without STOP and read back with the first surface as the stop).
#[test]
fn a_lens_without_a_marked_stop_keeps_its_stop_through_zmx() {
    let mut l = Lens::load("lens2").unwrap();
    for s in &mut l.surfaces {
        s.is_stop = false;
    }
    let p = l.paraxial(l.primary_wavelength_nm).unwrap();
    assert_ne!(
        p.stop_surface, 0,
        "the test needs a stop other than the first surface"
    );
    let z = parse(&zemax::to_string(&l, None)).unwrap();
    assert_eq!(z.lens.stop_index(), Some(p.stop_surface));
    let q = z.lens.paraxial(l.primary_wavelength_nm).unwrap();
    assert_eq!(q.stop_surface, p.stop_surface);
    assert!(rel(q.entrance_pupil_diameter_mm, p.entrance_pupil_diameter_mm) < 1e-12);
    assert!(rel(q.entrance_pupil_z_mm, p.entrance_pupil_z_mm) < 1e-12);
}
