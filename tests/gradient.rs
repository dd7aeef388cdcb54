//! Exact dual-number gradients against central finite differences, for every variable kind, on
//! lens1, lens2, the Cooke triplet, an aspheric lens and a two-mirror telescope, nominal and
//! perturbed.

use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{Adjustments, Material, Param, Surface};
use tolray::optim::{
    gradient, param_value, set_param, value, Bundles, Objective, SpotLoss, SpotMeasure,
};
use tolray::tolerance::ToleranceSpec;
use tolray::trace::{Field, Pupil, TraceOptions};
use tolray::{Lens, Object};

/// Every design variable of a lens: curvatures of refracting surfaces, every gap (the last is
/// the image distance), conics, and the asphere terms in use.
fn all_vars(lens: &Lens) -> Vec<Param> {
    let mut v = Vec::new();
    for (i, s) in lens.surfaces.iter().enumerate() {
        if s.role != tolray::lens::SurfaceRole::Aperture {
            v.push(Param::Curvature(i));
            if s.k != 0.0 || s.is_aspheric() {
                v.push(Param::Conic(i));
            }
            for j in 0..8 {
                if s.asph[j] != 0.0 {
                    v.push(Param::Asphere(i, j));
                }
            }
        }
        v.push(Param::Gap(i));
        if matches!(s.material, Material::Model { .. }) {
            v.push(Param::GlassNd(i));
            v.push(Param::GlassVd(i));
        }
    }
    v
}

fn asphere_lens() -> Lens {
    let mut l = Lens::load("lens1").unwrap();
    let mut s0 = Surface::sphere(1.0 / 30.0, 8.0, 5.0, Material::parse("N-BK7").unwrap());
    s0.k = -0.8;
    s0.asph = [1e-4, 2e-5, -3e-8, 1e-10, 0.0, 0.0, 0.0, 0.0];
    let mut s1 = Surface::sphere(-1.0 / 60.0, 8.0, 50.0, Material::Air);
    s1.k = 1.5;
    l.surfaces = vec![s0, s1];
    l.object = Object::Infinite;
    l
}

/// Fourth-order central difference (error O(h⁴)).
fn central_diff<O: Objective>(obj: &O, lens: &Lens, adj: &Adjustments, p: Param, h: f64) -> f64 {
    let x0 = param_value(lens, p).unwrap();
    let f = |dx: f64| {
        let mut l = lens.clone();
        set_param(&mut l, p, x0 + dx).unwrap();
        value(obj, &l, adj)
    };
    (-f(2.0 * h) + 8.0 * f(h) - 8.0 * f(-h) + f(-2.0 * h)) / (12.0 * h)
}

fn step(lens: &Lens, p: Param) -> f64 {
    let v = param_value(lens, p).unwrap().abs();
    match p {
        // Small steps: the triplet's near-hemispherical front makes the loss strongly nonlinear;
        // the fourth-order formula keeps the truncation error far below 1e-6 at these steps.
        Param::Curvature(_) => 1e-7,
        Param::Conic(_) => 1e-6 * v.max(1.0),
        Param::Asphere(_, j) => 1e-5 * v.max(1e-12 / 10f64.powi(j as i32)),
        Param::Gap(_) => 1e-5 * v.max(1.0),
        Param::GlassNd(_) => 1e-7,
        Param::GlassVd(_) => 1e-4,
    }
}

