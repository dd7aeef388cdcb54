//! Zernike sag surfaces (OpticStudio FZERNSAG and SZERNSAG): OpticStudio's own sags, optiland's
//! rays through a hand-made singlet and through the mirrors of a real file, closed forms (Z37,
//! the decenter, Extrapolate = 0, the paraxial curvature) and the round trips.

use super::*;
use tolray::lens::{Shape, Surface};
use tolray::math::zernike::Ordering;

fn zernike_shape(lens: &Lens, i: usize) -> (Ordering, f64, [f64; 2], bool) {
    match lens.surfaces[i].shape {
        Shape::Zernike {
            ordering,
            norm_radius_mm,
            decenter_mm,
            extrapolate,
        } => (ordering, norm_radius_mm, decenter_mm, extrapolate),
        other => panic!("surface {i} is {other:?}"),
    }
}

/// A flat-based Zernike surface of radius `radius_mm` over a `norm` mm circle, with `terms`
/// (index from 1, coefficient mm).
fn surface(ordering: Ordering, radius_mm: f64, norm: f64, terms: &[(usize, f64)]) -> Surface {
    let mut s = Surface::sphere(1.0 / radius_mm, 12.0, 5.0, Material::Air);
    s.shape = Shape::Zernike {
        ordering,
        norm_radius_mm: norm,
        decenter_mm: [0.0; 2],
        extrapolate: true,
    };
    let n = terms.iter().map(|t| t.0).max().unwrap_or(0);
    s.zernike = vec![0.0; n];
    for &(j, a) in terms {
        s.zernike[j - 1] = a;
    }
    s
}

/// OpticStudio's sags of a Zernike Standard and a Zernike Fringe sag surface (radius 22 mm,
/// normalization radius 10 mm, five terms each) on a 10 x 10 grid reaching ρ = √2 (computed in
/// OpticStudio through ZOSPy by optiland's authors: tests/data/zemax/zernike_opticstudio_sag.json
/// names the source), printed to 1e-8 mm: the library's surface (the kernel's merged terms)
/// and the reference tracer's sag (the polar definitions) both give them to 1e-8 mm.
#[test]
fn zernike_sags_are_opticstudios() {
    let doc: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(fixture("zernike_opticstudio_sag.json")).unwrap(),
    )
    .unwrap();
    for (key, ordering) in [
        ("standard", Ordering::Standard),
        ("fringe", Ordering::Fringe),
    ] {
        let case = &doc[key];
        let terms: Vec<(usize, f64)> = case["terms"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(j, a)| (j.parse().unwrap(), a.as_f64().unwrap()))
            .collect();
        let s = surface(ordering, 22.0, 10.0, &terms);
        let mut lens = Lens::load("lens1").unwrap();
        lens.surfaces = vec![s.clone()];
        lens.object = Object::Infinite;
        lens.validate().unwrap();
        let sys = lens.compile();
        let grid: Vec<f64> = (0..10).map(|k| -10.0 + 20.0 * k as f64 / 9.0).collect();
        let mut worst = 0.0f64;
        for (iy, row) in case["sag_mm"].as_array().unwrap().iter().enumerate() {
            for (ix, want) in row.as_array().unwrap().iter().enumerate() {
                let want = want.as_f64().unwrap();
                let (x, y) = (grid[ix], grid[iy]);
                let lib = s.sag_xy(x, y).unwrap();
                let (reference, _, _) =
                    tolray::trace::reference::surface_sag_xy(&sys.rows[0], x, y).unwrap();
                worst = worst.max((lib - want).abs()).max((reference - want).abs());
            }
        }
        assert!(
            worst < 1e-8,
            "{key}: worst {worst:e} mm against OpticStudio"
        );
    }
}

