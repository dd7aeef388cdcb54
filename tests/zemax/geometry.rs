//! Object media, overflowing terms, fold mirrors, virtual objects and afocal lenses.

use super::*;

/// An object medium (a .zmx `GLAS` on `SURF 0`, JSON `"object_medium"`): a single spherical
/// surface from water (n = 1.333) into glass (1.5) images an object as the closed form
/// n'/s' - n/s = (n' - n)/R says; the kernel traces as the scalar reference tracer; the
/// medium survives .zmx and JSON.
#[test]
fn an_object_medium_refracts_at_the_first_surface() {
    let text = "VERS 190513 80 0\nMODE SEQ\nUNIT MM X W X CM MR CPMM\nENPD 2\nFTYP 1 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nWAVM 1 0.5875618 1\nPWAV 1\nSURF 0\n  TYPE STANDARD\n  CURV 0\n  DISZ 60\n  GLAS ___BLANK 1 0 1.333 0 0 0 0 0 0 0\nSURF 1\n  STOP\n  TYPE STANDARD\n  CURV 0.05\n  DISZ 100\n  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0\n  DIAM 3 0 0 0 1 \"\"\nSURF 2\n  TYPE STANDARD\n  CURV 0\n  DISZ 0\n  DIAM 3 0 0 0 1 \"\"\n";
    let z = parse(text).unwrap();
    let lens = &z.lens;
    assert_eq!(lens.object_medium, Material::Constant(1.333));
    // n'/s' = (n' - n)/R + n/s with s = -60 mm, R = 20 mm: the image distance from the vertex.
    let (n, n2, r, s) = (1.333, 1.5, 20.0, -60.0);
    let s_img = n2 / ((n2 - n) / r + n / s);
    let p = lens.paraxial(LAMBDA_D_NM).unwrap();
    assert!(
        rel(p.image_distance_mm.unwrap(), s_img) < 1e-12,
        "{} vs {s_img}",
        p.image_distance_mm.unwrap()
    );
    // Magnification n s' / (n' s).
    let m = n * s_img / (n2 * s);
    assert!(
        rel(p.magnification, m) < 1e-12,
        "{} vs {m}",
        p.magnification
    );
    // A real ray near the axis crosses it there.
    let sys = lens.compile();
    let idx = sys.indices(LAMBDA_D_NM);
    assert_eq!((idx[0], idx[1]), (1.333, 1.5));
    let d = Vec3::cst(0.0, 1e-4, 60.0).normalized();
    let o = Vec3::cst(0.0, 0.0, -60.0);
    let rr = tolray::trace::reference::trace_ray(&sys, &idx, LAMBDA_D_NM, o, d, false, Some(0));
    let crossing = rr.o.z - rr.o.y / rr.d.y * rr.d.z;
    assert!(rel(crossing, s_img) < 1e-8, "{crossing} vs {s_img}");
    // The kernel agrees with the reference tracer, and the optical path counts the water.
    let mut b = RayBatch::<f64>::new();
    b.push(o, d);
    trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions { apertures: false });
    let full = tolray::trace::reference::trace_ray(&sys, &idx, LAMBDA_D_NM, o, d, false, None);
    let k = b.get(0);
    assert!((k.o - full.o).norm() < 1e-12 && (k.opl - full.opl).abs() < 1e-12);
    let first = (rr.o - o).norm();
    assert!(full.opl > 1.333 * first);
    // Both formats keep the medium.
    let again = parse(&zemax::to_string(lens, None)).unwrap().lens;
    assert_eq!(again.object_medium, lens.object_medium);
    let j = json::from_str(&json::to_string(lens)).unwrap();
    assert_eq!(j.object_medium, lens.object_medium);
    // An object-space NA is n sin θ in the medium, read and written so: the same lens with an
    // OBNA aperture, written back with it, keeps its entrance pupil (the writer once wrote
    // sin θ alone, and a file in water came back with a pupil 1.333 times too large; the
    // lithography lens of the corpus, in a gas of index 0.999982, by 1.9e-5).
    let obna = text.replace("ENPD 2\n", "OBNA 0.02 0\n");
    let z = parse(&obna).unwrap();
    let p = z.lens.paraxial(LAMBDA_D_NM).unwrap();
    let u = 0.5 * p.entrance_pupil_diameter_mm / (p.entrance_pupil_z_mm + 60.0);
    assert!(
        rel(1.333 * u.atan().sin(), 0.02) < 1e-12,
        "NA {}",
        1.333 * u.atan().sin()
    );
    let written = zemax::to_string(&z.lens, Some(&z.extras));
    assert!(written.contains("OBNA 0.02"), "{written}");
    let back = parse(&written).unwrap().lens.paraxial(LAMBDA_D_NM).unwrap();
    assert!(
        rel(
            back.entrance_pupil_diameter_mm,
            p.entrance_pupil_diameter_mm
        ) < 1e-12
    );
}

