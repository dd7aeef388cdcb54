//! DeepLens JSON: the reference files load unchanged, round trips are exact, legacy layouts and
//! asphere conventions are read, bad input gives errors that say where, and a mutation fuzzer
//! finds no panic.

use rand::{Rng, SeedableRng};
use serde_json::{json, Value};
use tolray::lens::json::{from_str, from_value, to_string};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::{ErrorKind, Lens, Object};

const LENS1: &str = include_str!("../../src/lens/builtin/lens1.json");

fn lens1_value() -> Value {
    serde_json::from_str(LENS1).unwrap()
}

fn err(v: Value) -> String {
    from_value(&v).unwrap_err().message().to_string()
}

#[test]
fn reference_files_load_with_their_prescriptions() {
    let l = from_str(LENS1).unwrap();
    assert_eq!(l.surfaces.len(), 7);
    assert_eq!(
        l.object,
        Object::Finite {
            distance_mm: 1000.0
        }
    );
    assert_eq!(l.stop_index(), Some(4));
    assert!((1.0 / l.surfaces[1].c + 435.76).abs() < 1e-9);
    assert!((l.sensor.half_diagonal_mm() - 5.07).abs() < 1e-12);
    assert!((l.surfaces[0].material.index(LAMBDA_D_NM) - 1.62041).abs() < 1e-15);
    let t = Lens::load("cooke-triplet").unwrap();
    assert_eq!(
        t.stop_index(),
        Some(3),
        "is_aperture on a spheric surface marks the stop"
    );
    assert!(
        !t.warnings().is_empty(),
        "the triplet's oversize clear apertures cross"
    );
    assert!(l.warnings().is_empty() && Lens::load("lens2").unwrap().warnings().is_empty());
}

#[test]
fn round_trip_is_exact() {
    for name in tolray::lens::builtin_names() {
        let l = Lens::load(name).unwrap();
        let back = from_str(&to_string(&l)).unwrap();
        assert_eq!(back, l, "{name}");
    }
    let mut l = Lens::load("lens2").unwrap();
    l.object = Object::Infinite;
    l.surfaces[0].k = -0.5;
    l.surfaces[0].asph[1] = 1.5e-6;
    l.surfaces[3].material = tolray::lens::Material::parse("N-SF5").unwrap();
    assert_eq!(from_str(&to_string(&l)).unwrap(), l);
    // Found by examples/fuzz.rs: a curvature whose radius overflows (5e-324 /mm) was written as
    // "roc": null, and tolray refused the file it wrote.
    for c in [5e-324, -1e-310, 1e-300] {
        l.surfaces[0].c = c;
        assert_eq!(from_str(&to_string(&l)).unwrap(), l, "c = {c:e}");
    }
}

#[test]
fn legacy_absolute_positions_and_sensor() {
    let mut v = lens1_value();
    let mut z = 0.0;
    for s in v["surfaces"].as_array_mut().unwrap() {
        let d = s["d_next"].as_f64().unwrap();
        s.as_object_mut().unwrap().remove("d_next");
        s["d"] = json!(z);
        z += d;
    }
    v["d_sensor"] = json!(z);
    let legacy = from_value(&v).unwrap();
    let modern = from_str(LENS1).unwrap();
    for (a, b) in legacy.surfaces.iter().zip(&modern.surfaces) {
        assert!((a.d_next_mm - b.d_next_mm).abs() < 1e-12);
    }
}

#[test]
fn asphere_coefficients_with_and_without_use_ai2() {
    let mut v = lens1_value();
    v["surfaces"][0]["type"] = json!("Aspheric");
    v["surfaces"][0]["k"] = json!(-0.3);
    v["surfaces"][0]["ai"] = json!([1e-5, 2e-7]);
    v["surfaces"][0]["use_ai2"] = json!(false);
    let l = from_value(&v).unwrap();
    assert_eq!(l.surfaces[0].asph[..3], [0.0, 1e-5, 2e-7]);
    v["surfaces"][0]["use_ai2"] = json!(true);
    assert_eq!(
        from_value(&v).unwrap().surfaces[0].asph[..3],
        [1e-5, 2e-7, 0.0]
    );
    v["surfaces"][0].as_object_mut().unwrap().remove("use_ai2");
    assert_eq!(
        from_value(&v).unwrap().surfaces[0].asph[..2],
        [1e-5, 2e-7],
        "legacy files start at a2"
    );
}

