//! A file's fields and vignetting factors launch the rays OpticStudio means, and round-trip.

use super::*;

/// A .zmx file's own field points, as every command uses them by default: each ray of tolray's
/// `grid:16` pupil, moved into the field's vignetted pupil (VDX/VDY/VCX/VCY), lands where
/// optiland 0.6.3's own ray generator puts the same ray for that field (OpticStudio's field
/// sign: a positive angle is a positive ray slope, so the file's +17° is tolray's -17°), to
/// 1e-9 mm; the rays optiland loses, tolray loses. Files: vignetting factors on two fields, a
/// decentred and tilted system with fields off both axes (where the mirrored field that tolray
/// traced before lands 280 mm away), object-height fields, paraxial image heights (FTYP 2, a
/// catadioptric lens at infinity) and real image heights (FTYP 3, solved by Newton's method on
/// the chief ray, at a finite object), and the object on the first surface (object distance 0,
/// two hand-made lenses beside the corpus: object heights, and real image heights with the first
/// surface curved toward the object) (`field_reference.json`,
/// scripts/zmxref/field_reference.py).
#[test]
fn file_fields_and_vignetting_launch_the_rays_opticstudio_means() {
    let corpus = fixture("real");
    let text = std::fs::read_to_string(corpus.join("field_reference.json")).unwrap();
    let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
    let (mut vignetted, mut backwards) = (0, 0);
    for file in reference["files"].as_array().unwrap() {
        let rel = file["path"].as_str().unwrap();
        let z = zemax::read_file(&corpus.join(rel), &GlassCatalogs::builtin()).unwrap();
        let lens = &z.lens;
        let fields = file["fields"].as_array().unwrap();
        assert_eq!(lens.fields.len(), fields.len(), "{rel}");
        let wl = file["wavelength_um"].as_f64().unwrap() * 1e3;
        let para = lens.paraxial(wl).unwrap();
        let sys = lens.compile();
        for (k, (p, want)) in lens.fields.iter().zip(fields).enumerate() {
            let at = format!("{rel} field {}", k + 1);
            let (fx, fy) = (want["x"].as_f64().unwrap(), want["y"].as_f64().unwrap());
            let expect = match file["field_type"].as_str().unwrap() {
                "angle" => Field::AngleDeg { x: -fx, y: -fy },
                "object_height" => Field::HeightMm { x: fx, y: fy },
                "paraxial_image_height" => Field::ImageHeightMm { x: fx, y: fy },
                "real_image_height" => Field::RealImageHeightMm { x: fx, y: fy },
                t => panic!("{rel}: field type {t}"),
            };
            assert_eq!(p.field, expect, "{at}");
            let v = &want["vignetting"];
            let vig = [p.vignetting.decenter_x, p.vignetting.decenter_y];
            let vig = [
                vig[0],
                vig[1],
                p.vignetting.compress_x,
                p.vignetting.compress_y,
            ];
            let vf = ["vdx", "vdy", "vcx", "vcy"].map(|key| v[key].as_f64().unwrap());
            assert_eq!(vig, vf, "{at}");
            vignetted += usize::from(!p.vignetting.is_none());
            let set = tolray::trace::RaySet::generate(lens, &para, p.field, &Pupil::grid(16), wl)
                .unwrap();
            let pupil = want["pupil"].as_array().unwrap();
            assert_eq!(set.pupil.len(), pupil.len(), "{at}");
            for (q, w) in set.pupil.iter().zip(pupil) {
                let w = [w[0].as_f64().unwrap(), w[1].as_f64().unwrap()];
                assert!(
                    (q[0] - w[0]).abs() < 1e-15 && (q[1] - w[1]).abs() < 1e-15,
                    "{at}: pupil point {q:?} vs {w:?}"
                );
            }
            let mut b = set.batch::<f64>();
            trace(&sys, wl, &mut b, TraceOptions { apertures: false });
            let hits = want["image_xy_mm"].as_array().unwrap();
            // Rays optiland moved backwards to a surface (a negative distance along the ray),
            // which tolray stops as backward@k.
            let backward: Vec<usize> = want["optiland_backward"]
                .as_array()
                .unwrap()
                .iter()
                .map(|i| i.as_u64().unwrap() as usize)
                .collect();
            backwards += backward.len();
            let mut alive = 0;
            for (i, (r, h)) in b.iter().zip(hits).enumerate() {
                if backward.contains(&i) {
                    assert!(
                        matches!(r.status, tolray::trace::RayStatus::Backward(_)),
                        "{at} ray {i}: optiland moved it backwards; tolray {:?}",
                        r.status
                    );
                    continue;
                }
                match (r.status.is_alive(), h.as_array()) {
                    (true, Some(h)) => {
                        // In the image surface's own frame, as optiland reports it.
                        let p = sys.image.point_to_local(r.o);
                        let (x, y) = (p.x, p.y);
                        let (hx, hy) = (h[0].as_f64().unwrap(), h[1].as_f64().unwrap());
                        let tol = 1e-9 * (1.0 + hx.abs().max(hy.abs()));
                        assert!(
                            (x - hx).abs() < tol && (y - hy).abs() < tol,
                            "{at} ray {i}: ({x}, {y}) vs optiland ({hx}, {hy})"
                        );
                        alive += 1;
                    }
                    (false, None) => {}
                    (a, _) => panic!(
                        "{at} ray {i}: tolray alive {a} ({:?}), optiland {h}",
                        r.status
                    ),
                }
            }
            assert!(alive > 100, "{at}: {alive} rays");
        }
    }
    assert_eq!(vignetted, 2);
    assert_eq!(backwards, 72);
}