/// A high-order term so large that the sag's slope overflows within the traced beam gives
/// misses, never a ray whose NaN direction passes the later surfaces as alive. The file is the
/// A fuzzer finding (`overflow-r2.zmx`: the same Thorlabs file with `PARM 2 1e308`, the y² term,
/// on the cylinder's flat back): the paraxial power overflowed and `tolray info` printed an EFL
/// of -0 and a NaN exit pupil with exit status 0. The lens is refused, naming the surface.
#[test]
fn an_overflowing_r2_term_is_refused_not_a_nan_pupil() {
    let e = match zemax::read_file(&fixture("overflow-r2.zmx"), &GlassCatalogs::builtin()) {
        Ok(z) => panic!("accepted: {:?}", z.lens.paraxial(LAMBDA_D_NM)),
        Err(e) => e.message().to_string(),
    };
    assert!(
        e.contains("surface 1: paraxial curvature inf") && e.contains("r² term"),
        "{e}"
    );
}

/// fuzzer's finding of 2026-11-27 (`overflow-term.zmx`: optiland's Thorlabs LJ1598L1 file with
/// `PARM 7 -1e308` on the cylinder's flat back), whose spot centroid came out NaN with every
/// ray counted valid: now every spot statistic is finite or the field has no ray, and kernel
/// and reference tracer stop the same rays.
///
/// Also `overflow-qcon.zmx` (the Qcon singlet with its back's a_2 = -1e300, a fuzz finding of
/// 2026-11-28): a ray whose crossing runs past the range of the numbers reached the image alive
/// with NaN coordinates; it is now a miss in the kernel and the reference tracer alike.
#[test]
fn an_overflowing_asphere_term_is_a_miss_not_a_nan() {
    for file in ["overflow-term.zmx", "overflow-qcon.zmx"] {
        overflowing_term(file);
    }
}

fn overflowing_term(file: &str) {
    let z = read(file);
    let lens = &z.lens;
    let sys = lens.compile();
    let n = sys.indices(LAMBDA_D_NM);
    let para = lens.paraxial(LAMBDA_D_NM).unwrap();
    let opts = SpotOptions {
        fields: vec![Field::fraction(0.0)],
        wavelengths_nm: vec![LAMBDA_D_NM],
        pupil: Pupil::grid(16),
        trace: TraceOptions { apertures: false },
    };
    match spot_diagram(lens, &sys, &opts) {
        Ok(rows) => {
            for r in rows {
                let s = &r.stats;
                assert!(
                    s.centroid_mm.iter().all(|c| c.is_finite()) && s.rms_um.is_finite(),
                    "{s:?}"
                );
            }
        }
        Err(e) => assert!(e.message().contains("no ray reached"), "{e}"),
    }
    let set = tolray::trace::RaySet::generate(
        lens,
        &para,
        Field::fraction(0.0),
        &Pupil::grid(16),
        LAMBDA_D_NM,
    )
    .unwrap();
    let mut b = set.batch::<f64>();
    trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions { apertures: false });
    for (i, (o, d)) in set.origins.iter().zip(&set.directions).enumerate() {
        let r = tolray::trace::reference::trace_ray(&sys, &n, LAMBDA_D_NM, *o, *d, false, None);
        let k = b.get(i);
        assert_eq!(r.status.is_alive(), k.status.is_alive(), "ray {i}");
        assert!(
            !k.status.is_alive() || (k.o.x.is_finite() && k.o.y.is_finite()),
            "{file} ray {i}"
        );
    }
    // The fuzzer's fan: 5 x 5 rays parallel to the axis over half the first semi-diameter.
    let r = 0.5 * lens.surfaces[0].semi_aperture_mm;
    let mut b = RayBatch::<f64>::new();
    for i in -2..=2 {
        for j in -2..=2 {
            b.push(
                Vec3::new(r * i as f64 / 2.0, r * j as f64 / 2.0, -1.0),
                Vec3::new(0.0, 0.0, 1.0),
            );
        }
    }
    let start = b.clone();
    trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions { apertures: true });
    for i in 0..25 {
        let k = b.get(i);
        let s = start.get(i);
        let r = tolray::trace::reference::trace_ray(&sys, &n, LAMBDA_D_NM, s.o, s.d, true, None);
        assert_eq!(
            r.status.is_alive(),
            k.status.is_alive(),
            "{file} fan ray {i}"
        );
        assert!(
            !k.status.is_alive() || [k.o.x, k.o.y, k.o.z].iter().all(|v| v.is_finite()),
            "{file} fan ray {i}: {:?}",
            k.o
        );
    }
}