fn check(name: &str, lens: &Lens, perturbed: bool) {
    let adj = if perturbed {
        let p = ToleranceSpec::default().sample(lens, 5, 1).unwrap();
        p.apply(lens).unwrap().1
    } else {
        Adjustments::none(lens.surfaces.len())
    };
    let fields = [0.0, 0.7, 1.0].map(Field::fraction);
    // Two wavelengths, so that Abbe-number derivatives are not zero.
    let bundles = Bundles::new(
        lens,
        &fields,
        &[LAMBDA_D_NM, 486.1327],
        &Pupil::grid(8),
        TraceOptions { apertures: false },
    )
    .unwrap();
    for measure in [SpotMeasure::Mean, SpotMeasure::Rms] {
        let obj = SpotLoss {
            bundles: bundles.clone(),
            measure,
        };
        let vars = all_vars(lens);
        let (v, g) = gradient::<_, 8>(&obj, lens, &adj, &vars).unwrap();
        assert!(
            v == value(&obj, lens, &adj),
            "value part of the dual pass equals the f64 value"
        );
        for (k, &p) in vars.iter().enumerate() {
            let fd = central_diff(&obj, lens, &adj, p, step(lens, p));
            let rel = (g[k] - fd).abs() / fd.abs().max(1e-9);
            assert!(
                rel < 1e-6,
                "{name} perturbed={perturbed} {measure:?} {p:?}: dual {} vs FD {fd} (rel {rel:e})",
                g[k]
            );
        }
    }
}

#[test]
fn gradients_match_finite_differences_nominal() {
    for name in ["lens1", "lens2", "cooke-triplet"] {
        check(name, &Lens::load(name).unwrap(), false);
    }
    check("asphere", &asphere_lens(), false);
    check("cassegrain", &cassegrain(), false);
}

/// The two-mirror telescope of tests/data/cassegrain.json, defocused by 5 mm: in focus its
/// axial spot is a point, where the distance in the mean-radius loss has no derivative.
fn cassegrain() -> Lens {
    let mut l = Lens::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/cassegrain.json"
    ))
    .unwrap();
    l.surfaces[1].d_next_mm += 5.0;
    l
}

#[test]
fn gradients_match_finite_differences_perturbed() {
    for name in ["lens1", "lens2", "cooke-triplet"] {
        check(name, &Lens::load(name).unwrap(), true);
    }
    check("asphere", &asphere_lens(), true);
    check("cassegrain", &cassegrain(), true);
}

#[test]
fn passes_of_different_width_agree() {
    let lens = Lens::load("lens2").unwrap();
    let adj = Adjustments::none(lens.surfaces.len());
    let b = Bundles::new(
        &lens,
        &[Field::fraction(0.5)],
        &[LAMBDA_D_NM],
        &Pupil::grid(6),
        TraceOptions::default(),
    )
    .unwrap();
    let obj = SpotLoss {
        bundles: b,
        measure: SpotMeasure::Mean,
    };
    let vars = all_vars(&lens);
    let (_, g8) = gradient::<_, 8>(&obj, &lens, &adj, &vars).unwrap();
    let (_, g16) = gradient::<_, 16>(&obj, &lens, &adj, &vars).unwrap();
    let (_, g1) = gradient::<_, 1>(&obj, &lens, &adj, &vars).unwrap();
    assert_eq!(g8.len(), 31, "10 curvatures, 11 gaps, 5 model glasses");
    for k in 0..vars.len() {
        assert!(
            (g8[k] - g16[k]).abs() <= 1e-14 * g8[k].abs().max(1e-12)
                && (g8[k] - g1[k]).abs() <= 1e-14 * g8[k].abs().max(1e-12)
        );
    }
}

