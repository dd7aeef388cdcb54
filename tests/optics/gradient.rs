//! Exact dual-number gradients against central finite differences, for every variable kind, on
//! lens1, lens2, the Cooke triplet, an aspheric lens, a two-mirror telescope, a toroidal, an
//! odd-asphere and an ideal-thin-lens system, a lens with a virtual image, one with its object in
//! water, a ruled (grating) surface, toroids rolled about the axis, a singlet folded by two
//! fold mirrors, one meeting a converging beam (a virtual object), singlets of Q-type
//! aspheres (Qbfs and Qcon), one of Zernike sag surfaces (Fringe and Standard, decentred,
//! every Zernike coefficient a variable) and one with a diffractive phase (Binary 2, every phase
//! coefficient a variable), nominal and perturbed. Where f64's rounding of the loss would limit a
//! difference, it is taken of the loss evaluated in double-double numbers (`Dd`, the same
//! generic code at ~1e-32 relative).

use crate::double_double::{dd_central_diff, value_dd};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{Adjustments, Material, Param, Surface};
use tolray::optim::{gradient, param_value, set_param, value, Objective, SpotLoss, SpotMeasure};
use tolray::tolerance::ToleranceSpec;
use tolray::trace::{Bundles, Field, Pupil, TraceOptions};
use tolray::{Lens, Object};