/// Fold mirrors: a singlet folded by a 45° mirror about x and a 30° mirror about y on a
/// decentred frame (tests/data/zemax/fold.zmx), and optiland's own five-mirror periscope with
/// mirrors off their incoming leg, trace every ray as optiland 0.6.3 does reading the same files
/// (fold_reference.json, scripts/zmxref/fold_reference.py: 147 rays in three directions each):
/// image positions in the file's frame and in the image plane's own frame to 1e-9 mm, directions
/// to 1e-11. The lens is kept unfolded (gaps along the axis, negative after a mirror) with the
/// axis' turn on each fold mirror, and survives .zmx -> JSON -> .zmx with the same geometry.
#[test]
fn fold_mirrors_trace_as_optiland_ray_by_ray() {
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("fold_reference.json")).unwrap())
            .unwrap();
    let v3 = |v: &serde_json::Value| {
        let a: Vec<f64> = (0..3).map(|i| v[i].as_f64().unwrap()).collect();
        Vec3::cst(a[0], a[1], a[2])
    };
    let run = |lens: &Lens, rays: &[serde_json::Value], dz: f64, wl: f64| {
        let mut b = RayBatch::<f64>::new();
        for r in rays {
            b.push(v3(&r["start"]) - Vec3::cst(0.0, 0.0, dz), v3(&r["dir"]));
        }
        let sys = lens.compile();
        trace(&sys, wl, &mut b, TraceOptions { apertures: false });
        (sys, b)
    };
    for (file, entry) in doc["lenses"].as_object().unwrap() {
        let z = zemax::read_file(&fixture(file), &GlassCatalogs::builtin()).unwrap();
        let lens = &z.lens;
        let folds: Vec<[f64; 3]> = (lens.surfaces.iter())
            .filter_map(|s| s.fold.map(|f| f.tilt_deg))
            .collect();
        if file == "fold.zmx" {
            assert!(z.warnings.is_empty(), "{:?}", z.warnings);
            let want = [[90.0, 0.0, 0.0], [0.0, 60.0, 0.0]];
            assert!(
                folds.len() == 2
                    && (0..2).all(|i| (0..3).all(|k| (folds[i][k] - want[i][k]).abs() < 1e-12)),
                "{folds:?}"
            );
            // Unfolded: 20 mm to the first mirror, 15 back to the second, then on to the image
            // (the second mirror's frame is decentred by 0.5 mm: 0.5 sin 60° more along the
            // turned axis, 0.5 cos 60° across it).
            let d: Vec<f64> = lens.surfaces.iter().map(|s| s.d_next_mm).collect();
            assert_eq!(d[..4], [2.0, 4.0, 20.0, -15.0]);
            assert!((d[4] - (18.5 + 0.5 * 60f64.to_radians().sin())).abs() < 1e-12);
            assert!((lens.image_plane.decenter_mm[0] - 0.25).abs() < 1e-12);
        } else {
            assert_eq!(folds.len(), 5, "{file}");
        }
        let wl = entry["wavelength_um"].as_f64().unwrap() * 1e3;
        let rays = entry["rays"].as_array().unwrap();
        assert_eq!(rays.len(), 147);
        let dz = z.extras.first_vertex_mm[2];
        let (sys, b) = run(lens, rays, dz, wl);
        let mut worst = [0.0f64; 3];
        for (i, r) in rays.iter().enumerate() {
            let k = b.get(i);
            assert!(k.status.is_alive(), "{file} ray {i}: {:?}", k.status);
            let want = v3(&r["image"]) - Vec3::cst(0.0, 0.0, dz);
            worst[0] = worst[0].max((k.o - want).norm());
            worst[1] = worst[1].max((k.d - v3(&r["image_dir"])).norm());
            let l = sys.image.point_to_local(k.o);
            let wl_ = v3(&r["local"]);
            worst[2] = worst[2].max((l.x - wl_.x).hypot(l.y - wl_.y));
        }
        assert!(
            worst[0] < 1e-9 && worst[1] < 1e-11 && worst[2] < 1e-9,
            "{file}: worst position {:e} mm, direction {:e}, in the image frame {:e} mm",
            worst[0],
            worst[1],
            worst[2]
        );
        // Through .zmx and JSON: the same folds and the same rays.
        let back = parse(&zemax::to_string(lens, None)).unwrap().lens;
        let j = json::from_str(&json::to_string(&back)).unwrap();
        for other in [&back, &j] {
            let (_, b2) = run(other, rays, dz, wl);
            let worst = (0..rays.len())
                .map(|i| (b2.get(i).o - b.get(i).o).norm())
                .fold(0.0, f64::max);
            assert!(
                worst < 1e-9,
                "{file}: round trip moves rays by {worst:e} mm"
            );
            let f2: Vec<[f64; 3]> = (other.surfaces.iter())
                .filter_map(|s| s.fold.map(|f| f.tilt_deg))
                .collect();
            assert_eq!(f2, folds, "{file}");
        }
        assert_eq!(j, back, "{file}: JSON round trip");
    }
}

