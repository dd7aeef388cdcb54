//! Reproduces the independent reference values (optiland / ray-optics / DeepLens) in
//! tests/data/reference_values.json with the fast f64 kernel, to 1e-6 relative or better.

use serde_json::Value;
use tolray::analysis::{spot_diagram, SpotOptions};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::trace::{Field, Pupil, PupilPattern, TraceOptions};
use tolray::{Lens, Object};

fn values() -> Value {
    serde_json::from_str(include_str!("../data/reference_values.json")).unwrap()
}

fn lens(name: &str) -> Lens {
    Lens::load(name).unwrap()
}

fn assert_rel(got: f64, want: f64, tol: f64, what: &str) {
    let rel = ((got - want) / want).abs();
    assert!(
        rel <= tol,
        "{what}: got {got}, want {want}, relative error {rel:e}"
    );
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[test]
fn first_order_data() {
    let v = values();
    for (key, name) in [
        ("Lens1", "lens1"),
        ("Lens2", "lens2"),
        ("Triplet", "cooke-triplet"),
    ] {
        let mut l = lens(name);
        let r = &v["first_order"][key];
        if key == "Triplet" {
            l.object = Object::Infinite;
        }
        let p = l.paraxial(LAMBDA_D_NM).unwrap();
        assert_rel(
            p.efl_mm.unwrap(),
            r["efl_mm"].as_f64().unwrap(),
            1e-9,
            &format!("{key} EFL"),
        );
        assert_rel(
            p.bfd_mm.unwrap(),
            r["bfd_mm"].as_f64().unwrap(),
            1e-9,
            &format!("{key} BFD"),
        );
        assert_rel(
            p.entrance_pupil_z_mm,
            r["enp_z_mm"].as_f64().unwrap(),
            1e-9,
            &format!("{key} EP z"),
        );
        assert_rel(
            p.entrance_pupil_diameter_mm,
            r["enp_diameter_mm"].as_f64().unwrap(),
            1e-9,
            &format!("{key} EPD"),
        );
        if let Some(d) = r.get("paraxial_image_distance_mm_for_stated_object") {
            assert_rel(
                p.image_distance_mm.unwrap(),
                d.as_f64().unwrap(),
                1e-9,
                &format!("{key} image distance"),
            );
        }
    }
}

/// Traces one reference case: `mode` "A" (no apertures, 64 grid) or "B" (apertures, 96 grid over 1.5 R).
fn rms_case(l: &Lens, angles_deg: &[f64], mode: &str) -> Vec<(f64, usize)> {
    let (pupil, apertures) = match mode {
        "A" => (
            Pupil {
                pattern: PupilPattern::Grid(64),
                scale: 1.0,
                aim: false,
            },
            false,
        ),
        _ => (
            Pupil {
                pattern: PupilPattern::Grid(96),
                scale: 1.5,
                aim: false,
            },
            true,
        ),
    };
    let opts = SpotOptions {
        fields: angles_deg.iter().map(|&a| Field::angle(a)).collect(),
        wavelengths_nm: vec![LAMBDA_D_NM],
        pupil,
        trace: TraceOptions { apertures },
    };
    let sys = l.compile();
    spot_diagram(l, &sys, &opts)
        .unwrap()
        .iter()
        .map(|s| (s.stats.rms_um, s.stats.n_valid))
        .collect()
}

#[test]
fn nominal_rms_spots() {
    let v = values();
    for (key, name) in [("Lens1@inf", "lens1"), ("Triplet", "cooke-triplet")] {
        let mut l = lens(name);
        l.object = Object::Infinite;
        let r = &v["rms_spot_um"][key];
        let angles = floats(&r["field_angles_deg"]);
        for mode in ["A", "B"] {
            let Some(want) = r.get(format!("{mode}:nominal")) else {
                continue;
            };
            let want = floats(want);
            let counts = floats(&r["n_valid_rays"][format!("{mode}:nominal")]);
            let got = rms_case(&l, &angles, mode);
            for (k, ((rms, n), (w, c))) in got.iter().zip(want.iter().zip(&counts)).enumerate() {
                assert_eq!(*n as f64, *c, "{key} {mode} field {k}: valid ray count");
                assert_rel(*rms, *w, 1e-6, &format!("{key} {mode} field {k} RMS"));
            }
        }
    }
}

use tolray::lens::{Adjustments, Material, Surface, System};
use tolray::math::{Mat3, Rigid, Vec3};

#[test]
fn tilted_plate_sign_check() {
    let v = values();
    let want = v["plate_tilt_check"]["y_mm"].as_f64().unwrap();
    let mut l = lens("lens1");
    l.surfaces = vec![
        Surface::sphere(0.0, 10.0, 10.0, Material::Constant(1.5)),
        Surface::sphere(0.0, 10.0, 20.0, Material::Air),
    ];
    let mut adj = Adjustments::none(2);
    let r = Mat3::from_tilt_deg(1.0, 0.0, 0.0);
    adj.surface_motion[0] =
        Rigid::about_pivot(r, Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 0.0));
    adj.surface_motion[1] =
        Rigid::about_pivot(r, Vec3::new(0.0, 0.0, 10.0), Vec3::new(0.0, 0.0, 0.0));
    let sys: System<f64> = System::compile(&l, &adj, &|_, v| v);
    let mut b = tolray::trace::RayBatch::<f64>::new();
    b.push(Vec3::new(0.0, 0.0, -5.0), Vec3::new(0.0, 0.0, 1.0));
    tolray::trace::trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
    let ray = b.get(0);
    assert!(ray.status.is_alive());
    assert!(
        (ray.o.y - want).abs() < 1e-12,
        "plate shift {} vs {want}",
        ray.o.y
    );
}
