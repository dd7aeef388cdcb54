//! The fast kernel against the independent scalar reference tracer, closed forms, per-ray
//! statuses and thread-count invariance.

use rand::{Rng, SeedableRng};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{Adjustments, GlassCatalogs, Material, Surface, System};
use tolray::math::{Mat3, Rigid, Vec3};
use tolray::trace::reference::trace_ray;
use tolray::trace::{trace, RayBatch, RayStatus, TraceOptions};
use tolray::{Lens, Object};

/// Random rays aimed roughly at the lens' first surface from a plane in front of it.
fn random_rays(lens: &Lens, n: usize, seed: u64) -> Vec<(Vec3<f64>, Vec3<f64>)> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let r = lens.surfaces[0].semi_aperture_mm.min(15.0);
    (0..n)
        .map(|_| {
            let o = Vec3::new(rng.random_range(-r..r), rng.random_range(-r..r), -5.0);
            let d = Vec3::new(
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
                1.0,
            );
            (o, d)
        })
        .collect()
}

/// An aspheric singlet (even asphere front, conic back) to exercise the Newton path.
fn asphere_lens() -> Lens {
    let mut l = Lens::load("lens1").unwrap();
    let mut s0 = Surface::sphere(1.0 / 30.0, 10.0, 5.0, Material::parse("N-BK7").unwrap());
    s0.k = -0.8;
    s0.asph = [0.0, 2e-5, -3e-8, 1e-10, 0.0, 0.0, 0.0, 0.0];
    let mut s1 = Surface::sphere(-1.0 / 60.0, 10.0, 50.0, Material::Air);
    s1.k = 1.5;
    l.surfaces = vec![s0, s1];
    l.object = Object::Infinite;
    l
}

/// A perturbed copy: element moves and tilts on some surfaces, image tilted.
fn perturbed(lens: &Lens) -> Adjustments {
    let n = lens.surfaces.len();
    let mut adj = Adjustments::none(n);
    for i in 0..n {
        let r = Mat3::from_tilt_deg(0.3 * i as f64, -0.2, 0.1);
        adj.surface_motion[i] = Rigid::about_pivot(
            r,
            Vec3::new(0.0, 0.0, i as f64),
            Vec3::new(0.02, -0.03, 0.01),
        );
        adj.curvature_offset[i] = 1e-4;
    }
    adj.image_motion = Rigid::about_pivot(
        Mat3::from_tilt_deg(0.5, 0.5, 0.0),
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, 0.0),
    );
    adj
}

fn lenses() -> Vec<(String, Lens)> {
    let mut v: Vec<(String, Lens)> = ["lens1", "lens2", "cooke-triplet"]
        .iter()
        .map(|n| (n.to_string(), Lens::load(n).unwrap()))
        .collect();
    v.push(("asphere".into(), asphere_lens()));
    v.push(("cassegrain".into(), cassegrain()));
    v.push(("toroid".into(), zmx("toroid.zmx")));
    v.push(("odd asphere".into(), zmx("oddasphere.zmx")));
    v.push(("ideal thin lens".into(), zmx("thinlens.zmx")));
    v.push(("Q-type aspheres".into(), zmx("qbfs.zmx")));
    v.push(("Qcon aspheres".into(), zmx("qcon.zmx")));
    v.push(("Zernike sag surfaces".into(), zmx("zernike.zmx")));
    v.push(("diffractive phase".into(), zmx("binary2.zmx")));
    // (The primary's annular aperture, 85 to 180 mm, would stop every test ray: opened.)
    let mut m = zmx("zernike-mirrors.zmx");
    m.surfaces[0].aperture = None;
    v.push(("Zernike sag mirrors".into(), m));
    // The toroid's front turned the other way about x (a negative radius of rotation).
    let mut t = zmx("toroid.zmx");
    t.surfaces[1].shape = tolray::lens::Shape::Toroidal { c_rot: -1.0 / 30.0 };
    v.push(("toroid, negative rotation".into(), t));
    v
}

/// A hand-made test lens of tests/data/zemax.
fn zmx(name: &str) -> Lens {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zemax/").to_string() + name;
    tolray::lens::zemax::read_file(std::path::Path::new(&path), &GlassCatalogs::builtin())
        .unwrap()
        .lens
}

/// A two-mirror telescope (tests/data/cassegrain.json): reflections, negative gaps after the
/// primary, conic mirrors.
fn cassegrain() -> Lens {
    Lens::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/cassegrain.json"
    ))
    .unwrap()
}