/// A fabricated folded lens (a tolerance pattern, and the first fold mirror moved along and
/// across its leg and tilted) bakes into a prescription that traces as the nominal lens with the
/// adjustments: the moved fold mirror keeps its downstream optics in place through the fold's
/// pivot. The baked lens survives .zmx (its frames written as coordinate breaks) with the same
/// rays.
#[test]
fn fabricated_fold_mirror_systems_bake_and_round_trip() {
    use tolray::tolerance::ToleranceSpec;
    let lens = read("fold.zmx").lens;
    let p = ToleranceSpec::default().sample(&lens, 3, 7).unwrap();
    let (perturbed, mut adj) = p.apply(&lens).unwrap();
    adj.surface_motion[3] = tolray::math::Rigid {
        rotation: tolray::math::Mat3::from_tilt_deg(0.2, -0.1, 0.0),
        translation: adj.surface_motion[3].translation + Vec3::new(0.02, -0.03, 0.05),
    };
    let baked = perturbed.with_adjustments(&adj).unwrap();
    let pivot = baked.surfaces[3].fold.unwrap().pivot_mm;
    assert!(pivot != 0.0, "the mirror moved along its leg: {pivot}");
    let moved: System<f64> = System::compile(&perturbed, &adj, &|_, v| v);
    let nominal = lens.compile();
    assert_same_trace(&moved, &baked.compile(), 1e-9, "baked");
    // The perturbation changes the rays (else the check above proves nothing).
    let (a, b) = (trace_fan(&nominal, 0.0), trace_fan(&moved, 0.0));
    let shift = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x.2 && y.2)
        .map(|(x, y)| (x.0 - y.0).norm())
        .fold(0.0, f64::max);
    assert!(shift > 1e-3, "{shift}");
    let back = parse(&zemax::to_string(&baked, None)).unwrap();
    assert!(back.warnings.is_empty(), "{:?}", back.warnings);
    assert_same_trace(&back.lens.compile(), &baked.compile(), 1e-9, "read back");
    assert_eq!(json::from_str(&json::to_string(&baked)).unwrap(), baked);
}