/// Every design variable of a lens: curvatures of refracting surfaces, every gap (the last is
/// the image distance), conics, and the asphere terms in use.
fn all_vars(lens: &Lens) -> Vec<Param> {
    let mut v = Vec::new();
    for (i, s) in lens.surfaces.iter().enumerate() {
        // An ideal thin lens is flat: its shape has no variables.
        let thin = matches!(s.shape, tolray::lens::Shape::Paraxial { .. });
        if s.role != tolray::lens::SurfaceRole::Aperture && !thin {
            v.push(Param::Curvature(i));
            if s.k != 0.0 || s.is_aspheric() {
                v.push(Param::Conic(i));
            }
            for j in 0..8 {
                if s.asph[j] != 0.0 {
                    v.push(Param::Asphere(i, j));
                }
            }
            for (j, a) in s.zernike.iter().enumerate() {
                if *a != 0.0 {
                    v.push(Param::Zernike(i, j));
                }
            }
            if let Some(ph) = &s.phase {
                for j in 0..ph.coefficients.len() {
                    v.push(Param::Phase(i, j));
                }
            }
        }
        v.push(Param::Gap(i));
        if matches!(s.material, Material::Model { .. }) {
            v.push(Param::GlassNd(i));
            v.push(Param::GlassVd(i));
        }
        // A gradient-index medium: n0, r² and the terms in use.
        if let Material::Gradient(g) = &s.material {
            let terms = g.radial.iter().chain(&g.axial).enumerate();
            v.push(Param::Gradient(i, 0));
            v.extend(
                terms
                    .filter(|&(j, a)| j == 0 || *a != 0.0)
                    .map(|(j, _)| Param::Gradient(i, j + 1)),
            );
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

/// The aspheric lens of [`asphere_lens`] with its object 60 mm away in water (n = 1.333).
fn immersed() -> Lens {
    let mut l = asphere_lens();
    l.object = Object::Finite { distance_mm: 60.0 };
    l.object_medium = Material::Constant(1.333);
    l
}

/// The aspheric lens of [`asphere_lens`] with a grating ruled on its conic back surface (300
/// lines/mm, first order) and the grating and both faces rolled about the axis.
fn ruled() -> Lens {
    let mut l = asphere_lens();
    l.surfaces[1].grating = Some(tolray::lens::Grating {
        lines_per_um: 0.3,
        order: 1.0,
    });
    l.surfaces[1].roll_deg = 25.0;
    l
}

/// tests/data/zemax/toroid.zmx with its toroidal faces rolled 30 degrees about the axis.
fn rolled_toroid() -> Lens {
    let mut l = zmx("toroid.zmx");
    for s in &mut l.surfaces {
        if !s.shape.is_rotational() {
            s.roll_deg = 30.0;
        }
    }
    l
}

/// Sixth-order central difference (error O(h⁶)) of the objective as an optimizer evaluates it
/// when `p` moves by `h`: `make` builds it from the stepped design (its rays launched from that
/// design), which is traced with `adj`.
fn central_diff<O: Objective>(
    make: &dyn Fn(&Lens) -> O,
    lens: &Lens,
    adj: &Adjustments,
    p: Param,
    h: f64,
) -> f64 {
    let x0 = param_value(lens, p).unwrap();
    let f = |dx: f64| {
        let mut l = lens.clone();
        set_param(&mut l, p, x0 + dx).unwrap();
        value(&make(&l), &l, adj)
    };
    let d4 = |h: f64| (-f(2.0 * h) + 8.0 * f(h) - 8.0 * f(-h) + f(-2.0 * h)) / (12.0 * h);
    // Richardson's extrapolation removes the h⁴ term, so that steps can stay well above the
    // rounding of re-launched rays.
    (16.0 * d4(0.5 * h) - d4(h)) / 15.0
}

/// The spot loss of `fields` at the d and F lines through an `n x n` pupil grid, its rays
/// launched from `lens`.
fn spot_loss(lens: &Lens, fields: &[Field], n: usize, measure: SpotMeasure) -> SpotLoss {
    SpotLoss {
        bundles: Bundles::new(lens, fields, &[LAMBDA_D_NM, 486.1327], &Pupil::grid(n)).unwrap(),
        measure,
        trace: TraceOptions { apertures: false },
    }
}

fn step(lens: &Lens, p: Param) -> f64 {
    let v = param_value(lens, p).unwrap().abs();
    match p {
        // Small steps: the triplet's near-hemispherical front makes the loss strongly nonlinear;
        // the fourth-order formula keeps the truncation error far below 1e-6 at these steps.
        Param::Curvature(_) => 1e-7,
        Param::Conic(_) => 1e-6 * v.max(1.0),
        // Or, if larger, the step that moves the sag by 1e-7 mm at the semi-diameter (a large
        // high-order term would otherwise get a step whose effect drowns in rounding).
        Param::Asphere(i, j) => {
            let s = &lens.surfaces[i];
            let power = match s.shape {
                tolray::lens::Shape::Odd => j as i32 + 1,
                // A Q term is a departure in mm whatever its index.
                tolray::lens::Shape::Qbfs { .. } | tolray::lens::Shape::Qcon { .. } => 0,
                _ => 2 * j as i32 + 2,
            };
            (1e-5 * v.max(1e-12 / 10f64.powi(j as i32))).max(1e-7 / s.semi_aperture_mm.powi(power))
        }
        // Gaps: the launch (entrance pupil, field angle) moves with them too, and re-launching
        // at each step adds rounding a smaller step would magnify.
        // A virtual image's gap (against the travel): behind a fast negative lens the loss
        // curves fast in it (at 3.9e-3 mm the difference quotient is 1.4e-6 off; it converges
        // to the dual value, 1e-9 at 1e-3 mm and 1e-11 at 1e-4 mm).
        Param::Gap(i)
            if i + 1 == lens.surfaces.len()
                && lens.surfaces[i].d_next_mm * lens.travel_directions()[i + 1] < 0.0 =>
        {
            1e-5 * v
        }
        Param::Gap(_) => 1e-4 * v.max(1.0),
        // A Zernike coefficient is a sag in mm (a term is of order 1 over the circle): a step
        // that moves the sag by 1e-5 mm, above the re-launched rays' rounding (a piston moves
        // the launch, through the paraxial model's vertex).
        Param::Zernike(..) => 1e-5,
        // A phase coefficient in radians: 1e-2 rad moves the path by ~1e-6 mm.
        Param::Phase(..) => 1e-2,
        Param::GlassNd(_) => 1e-7,
        Param::GlassVd(_) => 1e-4,
        // A gradient-index coefficient: the step that changes the index by 1e-7 at the
        // semi-diameter (radial terms) or across the gap (axial ones).
        Param::Gradient(i, j) => {
            let s = &lens.surfaces[i];
            match j {
                0 => 1e-7,
                1..=6 => 1e-7 / s.semi_aperture_mm.powi(2 * j as i32),
                _ => 1e-7 / s.d_next_mm.powi(j as i32 - 6),
            }
        }
    }
}

fn check(name: &str, lens: &Lens, perturbed: bool) {
    let adj = if perturbed {
        let p = ToleranceSpec::default().sample(lens, 5, 1).unwrap();
        p.apply(lens).unwrap().1
    } else {
        Adjustments::none(lens.surfaces.len())
    };
    // Two wavelengths, so that Abbe-number derivatives are not zero.
    let fields = [0.0, 0.7, 1.0].map(Field::fraction);
    for measure in [SpotMeasure::Mean, SpotMeasure::Rms] {
        let make = |l: &Lens| spot_loss(l, &fields, 8, measure);
        let obj = make(lens);
        let vars = all_vars(lens);
        let (v, g) = gradient::<_, 8>(&obj, lens, &adj, &vars).unwrap();
        assert!(
            v == value(&obj, lens, &adj),
            "value part of the dual pass equals the f64 value"
        );
        for (k, &p) in vars.iter().enumerate() {
            // The loss in double-double numbers: in f64, re-launching at each step rounds the
            // launch afresh and the loss jitters by ~5e-13 from one step to the next, which
            // small derivatives could only be checked to over the step. Measured 2026-11-30:
            // every derivative to 8.2e-7 at worst.
            let fd = dd_central_diff(&make, lens, &adj, p, step(lens, p), true);
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
    check("toroid", &zmx("toroid.zmx"), false);
    check("odd asphere", &zmx("oddasphere.zmx"), false);
    check("ideal thin lens", &zmx("thinlens.zmx"), false);
    check("virtual image", &zmx("virtual-image.zmx"), false);
    check("immersed", &immersed(), false);
    check("grating", &ruled(), false);
    check("rolled toroid", &rolled_toroid(), false);
    check("fold mirrors", &zmx("fold.zmx"), false);
    check("virtual object", &zmx("virtual-object.zmx"), false);
    check("Q-type aspheres", &zmx("qbfs.zmx"), false);
    check("Qcon aspheres", &zmx("qcon.zmx"), false);
    check("curved image", &zmx("curved-image.zmx"), false);
    check("Zernike sag surfaces", &zmx("zernike.zmx"), false);
    check("diffractive phase", &zmx("binary2.zmx"), false);
    check("gradient index", &zmx("grin.zmx"), false);
}

/// A hand-made lens of tests/data/zemax: toroid.zmx (a toroidal front, a cylindrical back) or
/// oddasphere.zmx (an odd-asphere front with a cone term).
fn zmx(name: &str) -> Lens {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zemax/").to_string() + name;
    tolray::lens::zemax::read_file(
        std::path::Path::new(&path),
        &tolray::lens::GlassCatalogs::builtin(),
    )
    .unwrap()
    .lens
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
    check("toroid", &zmx("toroid.zmx"), true);
    check("odd asphere", &zmx("oddasphere.zmx"), true);
    check("ideal thin lens", &zmx("thinlens.zmx"), true);
    check("virtual image", &zmx("virtual-image.zmx"), true);
    check("immersed", &immersed(), true);
    check("grating", &ruled(), true);
    check("rolled toroid", &rolled_toroid(), true);
    check("fold mirrors", &zmx("fold.zmx"), true);
    check("virtual object", &zmx("virtual-object.zmx"), true);
    check("Q-type aspheres", &zmx("qbfs.zmx"), true);
    check("Qcon aspheres", &zmx("qcon.zmx"), true);
    check("Zernike sag surfaces", &zmx("zernike.zmx"), true);
    check("diffractive phase", &zmx("binary2.zmx"), true);
    check("gradient index", &zmx("grin.zmx"), true);
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
    )
    .unwrap();
    let obj = SpotLoss {
        bundles: b,
        measure: SpotMeasure::Mean,
        trace: TraceOptions::default(),
    };
    let vars = all_vars(&lens);
    // Widths 8 and 1 run the library's builds of the kernel; width 3 the generic one (in this
    // crate: a narrow width keeps its build short), in 11 passes, the last with one variable.
    let (_, g8) = gradient::<_, 8>(&obj, &lens, &adj, &vars).unwrap();
    let (_, g3) = gradient::<_, 3>(&obj, &lens, &adj, &vars).unwrap();
    let (_, g1) = gradient::<_, 1>(&obj, &lens, &adj, &vars).unwrap();
    assert_eq!(g8.len(), 31, "10 curvatures, 11 gaps, 5 model glasses");
    for k in 0..vars.len() {
        assert!(
            (g8[k] - g3[k]).abs() <= 1e-14 * g8[k].abs().max(1e-12)
                && (g8[k] - g1[k]).abs() <= 1e-14 * g8[k].abs().max(1e-12)
        );
    }
}

/// PSF-similarity loss of a perturbed lens against the design's own PSFs: exact gradient (the
/// launch and the reference moving with the design) against a central difference of the loss
/// rebuilt at each step. The bilinear splat is smooth while no ray changes pixel, so the step is
/// halved until every ray keeps its pixel between x - 2h and x + 2h (checked through the loss's
/// own piecewise-quadratic behaviour: the 2nd- and 4th-order differences must agree).
#[test]
fn psf_similarity_loss_gradient_matches_finite_differences() {
    use tolray::optim::PsfLoss;
    use tolray::psf::PsfOptions;
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
        // The loss as evaluated at a design: rays launched from it, its own PSFs the reference.
        let make = |l: &Lens| PsfLoss {
            rays: Bundles::pairs(l, &pairs, &opts.pupil).unwrap(),
            opts,
            trace: TraceOptions { apertures: false },
        };
        let loss = make(&lens);
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
            // The design and the unit step together; the pattern's motions are constants (as
            // the gradient holds them: a tilt's pivot does not follow the design's gaps).
            let (x0, u0) = (
                param_value(&lens, p).unwrap(),
                param_value(&plens, p).unwrap(),
            );
            let f = |dx: f64| {
                let (mut l, mut u) = (lens.clone(), plens.clone());
                set_param(&mut l, p, x0 + dx).unwrap();
                set_param(&mut u, p, u0 + dx).unwrap();
                value(&make(&l), &u, &adj)
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
        let fields = [0.0, 1.0].map(Field::fraction);
        let make = |l: &Lens| spot_loss(l, &fields, 8, SpotMeasure::Rms);
        let obj = make(&lens);
        let vars: Vec<Param> = terms.map(|j| Param::Asphere(surf, j)).collect();
        let (_, g) = gradient::<_, 8>(&obj, &lens, &adj, &vars).unwrap();
        let r = lens.surfaces[surf].semi_aperture_mm;
        for (k, &p) in vars.iter().enumerate() {
            let Param::Asphere(_, j) = p else {
                unreachable!()
            };
            // A step that moves the sag at the rim by 1e-6 mm.
            let h = 1e-6 / r.powi(2 * (j as i32 + 1));
            let fd = central_diff(&make, &lens, &adj, p, h);
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

/// Defect 3 of issue 15: the gradient is the derivative of the loss as an optimizer evaluates it,
/// with its rays launched from the design being stepped (the paraxial entrance pupil and the
/// field angle of a fraction of the field move with the design). On lens2 the launch is worth
/// percents of the derivative (here 2.5 % of it in the front curvature, 4.8 % in the first gap;
/// the issue measured 1.7 % and 3.4 % in its setup); held launches are now only aimed ones, as
/// documented, and a parameter can be moved in the traced unit alone.
#[test]
fn the_gradient_includes_the_launch() {
    use tolray::optim::gradient_with_unit;
    let lens = Lens::load("lens2").unwrap();
    let adj = Adjustments::none(lens.surfaces.len());
    let fields = [0.0, 0.7, 1.0].map(Field::fraction);
    let make = |l: &Lens| spot_loss(l, &fields, 8, SpotMeasure::Mean);
    let obj = make(&lens);
    let vars = [Param::Curvature(0), Param::Gap(1), Param::Curvature(3)];
    let g = assert_launch_in_gradient(&make, &lens, &vars, 1e-3);
    // Aimed rays keep their launch: the gradient is that of the stored rays.
    let mut aimed = Pupil::grid(6);
    aimed.aim = true;
    let bundles = Bundles::new(&lens, &fields, &[LAMBDA_D_NM], &aimed).unwrap();
    let held = SpotLoss {
        bundles,
        measure: SpotMeasure::Rms,
        trace: TraceOptions { apertures: false },
    };
    let (_, ga) = gradient::<_, 8>(&held, &lens, &adj, &vars).unwrap();
    for (k, &p) in vars.iter().enumerate() {
        let fd = central_diff(&|_: &Lens| held.clone(), &lens, &adj, p, step(&lens, p));
        assert!(
            (ga[k] - fd).abs() < 1e-6 * fd.abs(),
            "aimed {p:?}: dual {} vs FD {fd}",
            ga[k]
        );
    }
    // A unit-only parameter moves the traced lens, not the launch: its derivative is that of
    // the stored rays, and the design's variables keep theirs.
    let last = Param::Gap(lens.surfaces.len() - 1);
    let (_, gu) = gradient_with_unit::<_, 8>(&obj, &lens, &adj, &vars, Param::Gap(1)).unwrap();
    assert_eq!(gu.len(), vars.len() + 1);
    assert_eq!(&gu[..vars.len()], &g[..]);
    let fd = central_diff(
        &|_: &Lens| obj.clone(),
        &lens,
        &adj,
        Param::Gap(1),
        step(&lens, Param::Gap(1)),
    );
    assert!(
        (gu[3] - fd).abs() < 1e-6 * fd.abs(),
        "unit Gap(1): dual {} vs FD {fd}",
        gu[3]
    );
    // The image distance does not move the launch: design and unit derivatives agree.
    let (_, gl) = gradient_with_unit::<_, 8>(&obj, &lens, &adj, &[last], last).unwrap();
    assert!((gl[0] - gl[1]).abs() <= 1e-12 * gl[0].abs(), "{gl:?}");
}

/// Asserts that the dual gradient of `make(lens)` in `vars` equals central differences of the
/// loss rebuilt from each moved lens (1e-6), and that the launch's share of each derivative (the
/// difference to central differences of the loss with its rays held) is above `min_launch`, ten
/// times the tolerance or more, so a held launch would fail the first check. Returns the gradient.
fn assert_launch_in_gradient(
    make: &dyn Fn(&Lens) -> SpotLoss,
    lens: &Lens,
    vars: &[Param],
    min_launch: f64,
) -> Vec<f64> {
    let adj = Adjustments::none(lens.surfaces.len());
    let obj = make(lens);
    let (_, g) = gradient::<_, 8>(&obj, lens, &adj, vars).unwrap();
    for (k, &p) in vars.iter().enumerate() {
        let h = step(lens, p);
        let exact = central_diff(make, lens, &adj, p, h);
        let frozen = central_diff(&|_: &Lens| obj.clone(), lens, &adj, p, h);
        let rel = (g[k] - exact).abs() / exact.abs();
        assert!(
            rel < 1e-6,
            "{p:?}: dual {} vs FD {exact} (rel {rel:e})",
            g[k]
        );
        let launch = (frozen - exact).abs() / exact.abs();
        eprintln!(
            "{p:?}: the launch is {:.4} % of the derivative",
            100.0 * launch
        );
        assert!(
            launch > min_launch,
            "{p:?}: the launch term is {launch:e} of it"
        );
    }
    g
}

/// Image-height fields (a .zmx file's FTYP 2 and 3): a paraxial image height's launch moves
/// with the design, the image distance included (the chief ray's height is taken on the image
/// plane), and the dual gradient of a spot loss at such fields equals central differences of
/// the loss rebuilt from each moved lens (1e-6); a real image height's field solve is held, as
/// documented, so its gradient is that of the stored rays.
#[test]
fn image_height_fields_carry_their_launch() {
    let lens = Lens::load("lens2").unwrap();
    let adj = Adjustments::none(lens.surfaces.len());
    let r = lens.sensor.half_diagonal_mm();
    let fields = [0.0, 0.7, 1.0].map(|f| Field::ImageHeightMm { x: 0.0, y: f * r });
    let make = |l: &Lens| spot_loss(l, &fields, 8, SpotMeasure::Mean);
    let last = Param::Gap(lens.surfaces.len() - 1);
    let vars = [Param::Curvature(0), Param::Gap(1), last];
    // The image distance's launch term is the smallest: 9.4e-5 of its derivative.
    assert_launch_in_gradient(&make, &lens, &vars, 1e-5);
    // A field means the same rays at every wavelength: the unit chief ray is the primary's.
    let at = |nm: f64| lens.paraxial(nm).unwrap().chief_image_height_mm;
    assert_eq!(at(486.1327), at(lens.primary_wavelength_nm));
    // At 2 m the unit is an object height of 1 mm: near the lateral magnification (the image
    // plane lies near the paraxial image).
    let m = lens
        .paraxial(lens.primary_wavelength_nm)
        .unwrap()
        .magnification;
    let k = at(lens.primary_wavelength_nm);
    assert!((k - m).abs() < 0.05 * m.abs(), "{k} vs {m}");
    let real = [0.0, 0.7, 1.0].map(|f| Field::RealImageHeightMm { x: 0.0, y: f * r });
    let held = spot_loss(&lens, &real, 8, SpotMeasure::Mean);
    let (_, gr) = gradient::<_, 8>(&held, &lens, &adj, &vars).unwrap();
    for (k, &p) in vars.iter().enumerate() {
        let fd = central_diff(&|_: &Lens| held.clone(), &lens, &adj, p, step(&lens, p));
        assert!(
            (gr[k] - fd).abs() < 1e-6 * fd.abs(),
            "real image height {p:?}: dual {} vs FD {fd}",
            gr[k]
        );
    }
}

/// The RMS wavefront loss (issue 40): its value is the wavefront analysis' RMS to centroid,
/// nominal and perturbed, and its dual gradient in every design variable (the launch, the
/// chief ray's reference point and the paraxial exit pupil moving with the design) equals
/// central differences of the loss rebuilt at each step, to 1e-6 relative, on lens1, lens2,
/// the Cooke triplet, the aspheric singlet and a finite-object lens (immersed), on and off
/// axis, at two wavelengths.
#[test]
fn wavefront_loss_gradient_matches_finite_differences() {
    use tolray::optim::WavefrontLoss;
    use tolray::wave::{wavefront, Sampling, WaveOptions};
    let (fields, wls) = (WAVE_FIELDS.map(Field::fraction), WAVE_WLS);
    let sampling = Sampling::Quadrature {
        rings: 6,
        spokes: 12,
    };
    let make = |l: &Lens| {
        WavefrontLoss::new(
            l,
            &fields,
            &wls,
            sampling,
            TraceOptions { apertures: false },
        )
        .unwrap()
    };
    let lenses = wave_lenses();
    let mut worst = 0.0f64;
    for (name, lens) in &lenses {
        for perturbed in [false, true] {
            let adj = unit_adjustments(lens, perturbed);
            let obj = make(lens);
            let v = value(&obj, lens, &adj);
            // The analysis' number, field by field.
            let sys = tolray::lens::System::compile(lens, &adj, &|_, v| v);
            let opts = WaveOptions {
                sampling,
                trace: TraceOptions { apertures: false },
                ..WaveOptions::default()
            };
            let mut mean = 0.0;
            for &f in &fields {
                for &wl in &wls {
                    let w = wavefront(lens, &sys, f, wl, &opts).unwrap();
                    mean += w.rms_to_centroid_waves().unwrap() / 4.0;
                }
            }
            assert!(
                (v - mean).abs() < 1e-9 * mean.max(1.0),
                "{name} perturbed={perturbed}: loss {v} vs analysis {mean}"
            );
            let vars = all_vars(lens);
            let (v8, g) = gradient::<_, 8>(&obj, lens, &adj, &vars).unwrap();
            assert_eq!(v8, v, "{name}: the dual pass's value is the f64 value");
            for (k, &p) in vars.iter().enumerate() {
                // An OPD in waves is a difference of path lengths of ~100 mm over λ: in f64 the
                // loss rounds at ~3e-10 waves, which the spot loss's steps would magnify beyond
                // 1e-6 of the smallest derivatives. Evaluated in double-double it still rounds
                // at ~5e-11 waves (measured 2026-11-30: some f64 rounding of a ~100 mm length
                // remains on the way, with the paraxial entrance pupil), so the step moves the
                // loss by about 1e-2 waves, within 10 of the spot loss's steps for a curvature
                // (larger ones can push a surface past its rim) and 100 otherwise, and the
                // difference is extrapolated to fourth order. Measured: 4.8e-7 at worst.
                let h0 = step(lens, p);
                let most = if matches!(p, Param::Curvature(_)) {
                    10.0
                } else {
                    100.0
                };
                let h = (1e-2 / g[k].abs().max(1e-300)).clamp(h0, most * h0);
                let fd = dd_central_diff(&make, lens, &adj, p, h, true);
                let rel = (g[k] - fd).abs() / fd.abs().max(1e-9);
                assert!(
                    rel < 1e-6,
                    "{name} perturbed={perturbed} {p:?}: dual {} vs FD {fd} (rel {rel:e})",
                    g[k]
                );
                worst = worst.max(rel);
            }
        }
    }
    println!("RMS wavefront loss: worst relative error {worst:e}");
}

/// The MTF loss (`1 − MTF` at one frequency, the mean of tangential and sagittal) equals the
/// direct MTF analysis on the same pupil grid to 1e-9, and its dual gradient in every design
/// variable equals the central difference of the loss rebuilt at each step to 1e-6 relative,
/// nominal and perturbed, on five lenses at two fields and two wavelengths (176 derivatives).
///
/// The differences are taken of the loss evaluated in double-double numbers (`Dd`, the same
/// objective traced in the same generic code at about 1e-32 relative): in f64 an OPD in waves is
/// a difference of ~1e5-wave path lengths and the loss scatters by up to 2e-9 about a smooth
/// curve, which no step could get below 1e-6 of the smallest derivatives (steps large enough
/// also moved sheared points across the pupil's rim, where the loss jumps). In double-double it
/// scatters by 4e-14 (measured 2026-11-30, the rms about a quadratic over nine points 1e-6 of
/// a step apart), so steps of 1e-4 of the spot loss's stay clear of the rim and of the
/// truncation error: every derivative agrees to 8e-8 at worst.
#[test]
fn mtf_loss_gradient_matches_finite_differences() {
    use tolray::optim::MtfLoss;
    use tolray::tolerance::MtfDirection;
    use tolray::wave::{mtf::direct_mtf, Sampling, WaveOptions};
    let (fields, wls) = (WAVE_FIELDS.map(Field::fraction), WAVE_WLS);
    let sampling = Sampling::Grid(16);
    let trace = TraceOptions { apertures: false };
    let lenses = wave_lenses();
    let (mut checked, mut worst) = (0, 0.0f64);
    for (name, lens) in &lenses {
        // A quarter of the on-axis cutoff at the d line.
        let p = lens.paraxial(LAMBDA_D_NM).unwrap();
        let freq = 0.25 / (LAMBDA_D_NM * 1e-6 * p.working_fnum.unwrap());
        let make = |l: &Lens| {
            MtfLoss::new(l, &fields, &wls, freq, MtfDirection::Mean, sampling, trace).unwrap()
        };
        for perturbed in [false, true] {
            let adj = unit_adjustments(lens, perturbed);
            let obj = make(lens);
            let v = value(&obj, lens, &adj);
            let sys = tolray::lens::System::compile(lens, &adj, &|_, v| v);
            let opts = WaveOptions {
                sampling,
                trace,
                ..WaveOptions::default()
            };
            let mut mean = 0.0;
            for &f in &fields {
                for &wl in &wls {
                    let m = direct_mtf(lens, &sys, f, wl, &opts, &[freq]).unwrap();
                    mean += 0.5 * (m.tangential[0] + m.sagittal[0]) / 4.0;
                }
            }
            assert!(
                (v - (1.0 - mean)).abs() < 1e-9,
                "{name} perturbed={perturbed}: loss {v} vs 1 - analysis {}",
                1.0 - mean
            );
            assert!(v > 0.0 && v < 1.0, "{name}: {v}");
            // The double-double evaluation is the same loss (to the f64 one's rounding).
            let vd = value_dd(&obj, lens, &adj);
            assert!(
                (vd.hi - v).abs() < 1e-8,
                "{name}: double-double {vd:?} vs {v}"
            );
            let vars = all_vars(lens);
            let (v8, g) = gradient::<_, 8>(&obj, lens, &adj, &vars).unwrap();
            assert_eq!(v8, v, "{name}: the dual pass's value is the f64 value");
            for (k, &p) in vars.iter().enumerate() {
                let h = 1e-4 * step(lens, p);
                let fd = dd_central_diff(&make, lens, &adj, p, h, false);
                let rel = (g[k] - fd).abs() / fd.abs().max(1e-9);
                assert!(
                    rel < 1e-6,
                    "{name} perturbed={perturbed} {p:?}: dual {} vs central difference {fd} \
                     (relative {rel:e})",
                    g[k]
                );
                worst = worst.max(rel);
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 176);
    println!("MTF loss: {checked} derivatives to 1e-6 relative, worst {worst:e}");
}

/// The lenses of the wave losses' gradient tests: lens1, lens2, the Cooke triplet, the aspheric
/// singlet and a finite-object lens (immersed).
fn wave_lenses() -> [(&'static str, Lens); 5] {
    [
        ("lens1", Lens::load("lens1").unwrap()),
        ("lens2", Lens::load("lens2").unwrap()),
        ("cooke-triplet", Lens::load("cooke-triplet").unwrap()),
        ("asphere", asphere_lens()),
        ("immersed", immersed()),
    ]
}

/// Their fields (fractions) and wavelengths (nm).
const WAVE_FIELDS: [f64; 2] = [0.0, 0.7];
const WAVE_WLS: [f64; 2] = [LAMBDA_D_NM, 486.1327];

/// No adjustment, or a perturbed unit's: pattern 5 of seed 1 of the default spec.
fn unit_adjustments(lens: &Lens, perturbed: bool) -> Adjustments {
    if perturbed {
        let p = ToleranceSpec::default().sample(lens, 5, 1).unwrap();
        p.apply(lens).unwrap().1
    } else {
        Adjustments::none(lens.surfaces.len())
    }
}