/// Mirrors against closed forms: a parabolic primary focuses every ray parallel to its axis at
/// its focus (z = R/2 in front of it, wherever the ray hits), and the Cassegrain images an axial
/// point perfectly; each reflected direction obeys the law of reflection.
#[test]
fn mirrors_reflect_to_their_closed_forms() {
    let mut lens = cassegrain();
    // The primary alone, image plane at its focus (200 mm in front of it, toward -z).
    lens.surfaces.truncate(1);
    lens.surfaces[0].d_next_mm = -200.0;
    let sys = lens.compile();
    let mut b = RayBatch::<f64>::new();
    let pts: Vec<(f64, f64)> = (0..400)
        .map(|k| {
            (
                -45.0 + 90.0 * (k % 20) as f64 / 19.0,
                -45.0 + 90.0 * (k / 20) as f64 / 19.0,
            )
        })
        .filter(|(x, y)| x * x + y * y < 49.0 * 49.0)
        .collect();
    for &(x, y) in &pts {
        b.push(Vec3::new(x, y, -10.0), Vec3::new(0.0, 0.0, 1.0));
    }
    trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
    for (i, &(x, y)) in pts.iter().enumerate() {
        let r = b.get(i);
        assert!(r.status.is_alive(), "{x} {y}: {:?}", r.status);
        assert!(
            r.o.x.abs() < 1e-12 && r.o.y.abs() < 1e-12,
            "{x} {y}: {:?}",
            r.o
        );
        assert!((r.o.z + 200.0).abs() < 1e-12);
        // The reflected ray points at the focus from the hit on the sag z = c ρ² / 2 = -ρ²/800.
        let hit = Vec3::new(x, y, -(x * x + y * y) / 800.0);
        let want = (Vec3::new(0.0, 0.0, -200.0) - hit).normalized();
        assert!(
            (r.d - want).norm() < 1e-13,
            "{x} {y}: {:?} vs {want:?}",
            r.d
        );
        // OPL from z = -10 to the focus is the same for every ray (Fermat): 10 + 200.
        assert!((r.opl - 210.0).abs() < 1e-10, "{x} {y}: OPL {}", r.opl);
    }
    // The full Cassegrain: perfect on axis (its primary and secondary are the classical conics).
    let lens = cassegrain();
    let p = lens.paraxial(LAMBDA_D_NM).unwrap();
    assert!(
        (p.efl_mm.unwrap() - 800.0).abs() < 1e-9 && (p.bfd_mm.unwrap() - 200.0).abs() < 1e-9,
        "{p:?}"
    );
    let mut b = RayBatch::<f64>::new();
    for &(x, y) in &pts {
        b.push(Vec3::new(x, y, -10.0), Vec3::new(0.0, 0.0, 1.0));
    }
    trace(
        &lens.compile(),
        LAMBDA_D_NM,
        &mut b,
        TraceOptions { apertures: false },
    );
    for i in 0..pts.len() {
        let r = b.get(i);
        assert!(r.o.x.abs() < 1e-10 && r.o.y.abs() < 1e-10, "{:?}", r.o);
        assert!((r.o.z - 50.0).abs() < 1e-12);
    }
}

#[test]
fn kernel_matches_reference_tracer_f64() {
    for (name, lens) in lenses() {
        for (adj, clip) in [
            (Adjustments::none(lens.surfaces.len()), true),
            (perturbed(&lens), true),
            (perturbed(&lens), false),
        ] {
            let sys: System<f64> = System::compile(&lens, &adj, &|_, v| v);
            let n = sys.indices(LAMBDA_D_NM);
            let rays = random_rays(&lens, 2000, 1);
            let mut b = RayBatch::<f64>::new();
            for (o, d) in &rays {
                b.push(*o, *d);
            }
            trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions { apertures: clip });
            let mut alive = 0;
            for (i, (o, d)) in rays.iter().enumerate() {
                let r = trace_ray(&sys, &n, LAMBDA_D_NM, *o, *d, clip, None);
                let k = b.get(i);
                assert_eq!(
                    k.status, r.status,
                    "{name} ray {i} {o:?} {d:?} {:?} {:?}",
                    k.o, r.o
                );
                if r.status.is_alive() {
                    alive += 1;
                    assert!(
                        (k.o - r.o).norm() < 1e-9,
                        "{name} ray {i}: {:?} vs {:?}",
                        k.o,
                        r.o
                    );
                    assert!((k.d - r.d).norm() < 1e-11, "{name} ray {i} direction");
                    assert!((k.opl - r.opl).abs() < 1e-9, "{name} ray {i} OPL");
                }
            }
            assert!(
                alive > 100,
                "{name}: only {alive} rays survived; the test would prove little"
            );
        }
    }
}

#[test]
fn f32_kernel_agrees_with_f64() {
    for (name, lens) in lenses() {
        let sys64 = lens.compile();
        let sys32: System<f32> = sys64.convert();
        let rays = random_rays(&lens, 2000, 2);
        let mut b64 = RayBatch::<f64>::new();
        let mut b32 = RayBatch::<f32>::new();
        for (o, d) in &rays {
            b64.push(*o, *d);
            b32.push(*o, *d);
        }
        trace(&sys64, LAMBDA_D_NM, &mut b64, TraceOptions::default());
        trace(&sys32, LAMBDA_D_NM, &mut b32, TraceOptions::default());
        let mut worst = 0.0f64;
        for i in 0..rays.len() {
            let (a, b) = (b64.get(i), b32.get(i));
            if a.status.is_alive() && b.status.is_alive() {
                worst = worst.max((a.o - b.o.map_value()).norm());
            }
        }
        // f32 carries ~7 digits over a ~100 mm track: a few tenths of a micrometre.
        assert!(worst < 1e-3, "{name}: f32 deviates {worst} mm");
    }
}