/// An 8 x 8 pupil grid's rays (at least 40 inside the pupil) from object height `h` mm, aimed or
/// not, at the d line.
fn grid_rays(lens: &Lens, p: &tolray::lens::Paraxial, h: f64, aim: bool) -> tolray::trace::RaySet {
    let pupil = Pupil {
        pattern: PupilPattern::Grid(8),
        scale: 1.0,
        aim,
    };
    let field = Field::HeightMm { x: 0.0, y: h };
    let set = tolray::trace::RaySet::generate(lens, p, field, &pupil, LAMBDA_D_NM).unwrap();
    assert!(set.origins.len() > 40);
    set
}

/// A virtual object (OpticStudio's negative object thickness): a singlet meets a beam that
/// converges on a point 50 mm behind its first vertex (tests/data/zemax/virtual-object.zmx).
/// The paraxial image distance and magnification agree with the refraction equation surface by
/// surface (n'/s' = n/s + (n' - n)/R, worked here independently of tolray's paraxial code);
/// every generated ray, for both of the file's fields and with ray aiming, lies on the line
/// through its pupil point and the object point and starts in front of the lens; the real chief
/// ray meets the paraxial image plane at the paraxial image height (to the third-order distortion
/// of a 1.5 mm object, 1e-3 relative); JSON (DeepLens' positive `obj_depth`) and .zmx keep it.
#[test]
fn a_virtual_object_is_a_converging_beam() {
    let z = read("virtual-object.zmx");
    let lens = &z.lens;
    assert_eq!(lens.object, Object::Finite { distance_mm: -50.0 });
    let p = lens.paraxial(LAMBDA_D_NM).unwrap();
    // Surface by surface: the object 48 mm behind the front surface (z = 2), n = 1.5168.
    let n = 1.5168;
    let s1 = n / (1.0 / 48.0 + (n - 1.0) / 40.0);
    let s2 = 1.0 / (n / (s1 - 4.0) + (1.0 - n) / -100.0);
    let m = (s1 / (n * 48.0)) * (n * s2 / (s1 - 4.0));
    assert!(
        (p.image_distance_mm.unwrap() - s2).abs() < 1e-10,
        "{} vs {s2}",
        p.image_distance_mm.unwrap()
    );
    assert!(
        (p.magnification - m).abs() < 1e-12,
        "{} vs {m}",
        p.magnification
    );
    let q = |h: f64| Vec3::cst(0.0, h, 50.0);
    for (h, aim) in [(0.0, false), (1.5, false), (1.5, true)] {
        let set = grid_rays(lens, &p, h, aim);
        for (o, d) in set.origins.iter().zip(&set.directions) {
            assert!(o.z < 0.0, "starts in front of the lens: {o:?}");
            // The line o + t d passes through the object point.
            let t = (50.0 - o.z) / d.z;
            let miss = (*o + *d * t - q(h)).norm();
            assert!(
                miss < 1e-12,
                "h {h} aim {aim}: {miss:e} mm off the object point"
            );
        }
    }
    // The chief ray of the 1.5 mm object at the paraxial image plane.
    let mut at_focus = lens.clone();
    at_focus.surfaces.last_mut().unwrap().d_next_mm = s2;
    let sys = at_focus.compile();
    let set = tolray::trace::RaySet::generate(
        &at_focus,
        &at_focus.paraxial(LAMBDA_D_NM).unwrap(),
        Field::HeightMm { x: 0.0, y: 1.5 },
        &Pupil::grid(4),
        LAMBDA_D_NM,
    )
    .unwrap();
    let mut b = RayBatch::<f64>::new();
    b.push(set.chief.0, set.chief.1);
    trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions { apertures: false });
    let y = b.get(0).o.y;
    assert!((y - 1.5 * m).abs() < 1e-3 * 1.5 * m, "{y} vs {}", 1.5 * m);
    // Both formats keep the virtual object.
    let j = json::to_string(lens);
    assert!(j.contains("\"obj_depth\": 50.0"), "{j}");
    assert_eq!(json::from_str(&j).unwrap().object, lens.object);
    let back = parse(&zemax::to_string(lens, None)).unwrap().lens;
    assert_eq!(back.object, lens.object);
}