/// A hand-made singlet (a Fringe front of 17 terms, a decentred Standard back of 12 terms
/// with r⁴ and r⁶ terms) and the two Zernike Fringe Sag mirrors of a real file (8 terms each,
/// the secondary with r⁴ .. r¹² terms) trace every ray as optiland 0.6.3 does with the files'
/// numbers (tests/data/zemax/zernike_reference.json, scripts/zmxref/zernike_reference.py: 147
/// and 336 rays in three directions; the Zernike terms move the singlet's rays by up to 0.35
/// mm): image positions to 1e-9 mm (1e-8 over the telescope's 870 mm), directions to 1e-11.
/// The surfaces survive .zmx and JSON.
#[test]
fn zernike_sag_surfaces_trace_as_optiland_ray_by_ray() {
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("zernike_reference.json")).unwrap())
            .unwrap();
    for (file, entry) in doc["lenses"].as_object().unwrap() {
        let z = zemax::read_file(&fixture(file), &GlassCatalogs::builtin()).unwrap();
        let lens = &z.lens;
        let wl = entry["wavelength_nm"].as_f64().unwrap();
        let zs: Vec<usize> = (0..lens.surfaces.len())
            .filter(|&i| matches!(lens.surfaces[i].shape, Shape::Zernike { .. }))
            .collect();
        assert_eq!(zs.len(), 2, "{file}");
        if file == "zernike.zmx" {
            assert!(z.warnings.is_empty(), "{file}: {:?}", z.warnings);
            assert_eq!(
                zernike_shape(lens, zs[0]),
                (Ordering::Fringe, 6.0, [0.0; 2], true)
            );
            // PARM 0 missing: extrapolated, as OpticStudio's default.
            assert_eq!(
                zernike_shape(lens, zs[1]),
                (Ordering::Standard, 7.0, [0.3, -0.2], true)
            );
            let (front, back) = (&lens.surfaces[zs[0]], &lens.surfaces[zs[1]]);
            assert_eq!((front.zernike.len(), back.zernike.len()), (36, 45));
            assert_eq!((front.zernike[3], front.zernike[35]), (0.02, 1e-4));
            assert_eq!((back.zernike[3], back.zernike[44]), (-0.01, -5e-5));
            assert_eq!(back.asph[..3], [0.0, -2e-5, 3e-7]);
        } else {
            let (primary, secondary) = (&lens.surfaces[zs[0]], &lens.surfaces[zs[1]]);
            assert_eq!(
                zernike_shape(lens, zs[0]),
                (Ordering::Fringe, 72.5, [0.0; 2], true)
            );
            assert_eq!(primary.zernike.len(), 8);
            assert_eq!(secondary.zernike[7], 6.1276432914260805e-12);
            assert_eq!(secondary.asph[5], -3.996119986487E-25);
        }
        let rays = entry["rays"].as_array().unwrap();
        let (worst, _) = worst_against(lens, wl, rays, file);
        let tol = if file == "zernike.zmx" { 1e-9 } else { 1e-8 };
        assert!(
            worst.0 < tol && worst.1 < 1e-11,
            "{file}: worst position {:e} mm, direction {:e}",
            worst.0,
            worst.1
        );
        // Both formats keep every number.
        let back = parse(&zemax::to_string(lens, None)).unwrap().lens;
        let j = json::from_str(&json::to_string(lens)).unwrap();
        for &i in &zs {
            for (what, other) in [(".zmx", &back), ("JSON", &j)] {
                let (a, b) = (&lens.surfaces[i], &other.surfaces[i]);
                assert_eq!(
                    (a.shape, &a.zernike, a.asph),
                    (b.shape, &b.zernike, b.asph),
                    "{file} {what}"
                );
            }
        }
        let (again, _) = worst_against(&back, wl, rays, file);
        assert!(again.0 < tol, "{file} after .zmx: {:e}", again.0);
    }
}