#[test]
fn pure_a2_asphere_equals_the_paraboloid_closed_form() {
    // sag = a2 ρ² is exactly the paraboloid c = 2 a2, k = -1.
    let mut a = asphere_lens();
    a.surfaces[0] = Surface {
        c: 0.0,
        k: 0.0,
        asph: [0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ..a.surfaces[0].clone()
    };
    let mut q = a.clone();
    q.surfaces[0] = Surface {
        c: 0.02,
        k: -1.0,
        asph: [0.0; 8],
        ..a.surfaces[0].clone()
    };
    let rays = random_rays(&a, 500, 3);
    let run = |l: &Lens| {
        let mut b = RayBatch::<f64>::new();
        for (o, d) in &rays {
            b.push(*o, *d);
        }
        trace(&l.compile(), LAMBDA_D_NM, &mut b, TraceOptions::default());
        b
    };
    let (ba, bq) = (run(&a), run(&q));
    for i in 0..rays.len() {
        assert_eq!(ba.get(i).status, bq.get(i).status);
        if ba.get(i).status.is_alive() {
            assert!((ba.get(i).o - bq.get(i).o).norm() < 1e-10);
        }
    }
}

#[test]
fn statuses_name_the_surface() {
    let mut l = asphere_lens();
    // Glass block whose exit face is tilted 50 degrees: an axial ray hits it beyond the
    // critical angle of n = 1.5 (41.8 degrees).
    l.surfaces = vec![
        Surface::sphere(0.0, 50.0, 10.0, Material::Constant(1.5)),
        Surface::sphere(0.0, 50.0, 10.0, Material::Air),
    ];
    let mut adj = Adjustments::none(2);
    adj.surface_motion[1] = Rigid::about_pivot(
        Mat3::from_tilt_deg(50.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, 10.0),
        Vec3::new(0.0, 0.0, 0.0),
    );
    let sys: System<f64> = System::compile(&l, &adj, &|_, v| v);
    let mut b = RayBatch::<f64>::new();
    b.push(Vec3::new(0.0, 0.0, -1.0), Vec3::new(0.0, 0.0, 1.0));
    b.push(Vec3::new(0.0, 60.0, -1.0), Vec3::new(0.0, 0.0, 1.0));
    trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
    assert_eq!(b.get(0).status, RayStatus::Tir(1));
    assert_eq!(b.get(1).status, RayStatus::Vignetted(0));
    // A ray passing beside a strongly curved sphere misses it.
    l.surfaces[0].c = 0.1;
    l.surfaces[0].semi_aperture_mm = 9.0;
    let mut b = RayBatch::<f64>::new();
    b.push(Vec3::new(0.0, 20.0, -1.0), Vec3::new(0.0, 0.0, 1.0));
    trace(
        &l.compile(),
        LAMBDA_D_NM,
        &mut b,
        TraceOptions { apertures: false },
    );
    assert_eq!(b.get(0).status, RayStatus::Missed(0));
}

#[test]
fn results_do_not_depend_on_thread_count() {
    let lens = Lens::load("lens2").unwrap();
    let sys = lens.compile();
    let rays = random_rays(&lens, 20_000, 4);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut b = RayBatch::<f32>::new();
        for (o, d) in &rays {
            b.push(*o, *d);
        }
        pool.install(|| {
            trace(
                &sys.convert::<f32>(),
                LAMBDA_D_NM,
                &mut b,
                TraceOptions::default(),
            )
        });
        b.iter()
            .map(|r| (r.o.x.to_bits(), r.o.y.to_bits(), r.status))
            .collect::<Vec<_>>()
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn aimed_rays_cross_the_real_stop_where_asked() {
    use tolray::trace::{Field, Pupil, RaySet};
    for name in ["lens2", "cooke-triplet"] {
        let lens = Lens::load(name).unwrap();
        let para = lens.paraxial(LAMBDA_D_NM).unwrap();
        let stop = para.stop_surface;
        let r_stop = lens.surfaces[stop].semi_aperture_mm;
        let pupil = Pupil {
            pattern: tolray::trace::PupilPattern::Hex(3),
            scale: 1.0,
            aim: true,
        };
        let set =
            RaySet::generate(&lens, &para, Field::fraction(1.0), &pupil, LAMBDA_D_NM).unwrap();
        let sys = lens.compile();
        let n = sys.indices(LAMBDA_D_NM);
        for ((o, d), q) in set.origins.iter().zip(&set.directions).zip(&set.pupil) {
            let r = trace_ray(&sys, &n, LAMBDA_D_NM, *o, *d, false, Some(stop));
            let p = r.o - sys.rows[stop].pos;
            assert!(
                (p.x - q[0] * r_stop).abs() < 1e-9 && (p.y - q[1] * r_stop).abs() < 1e-9,
                "{name}: {p:?} vs {q:?}"
            );
        }
        let r = trace_ray(
            &sys,
            &n,
            LAMBDA_D_NM,
            set.chief.0,
            set.chief.1,
            false,
            Some(stop),
        );
        assert!(
            (r.o - sys.rows[stop].pos).norm() < 1e-9,
            "{name}: the aimed chief ray passes the stop centre"
        );
    }
}

/// Rays are half-lines: a ray launched away from the lens, or starting behind a surface, stops
/// with `Backward` at that surface in the kernel and the reference tracer alike, instead of
/// landing where the forward ray lands (defect 1 of the outside review).
#[test]
fn rays_behind_a_surface_stop_unless_the_lens_asks_for_virtual_propagation() {
    let lens = Lens::load("lens1").unwrap();
    let sys = lens.compile();
    let n = sys.indices(LAMBDA_D_NM);
    let z_last = *lens.vertex_z_mm().last().unwrap();
    let cases = [
        // Heading away from the lens.
        (Vec3::new(0.0, 0.0, -10.0), Vec3::new(0.0, 0.0, -1.0), 0),
        // Starting behind the last surface, heading to the image: surface 0 lies behind it.
        (
            Vec3::new(0.0, 0.5, z_last + 1.0),
            Vec3::new(0.0, 0.0, 1.0),
            0,
        ),
    ];
    for (o, d, surf) in cases {
        let mut b = RayBatch::<f64>::new();
        b.push(o, d);
        trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
        assert_eq!(b.get(0).status, RayStatus::Backward(surf), "{o:?} {d:?}");
        let r = trace_ray(&sys, &n, LAMBDA_D_NM, o, d, true, None);
        assert_eq!(r.status, RayStatus::Backward(surf));
    }
    // A stop placed 2 mm inside the last element by a negative gap: the lens asks for virtual
    // propagation, so rays reach it backwards and go on to the image.
    let mut v = lens.clone();
    let k = v.surfaces.len() - 1;
    let back = v.surfaces[k].d_next_mm;
    v.surfaces[k].d_next_mm = -2.0;
    let mut stop = Surface::stop(5.0, back + 2.0);
    stop.is_stop = false; // a second, bare aperture: lens1 keeps its own stop
    v.surfaces.push(stop);
    let vsys = v.compile();
    let vn = vsys.indices(LAMBDA_D_NM);
    let mut b = RayBatch::<f64>::new();
    let (o, d) = (Vec3::new(0.0, 1.0, -5.0), Vec3::new(0.0, 0.0, 1.0));
    b.push(o, d);
    trace(&vsys, LAMBDA_D_NM, &mut b, TraceOptions::default());
    let r = trace_ray(&vsys, &vn, LAMBDA_D_NM, o, d, true, None);
    assert_eq!(b.get(0).status, RayStatus::Alive);
    assert_eq!(r.status, RayStatus::Alive);
    // The virtual stop changes nothing where the ray lands (it is a bare aperture).
    let mut b0 = RayBatch::<f64>::new();
    b0.push(o, d);
    trace(&sys, LAMBDA_D_NM, &mut b0, TraceOptions::default());
    assert!((b.get(0).o.y - b0.get(0).o.y).abs() < 1e-12);
    // A virtual image plane (negative last gap) is reached backwards; a real one is not.
    let mut vi = lens.clone();
    vi.surfaces[k].d_next_mm = -5.0;
    let mut b = RayBatch::<f64>::new();
    b.push(o, d);
    trace(&vi.compile(), LAMBDA_D_NM, &mut b, TraceOptions::default());
    assert_eq!(b.get(0).status, RayStatus::Alive);
}

/// A ray that crosses a steep surface's vertex plane beyond the sphere's rim (where the sag is
/// undefined) but meets the surface nearer the axis is a hit in the kernel and the reference
/// tracer alike, at the sphere's closed-form root. The reference's Newton started at the vertex
/// plane and called it a miss (found by the Embree check on a patent lens, surface 51: R 50 mm,
/// semi-aperture 42.5 mm, 1.2 % of the on-axis rays).
#[test]
fn a_steep_surface_crossed_beyond_its_rim_at_the_vertex_plane_is_hit() {
    let r_mm: f64 = 50.0;
    let p: Vec3<f64> = Vec3::new(0.0, -68.95430530365167, -34.727342366274456);
    let d = Vec3::new(0.0, 0.46418579392640935, 0.8855932156819379).normalized();
    // Vertex-plane crossing beyond the rim.
    let t0 = -p.z / d.z;
    assert!((p.y + d.y * t0).abs() > r_mm);
    // Closed form: |p + t d - (0, 0, R)|² = R², the nearer root is on the vertex side.
    let q = p - Vec3::new(0.0, 0.0, r_mm);
    let (b, c) = (q.dot(d), q.dot(q) - r_mm * r_mm);
    let t_exact = -b - (b * b - c).sqrt();
    let hit = p + d * t_exact;
    assert!(hit.y.hypot(hit.x) < 42.0 && hit.z < r_mm);
    for a4 in [0.0, 1e-9] {
        let mut l = Lens::load("lens1").unwrap();
        let mut s0 = Surface::sphere(1.0 / r_mm, 45.0, 40.0, Material::parse("N-BK7").unwrap());
        s0.asph[1] = a4; // 0: the quadric path; otherwise Newton from the quadric root
        l.surfaces = vec![s0, Surface::sphere(0.0, 60.0, 20.0, Material::Air)];
        l.object = Object::Infinite;
        let sys = l.compile();
        let n = sys.indices(LAMBDA_D_NM);
        let o = p + sys.rows[0].pos;
        let r = trace_ray(&sys, &n, LAMBDA_D_NM, o, d, false, Some(0));
        assert_eq!(r.status, RayStatus::Alive, "a4 {a4}");
        let local = r.o - sys.rows[0].pos;
        if a4 == 0.0 {
            assert!((local - hit).norm() < 1e-9, "{local:?} vs {hit:?}");
        } else {
            assert!((local - hit).norm() < 0.1, "{local:?} vs {hit:?}");
        }
        let mut batch = RayBatch::<f64>::new();
        batch.push(o, d);
        trace(
            &sys,
            LAMBDA_D_NM,
            &mut batch,
            TraceOptions { apertures: false },
        );
        let full = trace_ray(&sys, &n, LAMBDA_D_NM, o, d, false, None);
        assert_eq!(batch.get(0).status, full.status, "a4 {a4}");
        assert_eq!(full.status, RayStatus::Alive, "a4 {a4}");
        assert!((batch.get(0).o - full.o).norm() < 1e-9, "a4 {a4}");
    }
}

/// One row out per row in, whatever the wavelengths (0.0 and -0.0 were merged; defect 7).
#[test]
fn raw_trace_keeps_every_row() {
    use tolray::trace::raw::{trace_raw, RawRay};
    let sys = Lens::load("lens1").unwrap().compile();
    let ray = |wl: f64| RawRay {
        ox: 0.0,
        oy: 0.5,
        oz: -5.0,
        dx: 0.0,
        dy: 0.0,
        dz: 1.0,
        wavelength_nm: wl,
    };
    let rays = [ray(0.0), ray(-0.0), ray(f64::NAN), ray(587.5618), ray(-0.0)];
    let out = trace_raw(&sys, &rays, TraceOptions::default()).unwrap();
    assert_eq!(out.len(), rays.len());
    let st: Vec<&str> = out.iter().map(|h| h.status.as_str()).collect();
    assert_eq!(st, ["invalid", "invalid", "invalid", "alive", "invalid"]);
}

/// The streamed raw trace (`trace_csv_to`, `trace_rays_to`: read, traced and written a chunk at a
/// time) writes the bytes of the whole-set trace in CSV and in JSON, over more rays than a chunk
/// holds and many wavelengths; an error past the first chunk names its line and ray counted from
/// the start.
#[test]
fn streamed_raw_trace_writes_the_whole_trace() {
    use tolray::trace::raw::{
        parse_csv, to_csv, trace_csv_to, trace_raw, trace_rays_to, HitFormat, STREAM_RAYS,
    };
    let sys = Lens::load("lens1").unwrap().compile();
    let n = STREAM_RAYS + 3000;
    let mut csv = String::from("ox,oy,oz,dx,dy,dz,wavelength_nm\n# rays\n");
    for k in 0..n {
        let t = k as f64 / n as f64;
        let wl = [486.1327, 587.5618, 656.2725, 500.0 + (k % 97) as f64][k % 4];
        csv.push_str(&format!(
            "0.1,{},-10,0,{},1,{wl}\n",
            16.0 * t - 8.0,
            0.05 * t
        ));
        if k == 40_000 {
            csv.push('\n');
        }
    }
    let rays = parse_csv(&csv).unwrap();
    assert_eq!(rays.len(), n);
    let hits = trace_raw(&sys, &rays, TraceOptions::default()).unwrap();
    let alive = hits.iter().filter(|h| h.status == "alive").count();
    assert!(
        alive > n / 2 && alive < n,
        "{alive} of {n}: some rays vignetted"
    );
    let opts = TraceOptions::default();
    let mut out = Vec::new();
    let counts = trace_csv_to(&sys, csv.as_bytes(), &mut out, HitFormat::Csv, opts).unwrap();
    assert_eq!((counts.rays, counts.alive), (n, alive));
    assert!(out == to_csv(&hits).as_bytes(), "CSV differs");
    let mut out = Vec::new();
    trace_csv_to(&sys, csv.as_bytes(), &mut out, HitFormat::Json, opts).unwrap();
    let json = serde_json::to_string_pretty(&hits).unwrap() + "\n";
    assert!(out == json.as_bytes(), "JSON differs");
    let mut out = Vec::new();
    trace_rays_to(&sys, &rays[..0], &mut out, HitFormat::Json, opts).unwrap();
    assert_eq!(out, b"[]\n");
    // Errors past the first chunk, on line 68,003 (ray 68,000 after the header, the comment and
    // the blank line): a bad number, then a wavelength without an index.
    let refused = |line: &str| {
        let mut lines: Vec<&str> = csv.lines().collect();
        lines[68_002] = line;
        let text = lines.join("\n");
        let e = trace_csv_to(&sys, text.as_bytes(), std::io::sink(), HitFormat::Csv, opts);
        e.unwrap_err().message().to_string()
    };
    let e = refused("0,0,-10,0,0,1,x");
    assert!(e.starts_with("line 68003, column 7"), "{e}");
    let e = refused("0,0,-10,0,0,1,1e-300");
    assert!(e.starts_with("ray 68000 (wavelength 1e-300 nm)"), "{e}");
}

/// A field angle of 90° or more (or NaN) is refused: tan flips sign past 90°, so such a field
/// traced silently from the wrong side before.
#[test]
fn field_angles_of_90_degrees_or_more_are_refused() {
    use tolray::trace::{Field, Pupil, RaySet};
    let lens = Lens::load("cooke-triplet").unwrap();
    let para = lens.paraxial(587.5618).unwrap();
    let gen = |x: f64, y: f64| {
        RaySet::generate(
            &lens,
            &para,
            Field::AngleDeg { x, y },
            &Pupil::grid(4),
            587.5618,
        )
    };
    assert!(gen(0.0, 20.0).is_ok());
    assert!(gen(-89.0, 0.0).is_ok());
    for (x, y) in [
        (0.0, 90.0),
        (0.0, 95.0),
        (-120.0, 0.0),
        (f64::NAN, 0.0),
        (0.0, f64::INFINITY),
    ] {
        let e = gen(x, y).unwrap_err();
        assert_eq!(e.kind(), tolray::ErrorKind::Argument, "({x}, {y})");
        assert!(e.message().contains("below 90°"), "{}", e.message());
    }
}

/// Inputs the fuzzer's debug build caught reaching the kernel with numbers it cannot trace
/// (examples/fuzz.rs, `--target flags` and `rays`): each is now refused with its reason, and the
/// kernel marks every ray invalid rather than tracing through a medium without a usable index.
#[test]
fn unlaunchable_fields_objects_and_wavelengths_are_refused() {
    use tolray::analysis::{spot_diagram, SpotOptions};
    use tolray::trace::{Field, Pupil};
    let lens = Lens::load("lens1").unwrap();
    let spot = |lens: &Lens, field: Field, wl: f64| {
        let opts = SpotOptions {
            fields: vec![field],
            wavelengths_nm: vec![wl],
            pupil: Pupil::grid(8),
            trace: TraceOptions { apertures: true },
        };
        spot_diagram(lens, &lens.compile(), &opts)
    };
    let wl = lens.primary_wavelength_nm;
    assert!(spot(&lens, Field::fraction(0.7), wl).is_ok());
    // A field whose chief ray would leave the object at 90° (tangents overflowing on the way).
    for f in ["1e300", "0:1e300mm@image", "0:1e9", "0:1e10mm"] {
        let e = spot(&lens, Field::parse(f).unwrap(), wl).unwrap_err();
        assert_eq!(e.kind(), tolray::ErrorKind::Argument, "{f}");
        assert!(
            e.message()
                .contains("a field is a direction toward the lens"),
            "{f}: {}",
            e.message()
        );
    }
    // An object beyond 1e15 mm is refused by the parser and by validation.
    for d in ["1e300", "-1e308", "virtual:1e16"] {
        assert!(Object::parse(d).is_err(), "{d}");
    }
    let mut far = lens.clone();
    far.object = Object::Finite { distance_mm: 1e300 };
    assert!(far
        .validate()
        .unwrap_err()
        .message()
        .contains("at most 1e15"));
    far.object = Object::Finite { distance_mm: 1e14 };
    assert!(far.validate().is_ok() && spot(&far, Field::fraction(0.5), wl).is_ok());
    // A model glass of absurd dispersion (V_d 1e-4) has an index at the d line only: a spot at
    // the C line is refused naming the medium, and the kernel traces no ray there.
    let mut odd = lens.clone();
    odd.surfaces[0].material = Material::parse("1.6/1e-4").unwrap();
    assert!(odd.validate().is_ok() && spot(&odd, Field::fraction(0.5), wl).is_ok());
    let e = spot(&odd, Field::fraction(0.5), 656.2725).unwrap_err();
    assert!(
        e.message()
            .starts_with("surface 0: the medium after it (1.6/0.0001) has index -"),
        "{}",
        e.message()
    );
    let sys = odd.compile();
    assert_eq!(sys.unusable_index(656.2725).map(|(k, _)| k), Some(1));
    let mut batch = RayBatch::<f64>::new();
    for y in [0.0, 1.0, 2.0] {
        batch.push(Vec3::new(0.0, y, -5.0), Vec3::new(0.0, 0.0, 1.0));
    }
    let mut at_d = batch.clone();
    trace(&sys, 656.2725, &mut batch, TraceOptions::default());
    assert!((0..3).all(|i| batch.get(i).status == RayStatus::Invalid));
    trace(&sys, LAMBDA_D_NM, &mut at_d, TraceOptions::default());
    assert!((0..3).all(|i| at_d.get(i).status == RayStatus::Alive));
}

/// An ideal thin lens (OpticStudio PARAXIAL, DeepLens ThinLens) images perfectly: every ray of
/// a parallel beam at angles (θx, θy) meets the focal plane at (f tan θx, f tan θy), whatever
/// its height, in the kernel and the reference tracer; the paraxial EFL is f; a diverging lens
/// sends the beam back through its virtual focus.
#[test]
fn an_ideal_thin_lens_focuses_each_direction_to_one_point() {
    use tolray::lens::Shape;
    for f in [50.0, -40.0] {
        let mut lens = zmx("thinlens.zmx");
        // Stop, then the thin lens alone, the image plane |f| behind it: at the focus for
        // f > 0, where each beam meets at (f tan θx, f tan θy); for f < 0 each ray leaves as
        // if from the virtual focus (f tan θ, at z = f from the lens), which fixes where it
        // lands.
        lens.surfaces.truncate(2);
        lens.surfaces[1].shape = Shape::Paraxial { focal_mm: f };
        let gap = f.abs();
        lens.surfaces[1].d_next_mm = gap;
        let z_lens = lens.surfaces[0].d_next_mm;
        let para = lens.paraxial(LAMBDA_D_NM).unwrap();
        assert!(
            (para.efl_mm.unwrap() - f).abs() < 1e-12 * f.abs(),
            "{:?}",
            para.efl_mm
        );
        let sys = lens.compile();
        let n = sys.indices(LAMBDA_D_NM);
        let mut b = RayBatch::<f64>::new();
        let mut rays = Vec::new();
        for (ax, ay) in [(0.0f64, 0.0f64), (0.0, 5.0), (3.0, -4.0), (-10.0, 7.0)] {
            let (tx, ty) = (ax.to_radians().tan(), ay.to_radians().tan());
            let d = Vec3::new(tx, ty, 1.0).normalized();
            for k in 0..49 {
                let o = Vec3::new((k % 7) as f64 - 3.0, (k / 7) as f64 - 3.0, -1.0);
                b.push(o, d);
                // Height at the lens, then the straight line from the (virtual) focus.
                let (hx, hy) = (o.x + (z_lens - o.z) * tx, o.y + (z_lens - o.z) * ty);
                let want = [
                    f * tx + (hx - f * tx) * (1.0 - gap / f),
                    f * ty + (hy - f * ty) * (1.0 - gap / f),
                ];
                if f > 0.0 {
                    assert_eq!(want, [f * tx, f * ty]);
                }
                rays.push((o, d, want));
            }
        }
        trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions { apertures: false });
        for (i, (o, d, want)) in rays.iter().enumerate() {
            let k = b.get(i);
            let r = trace_ray(&sys, &n, LAMBDA_D_NM, *o, *d, false, None);
            assert!(k.status.is_alive() && r.status.is_alive(), "f {f} ray {i}");
            for (x, y) in [(k.o.x, k.o.y), (r.o.x, r.o.y)] {
                assert!(
                    (x - want[0]).abs() < 1e-12 * (1.0 + f.abs())
                        && (y - want[1]).abs() < 1e-12 * (1.0 + f.abs()),
                    "f {f} ray {i}: ({x}, {y}) vs {want:?}"
                );
            }
            assert!((k.d - r.d).norm() < 1e-14, "f {f} ray {i} direction");
        }
    }
}

/// An afocal lens (a parallel beam leaves parallel) opens and traces: a 2x Keplerian reducer of
/// two ideal thin lenses, 100 mm and 50 mm focal lengths 150 mm apart, has no focal length
/// (EFL, BFD, F-number and the image of an object at infinity are `None`), angular
/// magnification -f1/f2 = -2 and an exit pupil half the entrance pupil's size; every ray of
/// a field at angle θ leaves with the same direction, tan θ' = -2 tan θ (ideal lenses image
/// without aberration); a finite object is imaged at the constant lateral magnification
/// -f2/f1 = -0.5 at a finite distance; a field given as a fraction of the sensor is an error
/// naming the reason, except the axis. The all-flat fold-mirror files of optiland's suite
/// are afocal with angular magnification +1 (their rays are checked against optiland in
/// `tests/zemax/`, `corpus`).
#[test]
fn an_afocal_telescope_has_an_angular_magnification_and_parallel_beams() {
    use tolray::trace::{Field, Pupil, RaySet};
    let json = r#"{"surfaces": [
        {"type": "ThinLens", "f": 100, "r": 10, "mat2": "air", "d_next": 150, "is_aperture": true},
        {"type": "ThinLens", "f": 50, "r": 30, "mat2": "air", "d_next": 30}], "r_sensor": 5}"#;
    let lens = tolray::lens::json::from_str(json).unwrap();
    let p = lens.paraxial(LAMBDA_D_NM).unwrap();
    assert!(p.is_afocal(), "{p:?}");
    assert_eq!(
        (
            p.efl_mm,
            p.bfd_mm,
            p.fnum,
            p.image_distance_mm,
            p.half_fov_deg
        ),
        (None, None, None, None, None)
    );
    assert_eq!((p.power_per_mm, p.working_fnum), (0.0, None));
    let m = p.angular_magnification.unwrap();
    assert!((m + 2.0).abs() < 1e-12, "{m}");
    assert!((p.entrance_pupil_diameter_mm - 20.0).abs() < 1e-12);
    assert!((p.exit_pupil_diameter_mm - 10.0).abs() < 1e-12, "{p:?}");
    let err = p.focal_length_for("an F-number").unwrap_err();
    assert!(err.message().contains("afocal"), "{}", err.message());

    let sys = lens.compile();
    for deg in [1.0f64, -3.0, 5.0] {
        let set =
            RaySet::generate(&lens, &p, Field::angle(deg), &Pupil::grid(9), LAMBDA_D_NM).unwrap();
        let mut b = set.batch();
        trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
        let want = -2.0 * deg.to_radians().tan();
        assert!(b.len() > 40);
        for r in b.iter() {
            assert!(r.status.is_alive(), "{deg}°: {:?}", r.status);
            assert!(r.d.x.abs() < 1e-15, "{deg}°: {:?}", r.d);
            // tolray's angle sign: a positive field angle puts the object above the axis, so
            // its rays descend: tan of the ray is -tan θ before the lens.
            assert!((r.d.y / r.d.z + want).abs() < 1e-12, "{deg}°: {:?}", r.d);
        }
    }
    // A fraction of the sensor names no angle, but the axis is the axis.
    let e = RaySet::generate(
        &lens,
        &p,
        Field::fraction(0.5),
        &Pupil::grid(4),
        LAMBDA_D_NM,
    )
    .unwrap_err();
    assert!(
        e.message().contains("afocal") && e.message().contains("5deg"),
        "{}",
        e.message()
    );
    RaySet::generate(
        &lens,
        &p,
        Field::fraction(0.0),
        &Pupil::grid(4),
        LAMBDA_D_NM,
    )
    .unwrap();

    // A finite object: imaged at -f2/f1 whatever its distance.
    let mut near = lens.clone();
    near.object = Object::Finite { distance_mm: 400.0 };
    let q = near.paraxial(LAMBDA_D_NM).unwrap();
    assert!((q.magnification + 0.5).abs() < 1e-12, "{q:?}");
    assert!(q.image_distance_mm.unwrap().is_finite() && q.efl_mm.is_none());

    // A finite object in a focal lens' front focal plane has no finite image: an error, not
    // an image distance at infinity (the first lens alone, the object 100 mm before it).
    let mut single = lens.clone();
    single.surfaces.truncate(1);
    single.object = Object::Finite { distance_mm: 100.0 };
    let e = single.paraxial(LAMBDA_D_NM).unwrap_err();
    assert!(e.message().contains("front focal plane"), "{}", e.message());

    for f in ["simple_fold_mirror_up.zmx", "one_mirror_up_45deg.zmx"] {
        let l = zmx(&format!("real/optiland/{f}"));
        let p = l.paraxial(l.primary_wavelength_nm).unwrap();
        assert!(
            (p.angular_magnification.unwrap() - 1.0).abs() < 1e-12,
            "{f}"
        );
    }
}

