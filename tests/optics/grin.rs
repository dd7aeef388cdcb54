//! Gradient-index media (OpticStudio's Gradient 1 to 3): the kernel against closed forms (the
//! rod n² = n0² (1 - g² r²), whose rays are exactly harmonic in the parameter dt = ds / n), the
//! kernel against the reference tracer's independent integrator on a curved Gradient 3 +
//! Gradient 1 doublet, the paraxial model against the rod's focal length and real rays, f32
//! against f64, the files (.zmx and JSON) read back as the same lens, and the refusals.

use tolray::lens::gradient::{Gradient, GradientForm};
use tolray::lens::{GlassCatalogs, Material, Surface};
use tolray::math::Vec3;
use tolray::trace::reference::trace_ray;
use tolray::trace::{trace, RayBatch, RayStatus, TraceOptions};
use tolray::{Lens, Object};

const WL: f64 = 587.5618;

fn data(name: &str) -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zemax/").to_string() + name
}

/// A lens of tests/data/zemax.
fn zmx(name: &str) -> Lens {
    tolray::lens::zemax::read_file(std::path::Path::new(&data(name)), &GlassCatalogs::builtin())
        .unwrap()
        .lens
}

/// A rod of length `len` mm between flat faces in air, its medium `g`, the image plane `back`
/// mm behind it.
fn rod(g: Gradient, len: f64, back: f64) -> Lens {
    let mut l = Lens::load("lens1").unwrap();
    let mut s0 = Surface::sphere(0.0, 2.0, len, Material::Gradient(Box::new(g)));
    s0.is_stop = true;
    l.surfaces = vec![s0, Surface::sphere(0.0, 2.0, back, Material::Air)];
    l.object = Object::Infinite;
    l
}

/// The rod of n² = n0² (1 - g² r²): a ray entering at (x0, y0) with optical direction (n d) T0
/// follows x(t) = x0 cos ωt + (T0x / ω) sin ωt, z = T0z t, ω = n0 g, exactly; its optical path
/// is ∫ n² dt. Returns the image point, the direction and the optical path from the plane z =
/// -1 to the image plane, of a ray starting at `o` (z = -1) going `d`.
fn rod_closed_form(
    n0: f64,
    g: f64,
    len: f64,
    back: f64,
    o: Vec3<f64>,
    d: Vec3<f64>,
) -> (Vec3<f64>, Vec3<f64>, f64) {
    let w = n0 * g;
    let p0 = o + d * (1.0 / d.z);
    let n2 = |x: f64, y: f64| n0 * n0 * (1.0 - g * g * (x * x + y * y));
    let tz = (n2(p0.x, p0.y) - d.x * d.x - d.y * d.y).sqrt();
    let t = len / tz;
    let (c, s) = ((w * t).cos(), (w * t).sin());
    let axis = |a: f64, ta: f64| (a * c + ta / w * s, -a * w * s + ta * c);
    let (x, tx) = axis(p0.x, d.x);
    let (y, ty) = axis(p0.y, d.y);
    // ∫ (A cos ωt + B sin ωt)² dt.
    let square = |a: f64, b: f64| {
        let s2 = (2.0 * w * t).sin() / (4.0 * w);
        a * a * (t / 2.0 + s2) + a * b * s * s / w + b * b * (t / 2.0 - s2)
    };
    let inside = n0 * n0 * t - n0 * n0 * g * g * (square(p0.x, d.x / w) + square(p0.y, d.y / w));
    let out = Vec3::new(tx, ty, (1.0 - tx * tx - ty * ty).sqrt());
    let image = Vec3::new(x, y, len) + out * (back / out.z);
    (image, out, 1.0 / d.z + inside + back / out.z)
}