/// The object on the first surface (OpticStudio's object thickness 0): a source on the flat
/// face of a plano-convex lens, relayed by a biconvex lens (tests/data/zemax/object-on-surface.zmx,
/// object heights and an object-space NA). The paraxial image distance and magnification agree
/// with the refraction equation surface by surface (worked here, independently of tolray's
/// paraxial code; optiland's magnification from the same file is -1.6898237608998985), and the
/// entrance pupil with the file's NA (its radius is the pupil distance times tan asin 0.1);
/// every generated ray, also with ray aiming, starts at the object point on the first vertex's
/// plane; the chief ray's wavefront error is 0 there; a field angle (which names no point on
/// that plane) and an entrance pupil on the object plane are refused with the reason; the
/// object stays put when the first surface moves away from it; JSON and .zmx keep it. (Its rays
/// land where optiland's do: `file_fields_and_vignetting_launch_the_rays_opticstudio_means`.)
#[test]
fn an_object_on_the_first_surface_launches_from_it() {
    let z = read("object-on-surface.zmx");
    // (Its only warning: surfaces without a DIAM are sized to the paraxial beam.)
    assert!(
        z.warnings.len() == 1 && z.warnings[0].contains("no semi-diameter (DIAM) given"),
        "{:?}",
        z.warnings
    );
    let lens = &z.lens;
    assert_eq!(lens.object, Object::Finite { distance_mm: 0.0 });
    let p = lens.paraxial(LAMBDA_D_NM).unwrap();
    // n'/s' = n/s + (n' - n)/R from the object 5 mm inside the first lens (its flat face images
    // the object onto itself), with the magnification n s' / (n' s) of each surface.
    let (n1, n2) = (1.5168, 1.6727);
    let refract = |n: f64, s: f64, n_: f64, r: f64| {
        let s_ = n_ / (n / s + (n_ - n) / r);
        (s_, n * s_ / (n_ * s))
    };
    let (s2, m2) = refract(n1, -5.0, 1.0, -5.0);
    let (s4, m4) = refract(1.0, s2 - 2.0, n2, 5.0);
    let (s5, m5) = refract(n2, s4 - 3.0, 1.0, -5.0);
    let m = m2 * m4 * m5;
    assert!(
        (p.image_distance_mm.unwrap() - s5).abs() < 1e-10,
        "{p:?} vs {s5}"
    );
    assert!(
        (p.magnification - m).abs() < 1e-12,
        "{} vs {m}",
        p.magnification
    );
    assert!((m + 1.6898237608998985).abs() < 1e-12, "{m}");
    let r_ep = p.entrance_pupil_z_mm * 0.1f64.asin().tan();
    assert!(
        (p.entrance_pupil_diameter_mm / 2.0 - r_ep).abs() < 1e-12,
        "{p:?}"
    );
    for (h, aim) in [(0.0, false), (0.5, false), (0.5, true)] {
        let set = grid_rays(lens, &p, h, aim);
        for o in set.origins.iter().chain([&set.chief.0]) {
            assert_eq!(*o, Vec3::cst(0.0, h, 0.0), "h {h} aim {aim}");
        }
    }
    let sys = lens.compile();
    let pts = [[0.0, 0.0], [0.6, 0.0], [0.0, 0.6], [0.0, -0.6], [0.4, 0.4]];
    let w = tolray::wave::wavefront_at(
        lens,
        &sys,
        Field::HeightMm { x: 0.0, y: 0.5 },
        LAMBDA_D_NM,
        &pts,
        &[1.0; 5],
        &tolray::wave::WaveOptions::default(),
    )
    .unwrap();
    assert_eq!(w.pupil.len(), 5);
    assert!(w.opd_waves[0].abs() < 1e-9, "{:?}", w.opd_waves);
    assert!(w.opd_waves.iter().all(|v| v.is_finite() && v.abs() < 10.0));
    // An angle about the first vertex names no point on its plane.
    for f in [Field::angle(2.0), Field::fraction(0.5)] {
        let err =
            tolray::trace::RaySet::generate(lens, &p, f, &Pupil::grid(4), LAMBDA_D_NM).unwrap_err();
        assert!(
            err.message().contains("object distance 0") && err.message().contains("height"),
            "{}",
            err.message()
        );
    }
    // The stop on the first surface puts the entrance pupil on the object plane; 30 mm behind
    // the plano-convex lens (past its focus), the stop's image lies in front of the object.
    let mut on_plane = lens.clone();
    for (i, s) in on_plane.surfaces.iter_mut().enumerate() {
        s.is_stop = i == 0;
    }
    let err = on_plane.paraxial(LAMBDA_D_NM).unwrap_err();
    assert!(
        err.message()
            .contains("entrance pupil lies on the object plane"),
        "{}",
        err.message()
    );
    let mut in_front = lens.clone();
    in_front.surfaces[1].d_next_mm = 30.0;
    let p = in_front.paraxial(LAMBDA_D_NM).unwrap();
    assert!(p.entrance_pupil_z_mm < 0.0, "{p:?}");
    let f = Field::HeightMm { x: 0.0, y: 0.5 };
    let err = tolray::trace::RaySet::generate(&in_front, &p, f, &Pupil::grid(4), LAMBDA_D_NM)
        .unwrap_err();
    assert!(
        err.message().contains("entrance pupil is not behind it"),
        "{}",
        err.message()
    );
    // The object stays where it is when the first surface moves away from it.
    let mut adj = Adjustments::none(lens.surfaces.len());
    adj.surface_motion[0].translation = Vec3::cst(0.0, 0.0, 0.01);
    let moved = lens.with_adjustments(&adj).unwrap();
    assert_eq!(moved.object, Object::Finite { distance_mm: 0.01 });
    // Both formats keep it.
    let back = json::from_str(&json::to_string(lens)).unwrap();
    assert_eq!(back.object, lens.object);
    let back = parse(&zemax::to_string(lens, None)).unwrap().lens;
    assert_eq!(back.object, lens.object);
    let image = |l: &Lens| {
        let p = l.paraxial(LAMBDA_D_NM).unwrap();
        let f = Field::HeightMm { x: 0.2, y: 0.5 };
        let set = tolray::trace::RaySet::generate(l, &p, f, &Pupil::grid(8), LAMBDA_D_NM).unwrap();
        let mut b = set.batch::<f64>();
        trace(
            &l.compile(),
            LAMBDA_D_NM,
            &mut b,
            TraceOptions { apertures: false },
        );
        b.iter()
            .map(|r| (r.o, r.status.is_alive()))
            .collect::<Vec<_>>()
    };
    let (a, b) = (image(lens), image(&back));
    assert!(a.iter().filter(|r| r.1).count() > 40);
    for (x, y) in a.iter().zip(&b) {
        assert!(x.1 == y.1 && (x.0 - y.0).norm() < 1e-12, "{x:?} vs {y:?}");
    }
}