#[test]
fn errors_say_what_and_where() {
    let e = from_str("{\n  \"surfaces\": [\n    {\"type\": \"Spheric\",, }\n  ]\n}").unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Parse);
    assert!(e.message().starts_with("line 3, column"), "{}", e.message());

    let mut v = lens1_value();
    v["surfaces"][2].as_object_mut().unwrap().remove("mat2");
    assert!(err(v).starts_with("surface 2: missing \"mat2\""));

    let mut v = lens1_value();
    v["surfaces"][3]["d_next"] = json!(-1.0);
    assert!(err(v).contains("surface 3: gap to the next surface -1 mm is negative"));

    let mut v = lens1_value();
    v["surfaces"][6]["r"] = json!(19.0);
    assert!(err(v).contains("surface 6: clear semi-aperture 19 mm exceeds the surface's rim"));

    let mut v = lens1_value();
    v["surfaces"][0]["mat2"] = json!("0.8/40");
    assert!(err(v).contains("from 0.9 to 5"));

    let mut v = lens1_value();
    v["surfaces"][5]["mat2"] = json!("N-BK77");
    let m = err(v);
    assert!(
        m.contains("surface 5") && m.contains("unknown glass \"N-BK77\"") && m.contains("N-BK7"),
        "{m}"
    );

    let mut v = lens1_value();
    v["surfaces"][1]["type"] = json!("Cubic");
    assert!(err(v).contains("surface 1: unsupported surface type \"Cubic\""));

    let mut v = lens1_value();
    v["surfaces"][1]["roc"] = json!("big");
    assert!(err(v).contains("surface 1: \"roc\" must be a number"));

    let mut v = lens1_value();
    v.as_object_mut().unwrap().remove("r_sensor");
    assert!(err(v).contains("missing \"r_sensor\""));

    let dir = std::env::temp_dir().join(format!("tolray-json-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("broken.json");
    std::fs::write(&p, "{ \"surfaces\": [ }").unwrap();
    let e = tolray::lens::json::read_file(&p).unwrap_err();
    assert!(
        e.message().contains("broken.json") && e.message().contains("line 1"),
        "{}",
        e.message()
    );
    let e = Lens::load("no-such-lens").unwrap_err();
    assert!(e.message().contains("not a built-in lens"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A sensor size and a resolution whose aspects differ would make non-square pixels, which
/// tolray cannot model: refused, naming both (the sensor was silently reshaped to the
/// resolution's aspect). Without a resolution, a size gets 2000 pixels along its longer side
/// and its own aspect. An `obj_depth` beyond the largest finite object distance is a prescription
/// error (INVALID_INPUT in the C ABI), like the others, not a command-line argument error;
/// `obj_depth: 0` puts the object on the first vertex's plane.
#[test]
fn sensor_aspect_and_object_depth_are_prescription_errors() {
    let mut v = lens1_value();
    v.as_object_mut().unwrap().remove("r_sensor");
    v["sensor_size"] = json!([6.4, 4.8]);
    v["sensor_res"] = json!([2000, 2000]);
    let e = from_value(&v).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Invalid);
    assert!(e.message().contains("non-square pixels"), "{}", e.message());
    v["sensor_res"] = json!([4000, 3000]);
    let l = from_value(&v).unwrap();
    let [w, h] = l.sensor.size_mm();
    assert!(
        (w - 6.4).abs() < 1e-12 && (h - 4.8).abs() < 1e-12,
        "{w} {h}"
    );
    v.as_object_mut().unwrap().remove("sensor_res");
    let l = from_value(&v).unwrap();
    assert_eq!(l.sensor.resolution, [2000, 1500]);
    let [w, h] = l.sensor.size_mm();
    assert!(
        (w - 6.4).abs() < 1e-12 && (h - 4.8).abs() < 1e-12,
        "{w} {h}"
    );

    let mut v = lens1_value();
    v["obj_depth"] = json!(0.0);
    let l = from_value(&v).unwrap();
    assert_eq!(l.object, Object::Finite { distance_mm: 0.0 });
    v["obj_depth"] = json!(-1e300);
    let e = from_value(&v).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Invalid, "{}", e.message());
    assert!(e.message().contains("\"obj_depth\" -1"), "{}", e.message());
}

/// Structural and textual mutations of a real lens file: the reader must never panic, and any
/// lens it accepts must trace without panicking or producing non-finite alive rays.
#[test]
fn fuzz_the_reader() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let base = lens1_value();
    let bytes = LENS1.as_bytes();
    let junk = [
        json!(null),
        json!(-1.0),
        json!(0.0),
        json!(1e308),
        json!("x"),
        json!([]),
        json!({}),
        json!(true),
        json!(-1e-300),
        json!("1.5/0"),
    ];
    let mut accepted = 0;
    for it in 0..4000 {
        let text = if it % 2 == 0 {
            // Byte-level: delete, duplicate or replace a few bytes.
            let mut b = bytes.to_vec();
            for _ in 0..rng.random_range(1..4) {
                let i = rng.random_range(0..b.len());
                match rng.random_range(0..3) {
                    0 => {
                        b.remove(i);
                    }
                    1 => b.insert(i, b[i]),
                    _ => b[i] = b"0123456789-.e,:{}[]\" "[rng.random_range(0..21)],
                }
            }
            String::from_utf8_lossy(&b).into_owned()
        } else {
            // Structural: replace a value somewhere with junk.
            let mut v = base.clone();
            let s = rng.random_range(0..7);
            let keys = [
                "r",
                "roc",
                "d_next",
                "mat2",
                "type",
                "k",
                "ai",
                "is_aperture",
                "use_ai2",
                "vec_local",
                "pos_xy",
            ];
            let key = keys[rng.random_range(0..keys.len())];
            let val = junk[rng.random_range(0..junk.len())].clone();
            if rng.random_bool(0.8) {
                v["surfaces"][s][key] = val;
            } else {
                let top = [
                    "r_sensor",
                    "sensor_res",
                    "obj_depth",
                    "primary_wvln",
                    "surfaces",
                    "sensor_size",
                ];
                v[top[rng.random_range(0..top.len())]] = val;
            }
            v.to_string()
        };
        let result = std::panic::catch_unwind(|| from_str(&text));
        let Ok(parsed) = result else {
            panic!("reader panicked on mutation {it}:\n{text}")
        };
        if let Ok(lens) = parsed {
            accepted += 1;
            let traced = std::panic::catch_unwind(|| {
                let sys = lens.compile();
                let mut b = tolray::trace::RayBatch::<f64>::new();
                for k in 0..32 {
                    b.push(
                        tolray::math::Vec3::new(0.0, k as f64 * 0.3 - 4.8, -1.0),
                        tolray::math::Vec3::new(0.0, 0.01, 1.0),
                    );
                }
                tolray::trace::trace(&sys, LAMBDA_D_NM, &mut b, Default::default());
                let ok = b.iter().all(|r| {
                    !r.status.is_alive()
                        || (r.o.x.is_finite() && r.o.y.is_finite() && r.o.z.is_finite())
                });
                ok
            });
            assert!(
                matches!(traced, Ok(true)),
                "accepted lens misbehaved on mutation {it}:\n{text}"
            );
        }
    }
    assert!(
        accepted > 100,
        "the fuzzer should also exercise accepted lenses ({accepted})"
    );
}

/// Issue 15, item 9: the C ABI's parameter setter could make a model glass the JSON reader
/// refuses (n_d 0.9, a negative Abbe number); both are now refused where they are set, and a
/// valid value still round-trips through the lens' own JSON.
#[test]
fn a_model_glass_set_through_the_c_abi_stays_readable() {
    use std::ffi::CString;
    use tolray::ffi::*;
    let mut v = lens1_value();
    v["surfaces"][0]["mat2"] = json!("1.6/40");
    let text = CString::new(v.to_string()).unwrap();
    let mut lens = std::ptr::null_mut();
    unsafe {
        assert_eq!(
            tolray_lens_from_json(text.as_ptr(), &mut lens),
            tolray_status::TOLRAY_OK
        );
        for (kind, value, ok) in [
            (TOLRAY_PARAM_GLASS_ND, 0.85, false),
            // A model glass that disperses needs n_d of at least 1, as in a .zmx file.
            (TOLRAY_PARAM_GLASS_ND, 0.95, false),
            (TOLRAY_PARAM_GLASS_ND, 6.0, false),
            (TOLRAY_PARAM_GLASS_VD, -5.0, false),
            (TOLRAY_PARAM_GLASS_VD, 0.0, false),
            (TOLRAY_PARAM_GLASS_ND, 1.7, true),
            (TOLRAY_PARAM_GLASS_VD, 55.0, true),
        ] {
            let p = tolray_param {
                kind,
                surface: 0,
                term: 0,
            };
            let mut out = std::ptr::null_mut();
            let status = tolray_lens_with_param(lens, &p, value, &mut out);
            assert_eq!(
                status == tolray_status::TOLRAY_OK,
                ok,
                "kind {kind} value {value}"
            );
            if ok {
                let mut n = 0usize;
                assert_eq!(
                    tolray_lens_to_json(out, std::ptr::null_mut(), 0, &mut n),
                    tolray_status::TOLRAY_OK
                );
                let mut buf = vec![0u8; n + 1];
                assert_eq!(
                    tolray_lens_to_json(out, buf.as_mut_ptr().cast(), n + 1, &mut n),
                    tolray_status::TOLRAY_OK
                );
                let back = from_str(std::str::from_utf8(&buf[..n]).unwrap()).unwrap();
                let want = if kind == TOLRAY_PARAM_GLASS_ND {
                    "1.7/40"
                } else {
                    "1.6/55"
                };
                assert_eq!(back.surfaces[0].material.json_name(), want);
                tolray_lens_free(out);
            } else {
                assert!(out.is_null());
                let mut msg = vec![0u8; 512];
                let len = tolray_last_error(msg.as_mut_ptr().cast(), msg.len());
                let msg = String::from_utf8_lossy(&msg[..len.min(511)]).into_owned();
                assert!(msg.contains("surface 0"), "{msg}");
            }
        }
        tolray_lens_free(lens);
    }
}

/// A folded lens (tests/data/fold.json, tests/data/zemax/fold.zmx converted) reads with its
/// folds and round-trips exactly; a malformed fold, a fold on a surface that does not reflect,
/// and an image-plane normal whose length underflows to zero (a fuzz finding: the spot
/// centroid came out NaN) are errors naming what is wrong.
#[test]
fn folds_read_and_malformed_ones_are_refused() {
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/fold.json"))
            .unwrap();
    let lens = from_str(&text).unwrap();
    assert_eq!(lens.surfaces.iter().filter(|s| s.fold.is_some()).count(), 2);
    assert_eq!(from_str(&to_string(&lens)).unwrap(), lens);
    let v: Value = serde_json::from_str(&text).unwrap();
    let with = |f: &dyn Fn(&mut Value)| {
        let mut v = v.clone();
        f(&mut v);
        err(v)
    };
    let m = with(&|v| v["surfaces"][3]["fold"] = json!({"tilt_deg": [90, 0]}));
    assert!(m.contains("tilt_deg"), "{m}");
    let m = with(&|v| v["surfaces"][3]["fold"] = json!({"tilt_deg": [90, 0, 0], "at": 1}));
    assert!(m.contains("unknown key \"at\""), "{m}");
    let m = with(&|v| v["surfaces"][1]["fold"] = json!({"tilt_deg": [90, 0, 0]}));
    assert!(
        m.contains("surface 1: a fold turns the axis at a mirror"),
        "{m}"
    );
    let m = with(&|v| v["surfaces"][3]["fold"]["tilt_deg"] = json!([1e308, 0, 0]));
    assert!(m.contains("fold tilts"), "{m}");
    let m = with(&|v| v["image_plane"]["normal"] = json!([0.0, 0.0, 5e-324]));
    assert!(m.contains("image plane: normal"), "{m}");
}

/// A lens of Q-type aspheres (tests/data/qbfs.json, tests/data/zemax/qbfs.zmx converted) reads
/// as the .zmx file does and round-trips exactly, and so does a "qcon" shape; a Q shape without
/// its normalization radius, with a radius of zero, or an unknown shape is an error naming the
/// surface and the key.
#[test]
fn q_type_aspheres_read_and_malformed_ones_are_refused() {
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/qbfs.json"))
            .unwrap();
    let lens = from_str(&text).unwrap();
    let zmx = tolray::lens::zemax::read_file(
        std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/data/zemax/qbfs.zmx"
        )),
        &tolray::lens::GlassCatalogs::builtin(),
    )
    .unwrap()
    .lens;
    for (a, b) in lens.surfaces.iter().zip(&zmx.surfaces) {
        assert_eq!((a.shape, a.asph, a.c, a.k), (b.shape, b.asph, b.c, b.k));
    }
    assert_eq!(from_str(&to_string(&lens)).unwrap(), lens);
    let v: Value = serde_json::from_str(&text).unwrap();
    let with = |f: &dyn Fn(&mut Value)| {
        let mut v = v.clone();
        f(&mut v);
        err(v)
    };
    let q = v["surfaces"]
        .as_array()
        .unwrap()
        .iter()
        .position(|s| s["shape"] == "qbfs")
        .unwrap();
    let m = with(&|v| {
        v["surfaces"][q]
            .as_object_mut()
            .unwrap()
            .remove("norm_radius");
    });
    assert!(
        m.contains(&format!("surface {q}")) && m.contains("missing \"norm_radius\""),
        "{m}"
    );
    let m = with(&|v| v["surfaces"][q]["norm_radius"] = json!(0.0));
    assert!(
        m.contains(&format!("surface {q}")) && m.contains("normalization radius 0"),
        "{m}"
    );
    // "qcon" (Q-type of type 1) reads as the same surface with Qcon polynomials, and its
    // missing radius is named as its own.
    let mut qcon = v.clone();
    qcon["surfaces"][q]["shape"] = json!("qcon");
    let l = from_str(&qcon.to_string()).unwrap();
    assert_eq!(
        l.surfaces[q].shape,
        tolray::lens::Shape::Qcon {
            norm_radius_mm: v["surfaces"][q]["norm_radius"].as_f64().unwrap()
        }
    );
    assert_eq!(from_str(&to_string(&l)).unwrap(), l);
    qcon["surfaces"][q]
        .as_object_mut()
        .unwrap()
        .remove("norm_radius");
    let m = err(qcon);
    assert!(m.contains("of the \"qcon\" shape"), "{m}");
    let m = with(&|v| v["surfaces"][q]["shape"] = json!("qted"));
    assert!(
        m.contains("unknown \"shape\" \"qted\"") && m.contains("qcon"),
        "{m}"
    );
}