fn rays() -> Vec<(Vec3<f64>, Vec3<f64>)> {
    let mut v = Vec::new();
    for (x, y) in [(0.0, 0.0), (0.3, 0.0), (0.0, -0.7), (0.5, 0.6), (-1.1, 0.2)] {
        for (a, b) in [(0.0, 0.0), (0.05, -0.02), (-0.1, 0.08)] {
            let d = Vec3::new(a, b, 1.0).normalized();
            v.push((Vec3::new(x, y, -1.0), d));
        }
    }
    v
}

#[test]
fn rod_rays_match_the_closed_form() {
    let (n0, g, len, back) = (1.6, 0.3, 5.0, 2.5);
    let grin = Gradient::radial(GradientForm::IndexSquared, n0, &[-n0 * n0 * g * g], 0.005);
    let lens = rod(grin, len, back);
    lens.validate().unwrap();
    let sys = lens.compile();
    let rays = rays();
    let mut batch = RayBatch::<f64>::new();
    for (o, d) in &rays {
        batch.push(*o, *d);
    }
    trace(&sys, WL, &mut batch, TraceOptions { apertures: false });
    let mut worst = [0.0f64; 3];
    for (k, (o, d)) in rays.iter().enumerate() {
        let r = batch.get(k);
        assert_eq!(r.status, RayStatus::Alive, "ray {k}");
        let (p, dir, opl) = rod_closed_form(n0, g, len, back, *o, *d);
        worst[0] = worst[0].max((r.o - p).norm());
        worst[1] = worst[1].max((r.d - dir).norm());
        worst[2] = worst[2].max((r.opl - opl).abs());
    }
    // Measured 2026-12-01: 4e-14 mm, 2e-14, 2e-13 mm (steps of 5 µm along the ray).
    assert!(
        worst[0] < 1e-10 && worst[1] < 1e-11 && worst[2] < 1e-10,
        "position, direction, optical path: {worst:?}"
    );
    // The same in f32, to its rounding.
    let sys32 = sys.convert::<f32>();
    let mut b32 = RayBatch::<f32>::new();
    for (o, d) in &rays {
        b32.push(*o, *d);
    }
    trace(&sys32, WL, &mut b32, TraceOptions { apertures: false });
    for (k, r64) in batch.iter().enumerate() {
        let r = b32.get(k);
        assert_eq!(r.status, RayStatus::Alive, "f32 ray {k}");
        let e = (r.o.x as f64 - r64.o.x).abs() + (r.o.y as f64 - r64.o.y).abs();
        assert!(e < 2e-5, "f32 ray {k}: {e} mm from f64");
    }
}

#[test]
fn kernel_matches_the_reference_integrator() {
    let mut lens = zmx("grin.zmx");
    // Fine steps: both integrators converge (fourth order each) to the same path.
    for s in lens.surfaces.iter_mut() {
        if let Material::Gradient(g) = &mut s.material {
            g.step_mm = 0.002;
        }
    }
    let sys = lens.compile();
    let n = sys.indices(WL);
    let mut batch = RayBatch::<f64>::new();
    let mut starts = Vec::new();
    for (x, y) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.9), (-1.2, 1.2), (0.7, -1.5)] {
        for fy in [0.0f64, 2.0, -3.0] {
            let a = fy.to_radians();
            let d = Vec3::new(0.3 * a, a.sin(), a.cos()).normalized();
            let o = Vec3::new(x, y, -1.0);
            starts.push((o, d));
            batch.push(o, d);
        }
    }
    trace(&sys, WL, &mut batch, TraceOptions { apertures: true });
    let mut worst = [0.0f64; 2];
    for (k, (o, d)) in starts.iter().enumerate() {
        let k_ray = batch.get(k);
        let r = trace_ray(&sys, &n, WL, *o, *d, true, None);
        assert_eq!(k_ray.status, r.status, "ray {k}");
        assert_eq!(r.status, RayStatus::Alive, "ray {k}");
        worst[0] = worst[0].max((k_ray.o - r.o).norm());
        worst[1] = worst[1].max((k_ray.opl - r.opl).abs());
    }
    // Measured 2026-12-01: 2e-14 mm and 3e-13 mm.
    assert!(worst[0] < 1e-10 && worst[1] < 1e-10, "{worst:?}");
    // At the file's own steps (50 µm), as close to the fine trace.
    let coarse = zmx("grin.zmx").compile();
    let mut b2 = RayBatch::<f64>::new();
    for (o, d) in &starts {
        b2.push(*o, *d);
    }
    trace(&coarse, WL, &mut b2, TraceOptions { apertures: true });
    for k in 0..starts.len() {
        let e = (b2.get(k).o - batch.get(k).o).norm();
        // Measured 2026-12-01: 3e-13 mm at most (the index varies slowly on a step's scale).
        assert!(e < 1e-9, "ray {k}: 50 µm steps are {e} mm from 2 µm steps");
    }
}