/// Closed forms: Fringe Z37 is OpticStudio's 12th-order spherical term (optiland's Fringe set
/// differs there); a decentred Z4 is the centred Z1 .. Z4 it expands into (the polynomials are
/// evaluated at (x − dx, y − dy)); with Extrapolate = 0 the terms vanish beyond the circle; the
/// r² .. r¹⁶ terms alone trace exactly as the even asphere; and the paraxial model takes the
/// terms' y² coefficients and sag at the vertex: a collimated ray 1e-3 mm off the axis in the
/// y-z plane leaves at the paraxial EFL's slope (to 1e-7; leaving out the vertex sag, 7e-5).
#[test]
fn zernike_sag_closed_forms() {
    // Z37 = 924ρ¹² − 2772ρ¹⁰ + 3150ρ⁸ − 1680ρ⁶ + 420ρ⁴ − 42ρ² + 1 over a flat base.
    let s = surface(Ordering::Fringe, f64::INFINITY, 5.0, &[(37, 0.01)]);
    for (x, y) in [(0.0, 0.0), (1.0, 2.0), (-3.0, 2.5), (4.0, -3.0)] {
        let u = (x * x + y * y) / 25.0f64;
        let z37 = 924.0 * u.powi(6) - 2772.0 * u.powi(5) + 3150.0 * u.powi(4) - 1680.0 * u.powi(3)
            + 420.0 * u * u
            - 42.0 * u
            + 1.0;
        let got = s.sag_xy(x, y).unwrap();
        assert!((got - 0.01 * z37).abs() < 1e-14, "Z37 at ({x}, {y}): {got}");
    }

    // A decentred Fringe Z4: A (2 ((x − dx)² + (y − dy)²) / R² − 1) = the centred Z4 plus
    // Z2 = −4 A dx / R, Z3 = −4 A dy / R and Z1 = 2 A (dx² + dy²) / R².
    let (a, r, dx, dy) = (0.03, 6.0, 0.4, -0.7);
    let mut lens = zemax::read_file(&fixture("zernike.zmx"), &GlassCatalogs::builtin())
        .unwrap()
        .lens;
    let front = lens
        .surfaces
        .iter()
        .position(|s| s.zernike.len() == 36)
        .unwrap();
    let mut decentred = surface(Ordering::Fringe, 25.0, r, &[(4, a)]);
    decentred.shape = Shape::Zernike {
        ordering: Ordering::Fringe,
        norm_radius_mm: r,
        decenter_mm: [dx, dy],
        extrapolate: true,
    };
    let centred = surface(
        Ordering::Fringe,
        25.0,
        r,
        &[
            (1, 2.0 * a * (dx * dx + dy * dy) / (r * r)),
            (2, -4.0 * a * dx / r),
            (3, -4.0 * a * dy / r),
            (4, a),
        ],
    );
    let rays: Vec<(Vec3<f64>, Vec3<f64>)> = (0..49)
        .map(|k| {
            let (x, y) = ((k % 7) as f64 - 3.0, (k / 7) as f64 - 3.0);
            (
                Vec3::cst(x, y, -1.0),
                Vec3::cst(0.05, -0.03, 1.0).normalized(),
            )
        })
        .collect();
    let mut image = Vec::new();
    for s in [decentred, centred] {
        let mut l = lens.clone();
        l.surfaces[front] = Surface {
            d_next_mm: l.surfaces[front].d_next_mm,
            material: l.surfaces[front].material.clone(),
            semi_aperture_mm: 6.0,
            ..s
        };
        l.validate().unwrap();
        let mut b = RayBatch::<f64>::new();
        for (o, d) in &rays {
            b.push(*o, *d);
        }
        trace(
            &l.compile(),
            LAMBDA_D_NM,
            &mut b,
            TraceOptions { apertures: false },
        );
        image.push((0..rays.len()).map(|i| b.get(i)).collect::<Vec<_>>());
    }
    for (p, q) in image[0].iter().zip(&image[1]) {
        assert!(p.status.is_alive() && q.status.is_alive());
        assert!((p.o - q.o).norm() < 1e-12 && (p.d - q.d).norm() < 1e-14);
    }

    // Extrapolate = 0: beyond ρ = 1 only the base conic and the even terms are left.
    let mut s = surface(
        Ordering::Standard,
        30.0,
        4.0,
        &[(4, 0.02), (7, -0.01), (11, 0.005)],
    );
    s.asph[1] = 1e-5;
    let mut even = s.clone();
    even.shape = Shape::Even;
    even.zernike.clear();
    if let Shape::Zernike {
        ref mut extrapolate,
        ..
    } = s.shape
    {
        *extrapolate = false;
    }
    assert_eq!(s.sag_xy(3.0, 3.0), even.sag_xy(3.0, 3.0));
    assert!((s.sag_xy(2.0, 2.0).unwrap() - even.sag_xy(2.0, 2.0).unwrap()).abs() > 1e-3);

    // The even terms alone: the even asphere, ray for ray.
    let mut only_even = surface(Ordering::Standard, 25.0, 6.0, &[]);
    only_even.k = -0.8;
    only_even.asph[..3].copy_from_slice(&[1e-3, -2e-5, 3e-7]);
    let mut asphere = only_even.clone();
    asphere.shape = Shape::Even;
    let mut image = Vec::new();
    for s in [only_even, asphere] {
        lens.surfaces[front] = Surface {
            d_next_mm: lens.surfaces[front].d_next_mm,
            material: lens.surfaces[front].material.clone(),
            semi_aperture_mm: 6.0,
            ..s
        };
        let mut b = RayBatch::<f64>::new();
        for (o, d) in &rays {
            b.push(*o, *d);
        }
        trace(
            &lens.compile(),
            LAMBDA_D_NM,
            &mut b,
            TraceOptions { apertures: false },
        );
        image.push((0..rays.len()).map(|i| b.get(i)).collect::<Vec<_>>());
    }
    for (p, q) in image[0].iter().zip(&image[1]) {
        assert!(p.status.is_alive());
        assert!((p.o - q.o).norm() < 1e-12 && (p.d - q.d).norm() < 1e-14);
    }

    // Paraxial curvature: terms even in y (m = 0 and cosine m = 2, 4), centred, so that a ray
    // in the y-z plane stays there; their y² coefficients enter the EFL (Standard Z6 = √6 ρ²
    // cos 2θ adds −√6 / R² on y²).
    for ordering in [Ordering::Fringe, Ordering::Standard] {
        let terms: &[(usize, f64)] = match ordering {
            Ordering::Fringe => &[(4, 0.02), (5, -0.01), (9, 0.004), (12, 0.003), (17, 0.001)],
            Ordering::Standard => &[(4, 0.02), (6, -0.01), (11, 0.004), (12, 0.003), (14, 0.002)],
        };
        let mut l = lens.clone();
        l.surfaces[front] = Surface {
            d_next_mm: l.surfaces[front].d_next_mm,
            material: l.surfaces[front].material.clone(),
            semi_aperture_mm: 6.0,
            ..surface(ordering, 25.0, 6.0, terms)
        };
        // The back surface without its decentred terms.
        let back = front + 1;
        l.surfaces[back].shape = Shape::Even;
        l.surfaces[back].zernike.clear();
        let efl = l.paraxial(LAMBDA_D_NM).unwrap().efl_mm.unwrap();
        let h = 1e-3;
        let mut b = RayBatch::<f64>::new();
        b.push(Vec3::cst(0.0, h, -1.0), Vec3::cst(0.0, 0.0, 1.0));
        trace(
            &l.compile(),
            LAMBDA_D_NM,
            &mut b,
            TraceOptions { apertures: false },
        );
        let r = b.get(0);
        assert!(
            r.o.x == 0.0 && r.d.x == 0.0,
            "{ordering:?}: the ray left the y-z plane"
        );
        let real = -h / (r.d.y / r.d.z);
        assert!(
            (real - efl).abs() < 1e-7 * efl,
            "{ordering:?}: real-ray EFL {real} vs paraxial {efl}"
        );
        // Without the terms' y² coefficients the paraxial EFL would be far off.
        let mut plain = l.clone();
        plain.surfaces[front].zernike.clear();
        let other = plain.paraxial(LAMBDA_D_NM).unwrap().efl_mm.unwrap();
        assert!((other - efl).abs() > 0.1, "{ordering:?}: {other} vs {efl}");
    }
}