/// Issue 41's silent wrong results: a surface normal whose squared length overflows passed
/// validation and was traced as untilted; one turned within 1e-6 of 90 degrees was written as
/// coordinate breaks the .zmx reader refuses; a model glass "1e308/4" was a material with a NaN
/// index; an AGF glass named "1.5" was written to JSON as "1.5" and read back as a constant
/// index. Each is now refused (or, for the glass, skipped with a warning) where it comes in.
#[test]
fn directions_and_names_that_cannot_round_trip_are_refused() {
    use tolray::lens::{agf::AgfCatalog, Material};
    for (k, n) in [
        (0usize, json!([0.0, -1e308, 1.0])),
        (0, json!([1e200, 0.0, 1e200])),
        (2, json!([0.0, 1.0, 1e-7])),
        (2, json!([0.0, 0.0, -1.0])),
    ] {
        let mut v = lens1_value();
        v["surfaces"][k]["vec_local"] = n.clone();
        let m = err(v);
        assert!(
            m.contains(&format!("surface {k}")) && m.contains("turned less than 90 degrees"),
            "{n}: {m}"
        );
    }
    // Tilted but well within 90 degrees: accepted.
    let mut v = lens1_value();
    v["surfaces"][2]["vec_local"] = json!([0.0, 0.01, 1.0]);
    assert!(from_value(&v).is_ok());
    // A decentre of 9e18 mm (fuzz --seed 13 --target lens-json: written to .zmx, read back
    // with its paraxial image distance 18.9 mm as -532 mm) is refused; 1 km is the bound.
    for (d, ok) in [(9e18, false), (1e6, true), (-1.000001e6, false)] {
        let mut v = lens1_value();
        v["surfaces"][2]["pos_xy"] = json!([0.5, d]);
        match from_value(&v) {
            Ok(_) => assert!(ok, "{d}"),
            Err(e) => assert!(
                !ok && e.message().contains("surface 2") && e.message().contains("decenter"),
                "{d}: {}",
                e.message()
            ),
        }
    }
    for bad in ["1e308/4", "7/40", "0.95/40", "1e308", "6"] {
        let e = Material::parse(bad).unwrap_err();
        assert!(
            e.message().contains("from 0.9 to 5") || e.message().contains("at least 1"),
            "{bad}: {}",
            e.message()
        );
    }
    assert_eq!(Material::parse("0.95").unwrap(), Material::Constant(0.95));
    let agf = "NM 1.5 2 0 1.5168 64.17 0 1\nCD 1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002 1.01046945 1.03560653E+002\nLD 0.3 2.5\n\
               NM GOOD 2 0 1.5168 64.17 0 1\nCD 1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002 1.01046945 1.03560653E+002\nLD 0.3 2.5\n";
    let (cat, warnings) = AgfCatalog::from_str(agf, "T").unwrap();
    assert_eq!(cat.glasses.len(), 1);
    assert_eq!(cat.glasses[0].name, "GOOD");
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("line 1") && w.contains("\"1.5\" reads as a constant index")),
        "{warnings:?}"
    );
}