#[test]
fn paraxial_focal_length_of_a_rod() {
    // n(r) = n0 (1 - g² r² / 2) (Gradient 1): paraxial rays y'' = -g² y, so a parallel ray
    // leaves the rod with n u = -n0 g sin(gL): EFL = 1 / (n0 g sin gL).
    let (n0, g, len) = (1.6, 0.3, 3.0);
    let grin = Gradient::radial(GradientForm::Index, n0, &[-n0 * g * g / 2.0], 0.002);
    let lens = rod(grin, len, 5.0);
    let p = lens.paraxial(WL).unwrap();
    let efl = 1.0 / (n0 * g * (g * len).sin());
    assert!(
        (p.efl_mm.unwrap() - efl).abs() < 1e-9 * efl,
        "{} vs {efl}",
        p.efl_mm.unwrap()
    );
    let bfd = (g * len).cos() / (n0 * g * (g * len).sin());
    assert!(
        (p.bfd_mm.unwrap() - bfd).abs() < 1e-9,
        "{:?} vs {bfd}",
        p.bfd_mm
    );
    // The same for the rod lens of tests/data/zemax/grin-rod.zmx (a stop in air, 0.1 mm in
    // front of a 4.4 mm rod of n = 1.6 - 0.0871 r²).
    let file = zmx("grin-rod.zmx");
    let g2: f64 = 2.0 * 0.0871 / 1.6;
    let want = 1.0 / (1.6 * g2.sqrt() * (g2.sqrt() * 4.4).sin());
    let got = file.paraxial(WL).unwrap().efl_mm.unwrap();
    assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");
    // A real ray at 1 µm from the axis crosses it at the paraxial focus.
    let sys = lens.compile();
    let mut b = RayBatch::<f64>::new();
    b.push(Vec3::new(0.0, 1e-3, -1.0), Vec3::new(0.0, 0.0, 1.0));
    trace(&sys, WL, &mut b, TraceOptions { apertures: false });
    let r = b.get(0);
    let z_cross = r.o.z - r.o.y * r.d.z / r.d.y;
    assert!(
        (z_cross - (len + bfd)).abs() < 1e-5,
        "real focus {z_cross} vs {}",
        len + bfd
    );
}

#[test]
fn files_read_back_as_the_same_lens() {
    let cat = GlassCatalogs::builtin();
    let lens = zmx("grin.zmx");
    let Material::Gradient(g) = &lens.surfaces[1].material else {
        panic!("surface 1 starts a Gradient 3 medium");
    };
    assert_eq!(g.zemax_type(), "GRINSUR3");
    assert_eq!((g.n0, g.radial[0], g.axial[1]), (1.6, -0.004, -0.0002));
    let Material::Gradient(g1) = &lens.surfaces[2].material else {
        panic!("surface 2 starts a Gradient 1 medium");
    };
    assert_eq!(g1.zemax_type(), "GRINSUR1");
    let text = tolray::lens::zemax::to_string(&lens, None);
    assert!(text.contains("TYPE GRINSUR3") && text.contains("TYPE GRINSUR1"));
    let back = tolray::lens::zemax::from_str(&text, &cat).unwrap().lens;
    assert_eq!(back.surfaces, lens.surfaces);
    let json = tolray::lens::json::to_value(&lens);
    let again = tolray::lens::json::from_value(&json).unwrap();
    assert_eq!(again.surfaces, lens.surfaces);
    // DeepLens reads the vertex index from "mat2".
    assert_eq!(json["surfaces"][1]["mat2"], "1.6");
}