/// A real-glass afocal lens in OpticStudio's afocal image space: a Keplerian 2x reducer of two
/// N-BK7 plano-convex lenses (tests/data/zemax/keplerian.zmx, spaced so that a paraxial ray
/// leaves parallel) reads as afocal with angular magnification -2 (the lenses' focal lengths
/// scale with their radii, 51.68 and 25.84 mm); its angular spots at the file's three fields
/// (3228 rays each) agree with the angles of optiland's rays through the same file
/// (scripts/zmxref/afocal_reference.py): the RMS angular radius about the centroid and about
/// the chief ray in µrad and the centroid in mrad, to 1e-9 relative. The spherical aberration
/// of its plano-convex lenses spreads the beam leaving it by 208 µrad RMS on the axis.
#[test]
fn an_afocal_lens_has_optiland_s_angular_spots() {
    let z = read("keplerian.zmx");
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    let lens = z.lens;
    let p = lens.paraxial(lens.primary_wavelength_nm).unwrap();
    assert!(p.is_afocal() && p.efl_mm.is_none(), "{p:?}");
    assert!((p.angular_magnification.unwrap() + 2.0).abs() < 1e-12);
    // Off the design wavelength its focal length is long but finite (chromatic).
    let f = lens.paraxial(LAMBDA_F_NM).unwrap().efl_mm;
    assert!(f.unwrap().abs() > 1e3, "{f:?}");
    let r: serde_json::Value = serde_json::from_str(&text("afocal_reference.json")).unwrap();
    let opts = SpotOptions {
        fields: lens.fields.iter().map(|f| f.field).collect(),
        wavelengths_nm: vec![lens.primary_wavelength_nm],
        pupil: Pupil::grid(64),
        trace: TraceOptions { apertures: false },
    };
    let (rows, failures) =
        tolray::analysis::afocal_spot_diagram_rows(&lens, &lens.compile(), &opts).unwrap();
    assert!(failures.is_empty() && rows.len() == 3);
    let fields = r["fields"].as_array().unwrap();
    for (row, f) in rows.iter().zip(fields) {
        let num = |k: &str| f[k].as_f64().unwrap();
        let s = &row.stats;
        assert!(row.angular);
        assert_eq!(s.n_valid as u64, f["n_rays"].as_u64().unwrap());
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1e-3);
        assert!(close(s.rms_um, num("rms_urad")), "{s:?} vs {f}");
        assert!(
            close(s.rms_chief_um.unwrap(), num("rms_chief_urad")),
            "{s:?} vs {f}"
        );
        let c = f["centroid_mrad"].as_array().unwrap();
        for (got, want) in s.centroid_mm.iter().zip(c) {
            assert!((got - want.as_f64().unwrap()).abs() < 1e-9, "{s:?} vs {f}");
        }
    }
    assert!(rows[0].stats.rms_um > 200.0 && rows[0].stats.rms_um < 210.0);
}