/// A real image height is where the chief ray lands: without aiming, the chief ray through the
/// paraxial pupil centre meets the image plane at the asked height (1e-9 mm), also off both
/// axes and at a finite object; with rays aimed, the one that crosses the real stop at its
/// centre does (1e-8 mm: aiming meets the stop to 1e-10 mm). A height no chief ray reaches is an error that names it.
#[test]
fn real_image_heights_put_the_chief_ray_there() {
    use tolray::trace::reference::trace_ray;
    let mut far = Lens::load("cooke-triplet").unwrap();
    far.object = Object::Infinite;
    let mut near = far.clone();
    near.object = Object::Finite { distance_mm: 400.0 };
    for (lens, name) in [(far, "at infinity"), (near, "at 400 mm")] {
        let wl = lens.primary_wavelength_nm;
        let para = lens.paraxial(wl).unwrap();
        let sys = lens.compile();
        let n = sys.indices(wl);
        let stop = para.stop_surface;
        for aim in [false, true] {
            for (x, y) in [(0.0, 0.0), (0.0, 12.0), (-3.0, 9.5)] {
                let field = Field::RealImageHeightMm { x, y };
                let mut pupil = Pupil::grid(4);
                pupil.aim = aim;
                let set = tolray::trace::RaySet::generate(&lens, &para, field, &pupil, wl).unwrap();
                assert_eq!(set.field, field);
                let (o, d) = set.chief;
                let r = trace_ray(&sys, &n, wl, o, d, false, None);
                let p = sys.image.point_to_local(r.o);
                let at = format!("{name}, aim {aim}, ({x}, {y})");
                // Aiming meets the stop point to 1e-10 mm, which the lens magnifies.
                let tol = if aim { 1e-8 } else { 1e-9 };
                assert!(
                    (p.x - x).abs() < tol && (p.y - y).abs() < tol,
                    "{at}: chief ray at ({}, {})",
                    p.x,
                    p.y
                );
                if aim {
                    let s = trace_ray(&sys, &n, wl, o, d, false, Some(stop));
                    let row = &sys.rows[stop];
                    let q = row.rot.apply_t(s.o - row.pos);
                    assert!(q.x.abs() < 1e-9 && q.y.abs() < 1e-9, "{at}: stop at {q:?}");
                }
            }
        }
    }
    let lens = Lens::load("cooke-triplet").unwrap();
    let para = lens.paraxial(lens.primary_wavelength_nm).unwrap();
    let e = Field::RealImageHeightMm { x: 0.0, y: 1e4 }
        .resolved(&lens, &para, false)
        .unwrap_err();
    assert!(
        e.message()
            .contains("real image height field (0, 10000) mm"),
        "{e}"
    );
}

/// Fields and vignetting factors survive .zmx -> JSON -> .zmx and .zmx -> .zmx: the same field
/// points (OpticStudio's signs in both .zmx files), weights and factors, and the same rays.
#[test]
fn fields_and_vignetting_round_trip() {
    let path = fixture("real").join("rayoptics/US00583336-2-scaled.zmx");
    let z = zemax::read_file(&path, &GlassCatalogs::builtin()).unwrap();
    let dir = std::env::temp_dir().join(format!("tolray-zmx-fields-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json_path = dir.join("lens.json");
    json::write_file(&z.lens, &json_path).unwrap();
    let from_json = json::read_file(&json_path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(from_json.fields, z.lens.fields);
    let again = zemax::from_str(
        &zemax::to_string(&from_json, None),
        &GlassCatalogs::builtin(),
    )
    .unwrap();
    assert_eq!(again.lens.fields, z.lens.fields);
    let same = zemax::from_str(
        &zemax::to_string(&z.lens, Some(&z.extras)),
        &GlassCatalogs::builtin(),
    )
    .unwrap();
    assert_eq!(same.lens.fields, z.lens.fields);
    assert_eq!(same.extras.fields, z.extras.fields);
    let text = zemax::to_string(&from_json, None);
    assert!(text.contains("YFLN 0 17 24"), "{text}");
    assert!(
        text.contains("VCYN 0 0.1556542586327 0.364762539196"),
        "{text}"
    );
    // The rays of the vignetted field, from the file and from the round trip.
    let p = &z.lens.fields[2];
    assert!(!p.vignetting.is_none());
    let rays = |l: &Lens| {
        let para = l.paraxial(l.primary_wavelength_nm).unwrap();
        tolray::trace::RaySet::generate(l, &para, p.field, &Pupil::grid(8), l.primary_wavelength_nm)
            .unwrap()
    };
    let (a, b) = (rays(&z.lens), rays(&again.lens));
    assert_eq!(a.pupil, b.pupil);
    assert_eq!(a.directions, b.directions);
    // Invalid field points in JSON are errors that say what is wrong.
    let mut v = json::to_value(&z.lens);
    v["fields"][1]["vignetting"]["vcy"] = serde_json::json!(1.5);
    let e = json::from_value(&v).unwrap_err();
    assert!(
        e.message()
            .contains("field 2: vignetting compression y 1.5"),
        "{e}"
    );
    v["fields"][1]["vignetting"] = serde_json::json!({"vdq": 0.1});
    let e = json::from_value(&v).unwrap_err();
    assert!(e.message().contains("unknown key \"vdq\""), "{e}");
    let mut v = json::to_value(&z.lens);
    v["fields"][0] = serde_json::json!({"height_mm": [0, 1]});
    let e = json::from_value(&v).unwrap_err();
    assert!(e.message().contains("all of one kind"), "{e}");
}
