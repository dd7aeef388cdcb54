//! Tolerances: the perturbed reference spots through tolerance patterns, the sampler's
//! distributions and reproducibility, the compensator, sensitivity, and shard merging.

use serde_json::{json, Value};
use tolray::analysis::{spot_diagram, SpotOptions};
use tolray::lens::material::{LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use tolray::lens::System;
use tolray::tolerance::spec::{Distribution, Operand, OperandKind};
use tolray::tolerance::*;
use tolray::trace::{Field, Pupil, PupilPattern, TraceOptions};
use tolray::{Lens, Object};

fn values() -> Value {
    serde_json::from_str(include_str!("../data/reference_values.json")).unwrap()
}

/// The reference perturbations, written as tolerance patterns (files users could write).
fn reference_pattern(name: &str) -> Perturbation {
    let v = match name {
        "decenter_y" => json!({"elements": [{"element": 0, "decenter_mm": [0.0, 0.04]}]}),
        "tilt_x" => json!({"elements": [{"element": 0, "tilt_deg": [0.05, 0.0, 0.0]}]}),
        "thickness_e1" => json!({"elements": [{"element": 0, "thickness_mm": 0.04}]}),
        "curvature_s1" => json!({"surfaces": [{"surface": 0, "curvature_pct": 0.3}]}),
        _ => json!({}),
    };
    serde_json::from_value(v).unwrap()
}

#[test]
fn perturbed_reference_spots_through_patterns() {
    let v = values();
    for (key, name) in [("Lens1@inf", "lens1"), ("Triplet", "cooke-triplet")] {
        let mut lens = Lens::load(name).unwrap();
        lens.object = Object::Infinite;
        let r = &v["rms_spot_um"][key];
        let angles: Vec<f64> = r["field_angles_deg"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let opts = SpotOptions {
            fields: angles.iter().map(|&a| Field::angle(a)).collect(),
            wavelengths_nm: vec![LAMBDA_D_NM],
            pupil: Pupil::grid(64),
            trace: TraceOptions { apertures: false },
        };
        for pert in ["decenter_y", "tilt_x", "thickness_e1", "curvature_s1"] {
            let (plens, adj) = reference_pattern(pert).apply(&lens).unwrap();
            let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
            let got = spot_diagram(&lens, &sys, &opts).unwrap();
            let want = r[format!("A:{pert}")].as_array().unwrap();
            let counts = r["n_valid_rays"][format!("A:{pert}")].as_array().unwrap();
            for (k, g) in got.iter().enumerate() {
                let w = want[k].as_f64().unwrap();
                assert_eq!(g.stats.n_valid as u64, counts[k].as_u64().unwrap());
                let rel = ((g.stats.rms_um - w) / w).abs();
                assert!(
                    rel < 1e-6,
                    "{key} {pert} field {k}: {} vs {w} ({rel:e})",
                    g.stats.rms_um
                );
            }
        }
    }
}

#[test]
fn elements_are_found_from_the_prescription() {
    let l = Lens::load("lens1").unwrap();
    let e: Vec<(usize, usize)> = find_elements(&l)
        .iter()
        .map(|e| (e.first, e.last))
        .collect();
    assert_eq!(e, [(0, 1), (2, 3), (5, 6)]);
    // A cemented doublet is one element.
    let mut c = l.clone();
    c.surfaces[1].material = tolray::lens::Material::parse("F2").unwrap();
    c.surfaces[1].d_next_mm = 2.0;
    let e: Vec<(usize, usize)> = find_elements(&c)
        .iter()
        .map(|e| (e.first, e.last))
        .collect();
    assert_eq!(
        e,
        [(0, 3), (5, 6)],
        "glass on both sides of surface 1 and 2 joins them"
    );
}

#[test]
fn glass_errors_shift_nd_and_vd_exactly() {
    let l = Lens::load("lens1").unwrap();
    let p: Perturbation =
        serde_json::from_value(json!({"elements": [{"element": 1, "index": 0.001, "abbe": -0.5}]}))
            .unwrap();
    let (pl, _) = p.apply(&l).unwrap();
    let m = &pl.surfaces[2].material;
    let nd = m.index(LAMBDA_D_NM);
    let vd = (nd - 1.0) / (m.index(LAMBDA_F_NM) - m.index(LAMBDA_C_NM));
    assert!((nd - 1.62104).abs() < 1e-12);
    assert!((vd - 35.876491).abs() < 1e-9);
    assert_eq!(
        l.surfaces[2].material,
        Lens::load("lens1").unwrap().surfaces[2].material,
        "nominal untouched"
    );
}

fn one_operand(kind: OperandKind, max: f64, dist: Distribution) -> ToleranceSpec {
    ToleranceSpec {
        distribution: dist,
        pivot: Pivot::Front,
        operands: vec![Operand {
            kind,
            max,
            distribution: None,
            elements: Some(vec![0]),
            surfaces: None,
        }],
    }
}

#[test]
fn sampler_moments_clamping_and_reproducibility() {
    let l = Lens::load("lens1").unwrap();
    let sigma2 = (0.04f64 / 3.0).powi(2);
    // Variance of N(0, s²) clamped at 3s, truncated at 3s, and of U(-max, max).
    for (dist, var) in [
        (Distribution::Normal, 0.995_01 * sigma2),
        (Distribution::TruncatedNormal, 0.973_34 * sigma2),
        (Distribution::Uniform, 0.04f64.powi(2) / 3.0),
    ] {
        let spec = one_operand(OperandKind::Shift, 0.04, dist);
        let xs: Vec<f64> = (0..100_000)
            .map(|k| spec.sample(&l, 11, k).unwrap().elements[0].shift_mm)
            .collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let v = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(
            xs.iter().all(|x| x.abs() <= 0.04),
            "{dist:?} exceeds the range"
        );
        assert!(
            mean.abs() < 4.0 * (var / xs.len() as f64).sqrt(),
            "{dist:?} mean {mean}"
        );
        assert!(
            (v / var - 1.0).abs() < 0.015,
            "{dist:?} variance {v} vs {var}"
        );
        if dist == Distribution::Normal {
            let at_limit = xs.iter().filter(|x| x.abs() == 0.04).count() as f64 / xs.len() as f64;
            assert!((at_limit - 0.0027).abs() < 0.001, "clamped mass {at_limit}");
        }
    }
    let spec = ToleranceSpec::default();
    assert_eq!(
        spec.sample(&l, 7, 3).unwrap(),
        spec.sample(&l, 7, 3).unwrap()
    );
    assert_ne!(
        spec.sample(&l, 7, 3).unwrap(),
        spec.sample(&l, 7, 4).unwrap()
    );
    assert_ne!(
        spec.sample(&l, 7, 3).unwrap(),
        spec.sample(&l, 8, 3).unwrap()
    );
    // Every element gets decenter (x, y), tilt (x, y, z) and shift; every curved surface curvature.
    let p = spec.sample(&l, 7, 0).unwrap();
    assert_eq!(p.elements.len(), 3);
    assert_eq!(p.surfaces.len(), 6);
    assert!(p
        .elements
        .iter()
        .all(|e| e.tilt_deg[2] != 0.0 && e.decenter_mm[1] != 0.0));
}

#[test]
fn bad_specs_and_patterns_are_clear_errors() {
    let l = Lens::load("lens1").unwrap();
    let e =
        serde_json::from_str::<ToleranceSpec>(r#"{"operands": [{"type": "wobble", "max": 1}]}"#)
            .unwrap_err();
    assert!(e.to_string().contains("unknown variant `wobble`"), "{e}");
    let spec: ToleranceSpec = serde_json::from_str(
        r#"{"operands": [{"type": "decenter", "max": 0.1, "elements": [5]}]}"#,
    )
    .unwrap();
    assert!(spec
        .validate(&l)
        .unwrap_err()
        .message()
        .contains("element 5 is out of range"));
    // A negative range is refused where the spec is read (it used to pass until sampling).
    let e =
        serde_json::from_str::<ToleranceSpec>(r#"{"operands": [{"type": "tilt", "max": -0.1}]}"#)
            .unwrap_err();
    assert!(
        e.to_string()
            .contains("range max -0.1 must be a finite number >= 0"),
        "{e}"
    );
    let mut spec = ToleranceSpec::default();
    spec.operands[0].max = f64::NAN;
    assert!(spec
        .validate(&l)
        .unwrap_err()
        .message()
        .contains("non-negative"));
    let p: Perturbation =
        serde_json::from_str(r#"{"surfaces": [{"surface": 9, "curvature_pct": 1}]}"#).unwrap();
    assert!(p
        .apply(&l)
        .unwrap_err()
        .message()
        .contains("surface 9 is out of range"));
    assert!(serde_json::from_str::<Perturbation>(
        r#"{"elements": [{"element": 0, "decentre": [0, 1]}]}"#
    )
    .is_err());
    // Issue 41: an Abbe offset of 1.8e19 was accepted, left a dispersion that rounds to
    // nothing, and was written to a .zmx file as "V_d inf" that tolray then refused to read.
    for (field, value) in [("abbe", 1.8e19), ("index", 2.0), ("abbe", -1001.0)] {
        let p: Perturbation = serde_json::from_str(&format!(
            r#"{{"elements": [{{"element": 1, "{field}": {value}}}]}}"#
        ))
        .unwrap();
        let m = p.validate(&l).unwrap_err().message().to_string();
        assert!(m.contains("element 1") && m.contains("out of range"), "{m}");
    }
    let spec: ToleranceSpec =
        serde_json::from_str(r#"{"operands": [{"type": "abbe", "max": 5000}]}"#).unwrap();
    let m = spec.validate(&l).unwrap_err().message().to_string();
    assert!(m.contains("beyond the ±1000"), "{m}");
    // The largest accepted Abbe offset still writes a glass that reads back.
    let p: Perturbation =
        serde_json::from_str(r#"{"elements": [{"element": 1, "abbe": 1000}]}"#).unwrap();
    let (bent, _) = p.apply(&l).unwrap();
    let zmx = tolray::lens::zemax::to_string(&bent, None);
    let back = tolray::lens::zemax::from_str(&zmx, &tolray::lens::GlassCatalogs::builtin())
        .unwrap_or_else(|e| panic!("{}\n{zmx}", e.message()));
    let json = tolray::lens::json::from_str(&tolray::lens::json::to_string(&bent)).unwrap();
    // (A perturbed glass is written as a model glass: the same n_d and n_F - n_C.)
    let (d, f, c) = (587.5618, 486.1327, 656.2725);
    for m in [&back.lens, &json] {
        for (a, b) in m.surfaces.iter().zip(&bent.surfaces) {
            let (a, b) = (&a.material, &b.material);
            assert!((a.index(d) - b.index(d)).abs() < 1e-9);
            let disp = |m: &tolray::lens::Material| m.index(f) - m.index(c);
            assert!((disp(a) - disp(b)).abs() < 1e-9);
        }
    }
}

fn mc_options(trials: usize, compensate: bool) -> McOptions {
    McOptions {
        spec: ToleranceSpec::default(),
        trials,
        seed: 7,
        fields: [0.0, 0.7, 1.0].map(Field::fraction).to_vec(),
        wavelengths_nm: vec![LAMBDA_D_NM],
        pupil: Pupil {
            pattern: PupilPattern::Grid(16),
            scale: 1.0,
            aim: false,
        },
        compensate_focus: compensate,
        apertures: true,
        criterion: Default::default(),
    }
}

#[test]
fn shards_merge_into_exactly_the_single_run() {
    let l = Lens::load("lens2").unwrap();
    let opts = mc_options(40, true);
    let single = monte_carlo(&l, "lens2", &opts, None, &|| {}).unwrap();
    let parts: Vec<McReport> = (0..3)
        .map(|k| monte_carlo(&l, "lens2", &opts, Some((k, 3)), &|| {}).unwrap())
        .collect();
    assert!(parts.iter().all(|p| p.summary.is_none()));
    // Through JSON, as shard files would travel.
    let parts: Vec<McReport> = parts
        .iter()
        .map(|p| serde_json::from_str(&serde_json::to_string(p).unwrap()).unwrap())
        .collect();
    let merged = merge_reports(&[parts[2].clone(), parts[0].clone(), parts[1].clone()]).unwrap();
    assert!(
        serde_json::to_string(&merged).unwrap() == serde_json::to_string(&single).unwrap(),
        "merged shards differ from the single run"
    );
    assert!(merge_reports(&parts[..2])
        .unwrap_err()
        .message()
        .contains("missing"));
    assert!(merge_reports(&[
        parts[0].clone(),
        parts[0].clone(),
        parts[1].clone(),
        parts[2].clone()
    ])
    .unwrap_err()
    .message()
    .contains("twice"));
}

#[test]
fn monte_carlo_is_thread_count_independent_and_yield_is_ordered() {
    let l = Lens::load("lens1").unwrap();
    let opts = mc_options(24, false);
    let run = |t| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| monte_carlo(&l, "lens1", &opts, None, &|| {}).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert!(
        serde_json::to_string(&a).unwrap() == serde_json::to_string(&b).unwrap(),
        "1 and 2 threads differ"
    );
    let s = a.summary.unwrap().mean_over_fields;
    // "90 % of lenses below X" is the 90th percentile: the largest of the four.
    let y: Vec<f64> = s.yield_below.iter().map(|r| r[1]).collect();
    assert!(
        y[0] >= y[1] && y[1] >= y[2] && y[2] >= y[3] && s.max >= y[0] && y[3] >= s.min,
        "{y:?}"
    );
    // Trial k re-traces from its stored pattern.
    let t = &a.trials[5];
    let (rms, _) = tolray::tolerance::monte_carlo::perturbed_rms(&l, &opts, &t.pattern).unwrap();
    assert_eq!(rms, t.rms_um);
}

#[test]
fn focus_compensator_finds_the_traced_best_focus() {
    // lens1 at 1000 mm: the prescribed sensor sits near the infinity focus, ~2.8 mm short.
    let l = Lens::load("lens1").unwrap();
    let opts = mc_options(1, true);
    let (rms, shift) =
        tolray::tolerance::monte_carlo::perturbed_rms(&l, &opts, &Perturbation::default()).unwrap();
    let shift = shift.unwrap();
    assert!(shift > 2.0 && shift < 3.5, "refocus {shift} mm");
    // Trace with the image plane really moved there, and a little either side.
    let moved = |dz: f64| {
        let p: Perturbation =
            serde_json::from_value(json!({"surfaces": [{"surface": 6, "gap_mm": dz}]})).unwrap();
        tolray::tolerance::monte_carlo::perturbed_rms(&l, &mc_options(1, false), &p)
            .unwrap()
            .0
    };
    let at = moved(shift);
    for (a, b) in at.iter().zip(&rms) {
        assert!((a - b).abs() < 1e-9 * b, "closed form {b} vs traced {a}");
    }
    let ms = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    assert!(ms(&at) < ms(&moved(shift + 0.01)) && ms(&at) < ms(&moved(shift - 0.01)));
    let (nominal, _) = tolray::tolerance::monte_carlo::perturbed_rms(
        &l,
        &mc_options(1, false),
        &Perturbation::default(),
    )
    .unwrap();
    assert!(
        rms[0] < 0.2 * nominal[0],
        "refocus removes most of the defocus blur"
    );
}

#[test]
fn sensitivity_is_sorted_and_symmetric_operands_agree() {
    let l = Lens::load("lens1").unwrap();
    let (nominal, rows) = sensitivity(&l, &mc_options(1, false)).unwrap();
    assert_eq!(rows.len(), 3 * (2 + 3 + 1) + 6);
    assert!(rows
        .windows(2)
        .all(|w| w[0].worst_delta_um >= w[1].worst_delta_um));
    // On axis, decentering +x or -x is the same by symmetry.
    let dx = rows
        .iter()
        .find(|r| r.operand == OperandKind::Decenter && r.target == 0 && r.axis == 0)
        .unwrap();
    assert!((dx.rms_minus_um[0] - dx.rms_plus_um[0]).abs() < 1e-9);
    assert!(dx.rms_plus_um[0] != nominal.rms_um[0]);
}