/// Rays generated a chunk at a time (`RayStream`) are the rays of `RaySet::generate`, bit for
/// bit and in order: through aimed, vignetted, grid, hexapolar and random pupils.
#[test]
fn streamed_rays_are_the_ray_sets_rays() {
    use tolray::trace::{Field, Pupil, RaySet, RayStream};
    let vignetted = format!(
        "{}/tests/data/zemax/real/rayoptics/US00583336-2-scaled.zmx",
        env!("CARGO_MANIFEST_DIR")
    );
    let cases = [
        ("lens1", "grid:100", false, Field::fraction(0.7)),
        ("lens2", "hex:40", false, Field::fraction(1.0)),
        ("cooke-triplet", "random:5000", true, Field::fraction(1.0)),
        (vignetted.as_str(), "grid:90", false, Field::fraction(1.0)),
    ];
    for (name, pattern, aim, field) in cases {
        let lens = Lens::load(name).unwrap();
        let wl = lens.primary_wavelength_nm;
        let para = lens.paraxial(wl).unwrap();
        let mut pupil = Pupil::parse(pattern, 3).unwrap();
        pupil.aim = aim;
        let set = RaySet::generate(&lens, &para, field, &pupil, wl).unwrap();
        let whole = set.batch::<f64>();
        let stream = RayStream::new(&lens, &para, field, &pupil, wl).unwrap();
        assert_eq!(stream.chief(), set.chief, "{name}");
        let (mut pts, mut chunk) = (Vec::new(), RayBatch::<f64>::new());
        let (mut all_pts, mut all) = (Vec::new(), Vec::new());
        assert!(stream.chunks() > 1, "{name}: one chunk tests no seam");
        for k in 0..stream.chunks() {
            stream.fill(k, &mut pts, &mut chunk);
            all_pts.extend_from_slice(&pts);
            all.extend(chunk.iter());
        }
        assert_eq!(all_pts, set.pupil, "{name}");
        assert_eq!(all, whole.iter().collect::<Vec<_>>(), "{name}");
    }
}