/// What the reader refuses or warns about, naming the line: a term count beyond the set, a
/// missing normalization radius, an Extrapolate flag other than 0 or 1, coefficients past
/// XDAT 1; the lens check refuses too many terms and Zernike terms on another shape.
#[test]
fn zernike_sag_errors_name_the_line() {
    let text = std::fs::read_to_string(fixture("zernike.zmx")).unwrap();
    for (from, to, want) in [
        (
            "XDAT 1 36 0 0 1 0 0 \"\"",
            "XDAT 1 38 0 0 1 0 0 \"\"",
            "XDAT 1 = 38: the number of Zernike terms must be a whole number from 0 to 37",
        ),
        (
            "XDAT 2 6 0 0 1 0 0 \"\"",
            "XDAT 2 0 0 0 1 0 0 \"\"",
            "XDAT 2 = 0: the Zernike terms need a positive normalization radius",
        ),
        ("PARM 0 1", "PARM 0 2", "PARM 0 = 2: Extrapolate is 0 or 1"),
    ] {
        assert!(text.contains(from), "{from}");
        let e = parse(&text.replacen(from, to, 1)).unwrap_err();
        assert!(e.to_string().contains(want), "{e}");
        assert!(e.to_string().contains("line "), "{e}");
    }
    let z =
        parse(&text.replacen("XDAT 1 45 0 0 1 0 0 \"\"", "XDAT 1 44 0 0 1 0 0 \"\"", 1)).unwrap();
    assert!(
        z.warnings.iter().any(|w| w
            .contains("XDAT 47 = -0.00005 ignored: beyond the 44 Zernike terms")
            || w.contains("XDAT 47 = -5e-5 ignored: beyond the 44 Zernike terms")),
        "{:?}",
        z.warnings
    );
    let mut lens = z.lens;
    let i = lens
        .surfaces
        .iter()
        .position(|s| s.zernike.len() == 36)
        .unwrap();
    lens.surfaces[i].zernike.push(0.0);
    lens.surfaces[i].zernike.push(1e-3);
    let e = lens.validate().unwrap_err().to_string();
    assert!(
        e.contains("surface 1: 38 Zernike Fringe terms: a Zernike sag surface has at most 37"),
        "{e}"
    );
    lens.surfaces[i].zernike.truncate(36);
    lens.surfaces[i].shape = Shape::Even;
    let e = lens.validate().unwrap_err().to_string();
    assert!(
        e.contains("Zernike coefficients on a surface that is not a Zernike sag surface"),
        "{e}"
    );
}