/// PSF-similarity loss of a perturbed lens against the nominal PSFs: exact gradient against a
/// central difference. The bilinear splat is smooth while no ray changes pixel, so the step is
/// halved until every ray keeps its pixel between x - 2h and x + 2h (checked through the loss's
/// own piecewise-quadratic behaviour: the 2nd- and 4th-order differences must agree).
#[test]
fn psf_similarity_loss_gradient_matches_finite_differences() {
    use tolray::optim::PsfLoss;
    use tolray::psf::{PsfOptions, PsfRays};
    for name in ["lens2", "cooke-triplet"] {
        let mut lens = Lens::load(name).unwrap();
        lens.object = Object::Infinite;
        let mut opts = PsfOptions::for_lens(&lens);
        opts.ks = 31;
        opts.pitch_mm *= 4.0;
        opts.pupil = Pupil::grid(6);
        let pairs = [
            (Field::fraction(0.0), LAMBDA_D_NM),
            (Field::fraction(0.7), 486.1327),
        ];
        let rays = PsfRays::new(&lens, &pairs, &opts.pupil).unwrap();
        let nominal = lens.compile();
        let loss = PsfLoss::new(rays, &nominal, opts, TraceOptions { apertures: false });
        let pattern = ToleranceSpec::default().sample(&lens, 3, 0).unwrap();
        let (plens, adj) = pattern.apply(&lens).unwrap();
        let vars = vec![
            Param::Curvature(0),
            Param::Curvature(2),
            Param::Gap(1),
            Param::Gap(lens.surfaces.len() - 1),
        ];
        let (v, g) = gradient::<_, 8>(&loss, &plens, &adj, &vars).unwrap();
        assert!(v > 0.0 && v < 1.0, "{name}: loss {v}");
        for (k, &p) in vars.iter().enumerate() {
            let x0 = param_value(&plens, p).unwrap();
            let f = |dx: f64| {
                let mut l = plens.clone();
                set_param(&mut l, p, x0 + dx).unwrap();
                value(&loss, &l, &adj)
            };
            let mut h = if matches!(p, Param::Curvature(_)) {
                1e-7
            } else {
                1e-5
            };
            let mut fd = f64::NAN;
            for _ in 0..12 {
                let d2 = (f(h) - f(-h)) / (2.0 * h);
                let d4 = (-f(2.0 * h) + 8.0 * f(h) - 8.0 * f(-h) + f(-2.0 * h)) / (12.0 * h);
                fd = d4;
                if (d2 - d4).abs() <= 1e-7 * d4.abs() {
                    break;
                }
                h *= 0.5;
            }
            let rel = (g[k] - fd).abs() / fd.abs().max(1e-9);
            assert!(
                rel < 1e-6,
                "{name} {p:?}: dual {} vs FD {fd} (rel {rel:e})",
                g[k]
            );
        }
    }
}

/// Asphere terms that are zero get their true derivative (the sag term they switch on), on an
/// aspheric surface past its last nonzero term and on a spherical surface (defect 2: they were
/// exactly 0, so an optimizer could never switch an asphere term on).
#[test]
fn zero_asphere_terms_have_their_derivative() {
    let lens2 = Lens::load("lens2").unwrap();
    let cases = [
        ("lens2", lens2, 9, 0..8),
        ("asphere", asphere_lens(), 0, 4..8),
    ];
    for (name, lens, surf, terms) in cases {
        let adj = Adjustments::none(lens.surfaces.len());
        let bundles = Bundles::new(
            &lens,
            &[0.0, 1.0].map(Field::fraction),
            &[LAMBDA_D_NM],
            &Pupil::grid(8),
            TraceOptions { apertures: false },
        )
        .unwrap();
        let obj = SpotLoss {
            bundles,
            measure: SpotMeasure::Rms,
        };
        let vars: Vec<Param> = terms.map(|j| Param::Asphere(surf, j)).collect();
        let (_, g) = gradient::<_, 8>(&obj, &lens, &adj, &vars).unwrap();
        let r = lens.surfaces[surf].semi_aperture_mm;
        for (k, &p) in vars.iter().enumerate() {
            let Param::Asphere(_, j) = p else {
                unreachable!()
            };
            // A step that moves the sag at the rim by 1e-6 mm.
            let h = 1e-6 / r.powi(2 * (j as i32 + 1));
            let fd = central_diff(&obj, &lens, &adj, p, h);
            assert!(
                fd.abs() > 0.0,
                "{name} {p:?}: the term does change the loss"
            );
            let rel = (g[k] - fd).abs() / fd.abs();
            assert!(
                rel < 1e-6,
                "{name} {p:?}: dual {} vs FD {fd} (rel {rel:e})",
                g[k]
            );
        }
    }
}