/// The spot analysis reduces its rays a chunk at a time; its statistics are those of all the
/// rays at once (centroid, RMS about it and about the chief ray, the farthest ray found by
/// brute force), and the same at any thread count.
#[test]
fn streamed_spot_statistics_are_those_of_all_rays() {
    use tolray::analysis::{spot_diagram_rows, SpotOptions};
    use tolray::trace::{Field, Pupil, RaySet};
    let lens = Lens::load("lens2").unwrap();
    let sys = lens.compile();
    let wls = [486.1327, 656.2725];
    let opts = SpotOptions {
        fields: vec![Field::fraction(0.0), Field::fraction(0.9)],
        wavelengths_nm: wls.to_vec(),
        pupil: Pupil::grid(300),
        trace: TraceOptions::default(),
    };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| spot_diagram_rows(&lens, &sys, &opts).unwrap().0)
    };
    let rows = run(1);
    let bits = |rows: &[tolray::analysis::SpotResult]| {
        rows.iter()
            .map(|r| {
                let s = &r.stats;
                [
                    s.rms_um,
                    s.geo_radius_um,
                    s.centroid_mm[0],
                    s.centroid_mm[1],
                ]
                .map(f64::to_bits)
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&rows), bits(&run(3)));
    let para = lens.paraxial(wls[0]).unwrap();
    for (f, &field) in opts.fields.iter().enumerate() {
        let mut poly = Vec::new();
        for (w, &wl) in wls.iter().enumerate() {
            let set = RaySet::generate(&lens, &para, field, &opts.pupil, wl).unwrap();
            let mut batch = set.batch::<f64>();
            trace(&sys, wl, &mut batch, TraceOptions::default());
            let pts: Vec<[f64; 2]> = batch
                .iter()
                .filter(|r| r.status.is_alive())
                .map(|r| {
                    let p = sys.image.point_to_local(r.o);
                    [p.x, p.y]
                })
                .collect();
            poly.extend_from_slice(&pts);
            let got = &rows[f * 3 + w];
            assert_eq!(got.wavelength_nm, Some(wl));
            check_spot(&pts, set.origins.len(), &got.stats);
        }
        check_spot(
            &poly,
            2 * rows[f * 3].stats.n_launched,
            &rows[f * 3 + 2].stats,
        );
    }
}