#[test]
fn impossible_media_are_refused_with_the_reason() {
    let g = Gradient::radial(GradientForm::Index, 1.6, &[-0.01], 0.05);
    // Before the image: no surface ends the medium.
    let mut l = rod(g, 3.0, 5.0);
    l.surfaces[1].material = Material::Gradient(Box::new(g));
    let e = l.validate().unwrap_err().to_string();
    assert!(
        e.contains("surface 1") && e.contains("before the image"),
        "{e}"
    );
    // A mirror bounding it.
    let mut l = rod(g, 3.0, 5.0);
    l.surfaces[1].role = tolray::lens::SurfaceRole::Mirror;
    l.surfaces[1].material = l.surfaces[0].material.clone();
    l.surfaces[1].d_next_mm = -5.0;
    let e = l.validate().unwrap_err().to_string();
    assert!(e.contains("mirror"), "{e}");
    // A zero step.
    let mut bad = g;
    bad.step_mm = 0.0;
    let e = rod(bad, 3.0, 5.0).validate().unwrap_err().to_string();
    assert!(e.contains("surface 0") && e.contains("step"), "{e}");
    // Steps so fine that a trace would crawl (300,000 across the rod).
    bad.step_mm = 1e-5;
    let e = rod(bad, 3.0, 5.0).validate().unwrap_err().to_string();
    assert!(e.contains("surface 0") && e.contains("10,000 steps"), "{e}");
    // Gradient 1's r term, which tolray does not trace.
    // The reader's error for grin.zmx with `from` replaced by `to`.
    let edited = |from: &str, to: &str| {
        let text = std::fs::read_to_string(data("grin.zmx"))
            .unwrap()
            .replace(from, to);
        tolray::lens::zemax::from_str(&text, &GlassCatalogs::builtin())
            .unwrap_err()
            .to_string()
    };
    let e = edited("  PARM 3 -0.006\n", "  PARM 3 -0.006\n  PARM 4 0.01\n");
    assert!(e.contains("PARM 4") && e.contains("nr1"), "{e}");
    // Gradient 9 (SELFOC) needs OpticStudio's data file.
    let e = edited("TYPE GRINSUR1", "TYPE GRINSUR9");
    assert!(e.contains("GRADIENT_9.DAT") && e.contains("line 36"), "{e}");
    // An aspheric surface before the medium: OpticStudio's Gradient surfaces are conics.
    let mut l = rod(g, 3.0, 5.0);
    l.surfaces[0].asph[1] = 1e-4;
    let e = l.validate().unwrap_err().to_string();
    assert!(e.contains("surface 0") && e.contains("conic"), "{e}");
    // A tilted surface bounding it is traced, but its .zmx coordinate breaks would end the
    // medium in OpticStudio: the write is refused, and no file is left.
    let mut l = rod(g, 3.0, 5.0);
    l.surfaces[1].vec_local = [0.0, 0.02, 1.0];
    l.validate().unwrap();
    let out = std::env::temp_dir().join(format!("tolray-grin-{}.zmx", std::process::id()));
    let e = tolray::lens::zemax::write_file(&l, None, &out)
        .unwrap_err()
        .to_string();
    assert!(e.contains("surface 1") && e.contains("tilted"), "{e}");
    assert!(!out.exists(), "no half-written file");
}