/// A fold mirror with the next surface at its vertex (a gap of 0 after the fold) keeps its fold
/// through .zmx. The reader tells a fold from a tilted mirror by the frame the coordinate breaks
/// after the mirror leave, up to the first that moves along the axis; with none moving, the
/// next surface's own tilt joined the fold's (fuzz --seed 5 --target zmx: a 12-degree fold read
/// back as a tilted mirror, EFL 111.397 -> 113.744 mm). Here: a mirror tilted 10 degrees (a
/// 20-degree fold, below the angle that makes any mirror a fold) followed at its vertex by a bare
/// aperture tilted 3 degrees. The writer closes the fold's breaks with a flat dummy surface; the
/// lens reads back with its fold, the same first-order data and the same rays.
#[test]
fn a_fold_followed_at_its_vertex_by_a_tilted_surface_keeps_its_fold() {
    let mut lens =
        json::read_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fold.json"))
            .unwrap();
    let (s, c) = 10f64.to_radians().sin_cos();
    lens.surfaces[3].vec_local = [0.0, -s, c];
    lens.surfaces[3].fold = Some(tolray::lens::Fold {
        tilt_deg: [20.0, 0.0, 0.0],
        pivot_mm: 0.0,
    });
    let mut stop = tolray::lens::Surface::stop(30.0, lens.surfaces[3].d_next_mm);
    let (s3, c3) = 3f64.to_radians().sin_cos();
    stop.vec_local = [0.0, s3, c3];
    stop.is_stop = false;
    lens.surfaces[3].d_next_mm = 0.0;
    lens.surfaces.insert(4, stop);
    // (A stop and mirrors large enough for the fan of the check below.)
    lens.surfaces[0].semi_aperture_mm = 6.0;
    for s in &mut lens.surfaces[3..] {
        s.semi_aperture_mm = 30.0;
    }
    lens.validate().unwrap();
    let text = zemax::to_string(&lens, None);
    let back = parse(&text).unwrap().lens;
    assert_eq!(back.surfaces.len(), lens.surfaces.len(), "{text}");
    let fold = back.surfaces[3].fold.expect("the fold is kept");
    assert!(
        (fold.tilt_deg[0] - 20.0).abs() < 1e-12 && fold.pivot_mm == 0.0,
        "{fold:?}"
    );
    assert_paraxial_equal(&lens, &back, "fold, then a tilted surface at its vertex");
    assert_same_trace(&lens.compile(), &back.compile(), 1e-9, "read back");
    // The dummy is what keeps it: without it the reader joins the aperture's tilt to the fold.
    let dummy = "TYPE STANDARD\r\n  CURV 0\r\n  DISZ 0\r\nSURF";
    let k = text.find(dummy).expect("the dummy surface");
    let without = format!(
        "{}TYPE COORDBRK\r\n  DISZ 0\r\nSURF{}",
        &text[..k],
        &text[k + dummy.len()..]
    );
    let joined = parse(&without).unwrap().lens;
    assert_eq!(joined.surfaces[3].fold, None);
}