/// `stats` against the spot of `pts` computed here directly.
fn check_spot(pts: &[[f64; 2]], launched: usize, stats: &tolray::analysis::SpotStats) {
    let n = pts.len() as f64;
    let c = [0, 1].map(|k| pts.iter().map(|p| p[k]).sum::<f64>() / n);
    let ms = pts
        .iter()
        .map(|p| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2))
        .sum::<f64>()
        / n;
    let geo = pts
        .iter()
        .map(|p| (p[0] - c[0]).hypot(p[1] - c[1]))
        .fold(0.0, f64::max);
    assert_eq!((stats.n_valid, stats.n_launched), (pts.len(), launched));
    let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol * b.abs().max(1e-3);
    assert!(
        close(stats.rms_um, ms.sqrt() * 1e3, 1e-12),
        "{} {}",
        stats.rms_um,
        ms.sqrt() * 1e3
    );
    assert!(
        close(stats.geo_radius_um, geo * 1e3, 1e-12),
        "{} {}",
        stats.geo_radius_um,
        geo * 1e3
    );
    for k in 0..2 {
        assert!(
            (stats.centroid_mm[k] - c[k]).abs() < 1e-12 * c[k].abs().max(1.0),
            "{:?} {c:?}",
            stats.centroid_mm
        );
    }
}