/// The C ABI sets a medium's coefficients (`TOLRAY_PARAM_GRADIENT`) and refuses what the
/// files would: an unusable n0, a coefficient that does not exist.
#[test]
fn the_c_abi_sets_gradient_coefficients() {
    use std::ffi::CString;
    use tolray::ffi::*;
    let lens = zmx("grin.zmx");
    let text = CString::new(tolray::lens::json::to_string(&lens)).unwrap();
    let mut handle = std::ptr::null_mut();
    unsafe {
        assert_eq!(
            tolray_lens_from_json(text.as_ptr(), &mut handle),
            tolray_status::TOLRAY_OK
        );
        for (term, value, ok) in [(1, -0.005, true), (0, 0.5, false), (10, 0.1, false)] {
            let p = tolray_param {
                kind: TOLRAY_PARAM_GRADIENT,
                surface: 1,
                term,
            };
            let mut out = std::ptr::null_mut();
            let status = tolray_lens_with_param(handle, &p, value, &mut out);
            assert_eq!(status == tolray_status::TOLRAY_OK, ok, "term {term}");
            if !ok {
                assert!(out.is_null());
                continue;
            }
            let mut n = 0usize;
            tolray_lens_to_json(out, std::ptr::null_mut(), 0, &mut n);
            let mut buf = vec![0u8; n + 1];
            tolray_lens_to_json(out, buf.as_mut_ptr().cast(), n + 1, &mut n);
            let back = tolray::lens::json::from_str(std::str::from_utf8(&buf[..n]).unwrap());
            let Material::Gradient(g) = &back.unwrap().surfaces[1].material else {
                panic!("still a gradient-index medium");
            };
            assert_eq!(g.radial[0], -0.005);
            tolray_lens_free(out);
        }
        tolray_lens_free(handle);
    }
}

/// An independent engine: the GRIN solver of an optiland fork (RK4 in arc length; provenance in
/// tests/data/zemax/grin_optiland_fork.json, script scripts/zmxref/grin_optiland_fork.py)
/// through the rod and the Gradient 3 + Gradient 1 doublet, 15 rays each: image points,
/// directions and optical paths within its own convergence (2e-6 mm on halving its step).
#[test]
fn rays_match_an_optiland_grin_solver() {
    let text = std::fs::read_to_string(data("grin_optiland_fork.json")).unwrap();
    let refs: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rod_lens = rod(
        Gradient::radial(GradientForm::Index, 1.6, &[-0.072], 0.005),
        5.0,
        2.5,
    );
    let doublet = zmx("grin.zmx");
    let v3 = |v: &serde_json::Value| {
        let a: Vec<f64> = v
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        Vec3::new(a[0], a[1], a[2])
    };
    let mut worst = [0.0f64; 3];
    for (case, lens) in [("A_rod", &rod_lens), ("B_doublet", &doublet)] {
        let rays = refs["cases"][case].as_array().unwrap();
        assert_eq!(rays.len(), 15);
        let sys = lens.compile();
        let mut batch = RayBatch::<f64>::new();
        for r in rays {
            batch.push(v3(&r["o"]), v3(&r["d"]));
        }
        trace(&sys, WL, &mut batch, TraceOptions { apertures: false });
        for (k, r) in rays.iter().enumerate() {
            let t = batch.get(k);
            assert_eq!(t.status, RayStatus::Alive, "{case} ray {k}");
            worst[0] = worst[0].max((t.o - v3(&r["image"])).norm());
            worst[1] = worst[1].max((t.d - v3(&r["dir"])).norm());
            worst[2] = worst[2].max((t.opl - r["opl"].as_f64().unwrap()).abs());
        }
    }
    // Measured 2026-12-01: 1.9e-6 mm, 3.6e-7 and 7.2e-7 mm, the fork's own step error.
    assert!(
        worst[0] < 1e-5 && worst[1] < 2e-6 && worst[2] < 1e-5,
        "image point (mm), direction, optical path (mm): {worst:?}"
    );
}