/// Issue 41: OpticStudio prints the EFL "in air" (1/Φ, tolray's `efl_mm`) and "in image space"
/// (n'/Φ, the image-space index signed negative after an odd number of mirrors). Closed forms:
/// a concave mirror of radius -400 mm has 1/Φ = 200 mm and -200 mm in image space; a lens
/// imaging into water (n' = 1.333) has n'/Φ = 1.333/Φ; the Cassegrain (two mirrors) 800 mm in
/// both.
#[test]
fn focal_lengths_in_air_and_in_image_space() {
    let mirror = r#"{"info": "concave mirror", "primary_wvln": 0.5875618, "r_sensor": 1,
        "sensor_res": [512, 512],
        "surfaces": [{"type": "Mirror", "r": 20, "c": -0.0025, "d_next": -200, "mat2": "air",
        "is_aperture": true}]}"#;
    let p = from_str(mirror).unwrap().paraxial(LAMBDA_D_NM).unwrap();
    assert!((p.efl_mm.unwrap() - 200.0).abs() < 1e-9, "{:?}", p.efl_mm);
    assert!((p.efl_image_space_mm.unwrap() + 200.0).abs() < 1e-9);
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/cassegrain.json");
    let p = Lens::load(path).unwrap().paraxial(LAMBDA_D_NM).unwrap();
    assert!((p.efl_mm.unwrap() - 800.0).abs() < 1e-6, "{:?}", p.efl_mm);
    assert_eq!(p.efl_image_space_mm, p.efl_mm);
    let mut v = lens1_value();
    let last = v["surfaces"].as_array().unwrap().len() - 1;
    v["surfaces"][last]["mat2"] = json!("1.333");
    let p = from_value(&v).unwrap().paraxial(LAMBDA_D_NM).unwrap();
    let f = p.efl_mm.unwrap();
    assert!((p.efl_image_space_mm.unwrap() - 1.333 * f).abs() < 1e-9 * f.abs());
}