/// Every instruction set the CPU has traces the same bits: f32, f64 and both dual-number widths
/// the library differentiates with, on every test lens, nominal and perturbed, and the launch of
/// a field's rays. (The other tests check the kernel of the build in use against the reference
/// tracer; with this, every build is checked.)
#[test]
fn every_instruction_set_traces_the_same_bits() {
    use tolray::lens::Param;
    use tolray::psf::{psf_map, PsfOptions};
    use tolray::real::{Dual, GRAD_WIDTH};
    use tolray::trace::simd::{self, Isa};
    use tolray::trace::Traceable;

    /// The debug text of a traced batch: equal text, equal bits (f32 and f64 print the shortest
    /// text that reads back as the same number, signed zeros included).
    fn traced<S: Traceable>(
        lens: &Lens,
        adj: &Adjustments,
        lift: &dyn Fn(Param, S) -> S,
    ) -> String {
        let sys: System<S> = System::compile(lens, adj, lift);
        let mut b = RayBatch::<S>::new();
        for (o, d) in random_rays(lens, 300, 5) {
            b.push(o, d);
        }
        trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default());
        format!("{:?}", b.blocks())
    }
    fn seed<const N: usize>(p: Param, v: Dual<f64, N>) -> Dual<f64, N> {
        match p {
            Param::Curvature(i) => Dual::var(v.re, i % N),
            Param::Gap(i) => Dual::var(v.re, (i + 3) % N),
            _ => v,
        }
    }
    let available = Isa::available();
    assert!(available.contains(&Isa::Baseline) && available[0] == Isa::detected());
    let before = simd::active();
    let run = |isa: Isa| {
        simd::set_active(isa).unwrap();
        let mut out = Vec::new();
        for (name, lens) in lenses() {
            for adj in [Adjustments::none(lens.surfaces.len()), perturbed(&lens)] {
                out.push((name.clone(), "f32", traced::<f32>(&lens, &adj, &|_, v| v)));
                out.push((name.clone(), "f64", traced::<f64>(&lens, &adj, &|_, v| v)));
                out.push((
                    name.clone(),
                    "dual",
                    traced(&lens, &adj, &seed::<GRAD_WIDTH>),
                ));
                out.push((name.clone(), "dual1", traced(&lens, &adj, &seed::<1>)));
            }
        }
        // A PSF map launches each field's rays in the build too.
        let lens = Lens::load("lens2").unwrap();
        let map = psf_map(
            &lens,
            &lens.compile(),
            2,
            LAMBDA_D_NM,
            &PsfOptions::for_lens(&lens),
        );
        out.push(("lens2".into(), "psf map", format!("{:?}", map.unwrap())));
        out
    };
    let reference = run(Isa::Baseline);
    for &isa in available.iter().filter(|&&i| i != Isa::Baseline) {
        for (a, b) in run(isa).iter().zip(&reference) {
            assert!(
                a == b,
                "{} {}: the {} build differs from the baseline",
                a.0,
                a.1,
                isa.name()
            );
        }
    }
    simd::set_active(before).unwrap();
    eprintln!(
        "instruction sets compared: {}",
        available
            .iter()
            .map(|i| i.name())
            .collect::<Vec<_>>()
            .join(", ")
    );
}
