//! First-order data, spots, raw traces, exit codes, pictures, Monte Carlo shards and optics training.

use super::*;

#[test]
fn info_prints_the_reference_first_order_data() {
    let (code, out, _) = tolray(&["info", "lens2"]);
    assert_eq!(code, 0);
    assert!(out.contains("50.277907 mm"), "EFL\n{out}");
    assert!(out.contains("29.876996 mm"), "EP position\n{out}");
    let (code, out, _) = tolray(&["info", "lens1", "--json"]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let efl = v["paraxial"]["efl_mm"].as_f64().unwrap();
    assert!((efl - 48.53684694175222).abs() < 1e-9);
    // A folded lens: its folds and tilts; a virtual object: said so.
    let data = concat!(env!("TOLRAY_ROOT"), "/tests/data/zemax/");
    let (code, out, _) = tolray(&["info", &format!("{data}fold.zmx")]);
    assert_eq!(code, 0);
    assert_eq!(
        out.matches("fold mirror: the axis after it turns").count(),
        2,
        "{out}"
    );
    assert!(out.contains("tilted 45.000000 degrees"), "{out}");
    let (code, out, _) = tolray(&["info", &format!("{data}virtual-object.zmx")]);
    assert_eq!(code, 0);
    assert!(
        out.contains("object at 50 mm behind the first vertex: a virtual object"),
        "{out}"
    );
    assert!(
        out.contains("23.685824 mm"),
        "paraxial image distance\n{out}"
    );
    // --object: a real object overrides the file's virtual one; virtual:MM gives it back.
    let file = format!("{data}virtual-object.zmx");
    let (code, out, _) = tolray(&["info", &file, "--object", "1000"]);
    assert_eq!(code, 0);
    assert!(!out.contains("virtual object"), "{out}");
    let (code, out, _) = tolray(&["info", &file, "--object", "virtual:50"]);
    assert_eq!(code, 0);
    assert!(
        out.contains("a virtual object") && out.contains("23.685824 mm"),
        "{out}"
    );
    let (code, _, err) = tolray(&["info", &file, "--object", "virtual:-5"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("a virtual object needs a distance in mm"),
        "{err}"
    );
    // An afocal lens (optiland's all-flat fold mirror): no focal length, said so, in the text
    // and as JSON nulls; its spot at its file's field; a fraction field exits 1 saying why.
    let file = format!("{data}real/optiland/simple_fold_mirror_up.zmx");
    let (code, out, _) = tolray(&["info", &file]);
    assert_eq!(code, 0);
    assert!(
        ["(in air, 1/Φ)", "(in image space, n'/Φ)"]
            .iter()
            .all(|k| out
                .lines()
                .any(|l| l.contains(&format!("effective focal length {k}"))
                    && l.trim_end().ends_with("afocal")))
            && out.contains("angular magnification (afocal)                       1.000000"),
        "{out}"
    );
    let (code, out, _) = tolray(&["info", &file, "--json"]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["paraxial"]["efl_mm"].is_null(), "{out}");
    assert_eq!(v["paraxial"]["angular_magnification"].as_f64(), Some(1.0));
    let (code, out, err) = tolray(&["spot", &file]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("7083.1013"), "optiland's RMS\n{out}");
    let (code, _, err) = tolray(&["spot", &file, "--fields", "0.7"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("the lens is afocal"), "{err}");
    // Afocal image space: angular spots (optiland's 207.712 µrad for this Keplerian).
    let file = format!("{data}keplerian.zmx");
    let (code, out, err) = tolray(&["spot", &file, "--afocal"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("RMS (µrad)") && out.contains("cy (mrad)") && out.contains("207.7121"),
        "{out}"
    );
}

#[test]
fn spot_json_reproduces_reference_rms() {
    let want = [
        4.833032052561748,
        9.94319254102365,
        15.279530400713975,
        10.377528827647229,
    ];
    let (code, out, err) = tolray(&[
        "spot",
        "cooke-triplet",
        "--object",
        "inf",
        "--fields",
        "0deg,10deg,14deg,20deg",
        "--pupil",
        "grid:64",
        "--no-apertures",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for (k, w) in want.iter().enumerate() {
        let got = v[k]["stats"]["rms_um"].as_f64().unwrap();
        assert!(((got - w) / w).abs() < 1e-6, "field {k}: {got} vs {w}");
    }
    let png = tmp("spots.png");
    let (code, out, _) = tolray(&[
        "spot",
        "lens1",
        "--wavelengths",
        "rgb",
        "--png",
        png.to_str().unwrap(),
    ]);
    assert_eq!(code, 0);
    assert!(out.contains("poly"));
    // 4 field panels of 380 x 390 points, drawn at 2 pixels per point.
    assert_eq!(image_size(&png), (3080, 900));
}

pub(super) fn image_size(p: &std::path::Path) -> (u32, u32) {
    let bytes = std::fs::read(p).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    let be = |i: usize| u32::from_be_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
    (be(16), be(20))
}

#[test]
fn raw_trace_round_trip() {
    let input = tmp("rays.csv");
    std::fs::write(&input, "ox,oy,oz,dx,dy,dz,wavelength_nm\n0,1,-10,0,0,1,587.5618\n0,0,-10,0,0,2,486.1327\n0,15,-10,0,0,1,587.5618\n0,1,-10,0,0,1,587.5618\n").unwrap();
    let out = tmp("hits.csv");
    let (code, _, err) = tolray(&[
        "trace",
        "lens1",
        "--rays",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let text = std::fs::read_to_string(&out).unwrap();
    let rows: Vec<Vec<&str>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 4);
    assert_eq!(rows[0][7], "alive");
    assert_eq!(rows[2][7], "vignetted@0");
    assert_eq!(rows[0], rows[3], "same ray, same answer");
    // The axial ray stays on the axis and lands on the image plane (z = 60.52 mm).
    let z: f64 = rows[1][2].parse().unwrap();
    let y: f64 = rows[1][1].parse().unwrap();
    assert!((z - 60.52).abs() < 1e-9 && y.abs() < 1e-12);
    // Against the library on the same ray.
    let lens = tolray::Lens::load("lens1").unwrap();
    let sys = lens.compile();
    let n = sys.indices(587.5618);
    let r = tolray::trace::reference::trace_ray(
        &sys,
        &n,
        587.5618,
        tolray::math::Vec3::new(0.0, 1.0, -10.0),
        tolray::math::Vec3::new(0.0, 0.0, 1.0),
        true,
        None,
    );
    let y0: f64 = rows[0][1].parse().unwrap();
    let opl: f64 = rows[0][6].parse().unwrap();
    assert!((y0 - r.o.y).abs() < 1e-10 && (opl - r.opl).abs() < 1e-9);
    // --no-apertures lets the far ray through the first surface.
    let (code, _, _) = tolray(&[
        "trace",
        "lens1",
        "--rays",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-apertures",
    ]);
    assert_eq!(code, 0);
    assert!(!std::fs::read_to_string(&out)
        .unwrap()
        .contains("vignetted@0"));
}

#[test]
fn errors_and_exit_codes() {
    let (code, _, err) = tolray(&["spot"]);
    assert_eq!(code, 2, "usage error: {err}");
    // A negative value is a value, not a flag: a field below the axis traces (clap refused it
    // as "unexpected argument '-0'" before), and a negative noise is an error naming its flag.
    let (code, out, err) = tolray(&["spot", "lens1", "--fields", "-0.7", "--json"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("-0.7"), "{out}");
    let (code, _, err) = tolray(&["deep", "lens1", "--noise", "-0.01", "--out", "x"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--noise -0.01"), "{err}");
    let (code, _, err) = tolray(&["info", "missing.json"]);
    assert_eq!(code, 1);
    assert!(
        err.contains("missing.json") && err.contains("built-in"),
        "{err}"
    );
    let bad = tmp("bad.json");
    std::fs::write(&bad, "{\"surfaces\": [{\"type\": \"Spheric\", \"r\": 5, \"roc\": 10, \"d_next\": 5, \"mat2\": \"unobtainium\"}], \"r_sensor\": 5}").unwrap();
    let (code, _, err) = tolray(&["info", bad.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(
        err.contains("bad.json") && err.contains("surface 0") && err.contains("unknown glass"),
        "{err}"
    );
    let rays = tmp("bad.csv");
    std::fs::write(&rays, "0,0,-1,0,0,1,587\n0,0,-1,0,zero,1,587\n").unwrap();
    let out = tmp("never.csv");
    let (code, _, err) = tolray(&[
        "trace",
        "lens1",
        "--rays",
        rays.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(
        err.contains("bad.csv") && err.contains("line 2, column 5"),
        "{err}"
    );
    assert!(!out.exists(), "no output file on error");
    // A wavelength at which a glass has no index names the file, the ray and the medium (the
    // release build reported such a ray as "tir@1").
    std::fs::write(&rays, "0,0,-1,0,0,1,587\n0,0,-1,0,0,1,5e-324\n").unwrap();
    let (code, _, err) = tolray(&[
        "trace",
        "lens1",
        "--rays",
        rays.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(
        err.contains("bad.csv")
            && err.contains("ray 2 (wavelength 5e-324 nm): the medium after surface 0"),
        "{err}"
    );
    assert!(!out.exists(), "no output file on error");
    let (code, _, err) = tolray(&["spot", "lens1", "--fields", "abc"]);
    assert_eq!(code, 2, "a bad flag value is a usage error");
    assert!(err.contains("field \"abc\""), "{err}");
    // A field beyond the lens' coverage is a row of its own, not the end of the analysis
    // (issue 14: every field failed when one had no ray at the image): the others print, the
    // failed ones are named, and the exit code says a requested result is missing.
    let (code, out, err) = tolray(&["spot", "lens1", "--fields", "0,1,80deg"]);
    assert_eq!(code, 1, "{out}\n{err}");
    assert!(
        err.contains("no spot: field 80.000deg at ") && err.contains("no ray reached the image"),
        "{err}"
    );
    assert!(err.contains("1 of 3 spot rows have no result"), "{err}");
    assert_eq!(
        out.lines().count(),
        3,
        "a header and the two fields with spots: {out}"
    );
}

#[test]
fn layout_and_demo_write_pictures() {
    let png = tmp("layout.png");
    let (code, _, err) = tolray(&["layout", "cooke-triplet", "--png", png.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(image_size(&png), (2200, 1120));
    let dir = tmp("demo");
    let (code, out, err) = tolray(&["demo", "--optics", "--out", dir.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("cooke-triplet"));
    for n in [
        "lens1-spots.png",
        "lens2-layout.png",
        "cooke-triplet-spots.json",
    ] {
        assert!(dir.join(n).exists(), "{n}");
    }
}

#[test]
fn tolerance_shards_merge_and_patterns_retrace() {
    let dir = tmp("mc");
    std::fs::create_dir_all(&dir).unwrap();
    let s = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let common = [
        "tolerance",
        "lens1",
        "--trials",
        "12",
        "--seed",
        "3",
        "--pupil",
        "grid:12",
        "--compensate",
        "focus",
    ];
    let (code, out, err) = tolray(
        &[
            &common[..],
            &[
                "--json",
                &s("all.json"),
                "--png",
                &s("h.png"),
                "--save-pattern",
                "4",
                &s("p4.json"),
            ],
        ]
        .concat(),
    );
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("yield: 90 %") && err.contains("\"type\": \"decenter\""),
        "prints the spec used\n{err}"
    );
    for k in 0..2 {
        let (code, out, _) = tolray(
            &[
                &common[..],
                &[
                    "--shard",
                    &format!("{k}/2"),
                    "--json",
                    &s(&format!("part{k}.json")),
                ],
            ]
            .concat(),
        );
        assert_eq!(code, 0);
        assert!(out.contains("partial report"));
    }
    let (code, _, err) = tolray(&[
        "merge",
        &s("part1.json"),
        &s("part0.json"),
        "--json",
        &s("merged.json"),
    ]);
    assert_eq!(code, 0, "{err}");
    let all: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s("all.json")).unwrap()).unwrap();
    let merged: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s("merged.json")).unwrap()).unwrap();
    assert!(
        all == merged,
        "merged shard reports differ from the single run"
    );
    // The saved pattern re-traces to the trial's numbers (no compensator, so compare with the
    // library's uncompensated RMS of the same pattern).
    let pattern =
        tolray::tolerance::Perturbation::read(std::path::Path::new(&s("p4.json"))).unwrap();
    assert!(pattern == serde_json::from_value(all["trials"][4]["pattern"].clone()).unwrap());
    let (code, _, err) = tolray(&["spot", "lens1", "--perturb", &s("p4.json"), "--fields", "0"]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = tolray(&["merge", &s("part1.json"), "--json", &s("bad.json")]);
    assert_eq!(code, 1);
    assert!(err.contains("missing"), "{err}");
    std::fs::write(
        s("spec.json"),
        r#"{"operands": [{"type": "decenter", "max": 0.01, "elements": [7]}]}"#,
    )
    .unwrap();
    let (code, _, err) = tolray(&[
        "tolerance",
        "lens1",
        "--trials",
        "2",
        "--spec",
        &s("spec.json"),
    ]);
    assert_eq!(code, 1);
    assert!(
        err.contains("spec.json") && err.contains("element 7 is out of range"),
        "{err}"
    );
    let (code, out, _) = tolray(&[
        "sensitivity",
        "cooke-triplet",
        "--top",
        "3",
        "--pupil",
        "grid:12",
    ]);
    assert_eq!(code, 0);
    assert_eq!(out.lines().count(), 5);
}

#[test]
fn training_resumes_exactly_and_reports() {
    let dir = tmp("train");
    let s = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let common = [
        "--iters",
        "3",
        "--samples",
        "4",
        "--psf-spp",
        "64",
        "--eval-trials",
        "8",
        "--checkpoint-every",
        "2",
    ];
    // One uninterrupted run of 3 + 3 iterations.
    let (code, out, err) =
        tolray(&[&["train", "lens1", "--out", &s("full")][..], &common].concat());
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("Held-out evaluation") && out.contains("stage 1") && out.contains("final"),
        "{out}"
    );
    let ck: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s("full/checkpoint.json")).unwrap()).unwrap();
    assert_eq!(ck["next_iter"], 6);
    // A run stopped after 2 iterations (as Ctrl-C or a killed job leaves it), then resumed.
    let config = serde_json::from_value(ck["config"].clone()).unwrap();
    let initial = std::fs::read_to_string(s("full/lens-initial.json")).unwrap();
    let mut state = tolray::optim::train::TrainState::new(
        &tolray::lens::json::from_str(&initial).unwrap(),
        config,
    );
    for _ in 0..2 {
        tolray::optim::train::step(&mut state).unwrap();
    }
    let resume_dir = dir.join("resumed");
    std::fs::create_dir_all(&resume_dir).unwrap();
    std::fs::write(
        resume_dir.join("checkpoint.json"),
        serde_json::to_string(&state).unwrap(),
    )
    .unwrap();
    std::fs::write(resume_dir.join("lens-initial.json"), &initial).unwrap();
    let (code, _, err) = tolray(&[
        "train",
        "--resume",
        &s("resumed"),
        "--out",
        &s("resumed"),
        "--eval-trials",
        "8",
    ]);
    assert_eq!(code, 0, "{err}");
    let a = std::fs::read_to_string(s("full/lens-final.json")).unwrap();
    let b = std::fs::read_to_string(s("resumed/lens-final.json")).unwrap();
    assert!(a == b, "a resumed run ends in exactly the same design");
    let log: Vec<&str> = std::fs::read_to_string(s("full/log.jsonl"))
        .unwrap()
        .leak()
        .lines()
        .collect();
    assert_eq!(log.len(), 6);
    assert!(dir.join("full/training.png").exists() && dir.join("full/lens-iter2.json").exists());
    let (code, _, err) = tolray(&["train", "--out", &s("x")]);
    assert_eq!(code, 2);
    assert!(err.contains("needs a LENS"), "{err}");
    let (code, _, err) = tolray(&[
        "train",
        "lens1",
        "--tolerance-lr-scale",
        "0",
        "--out",
        &s("x"),
    ]);
    assert_eq!(code, 2);
    assert!(
        err.contains("--tolerance-lr-scale 0: must be positive"),
        "{err}"
    );
}

/// `tolray bench` measures every figure it lists (finite, positive, the instruction sets this CPU
/// runs), and `TOLRAY_SIMD` forces a build: every build prints the same spot and PSF numbers, and
/// a build the CPU cannot run or a name that is none is refused with exit 2.
#[test]
fn bench_measures_and_instruction_sets_are_forced() {
    let run_env = |isa: &str, args: &[&str]| common::tolray_env(&[("TOLRAY_SIMD", isa)], args);
    let (code, out, err) = tolray(&[
        "bench",
        "--seconds",
        "0.001",
        "--deep",
        "none",
        "--all-isas",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let isas: Vec<&str> = v["isas_available"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| i.as_str().unwrap())
        .collect();
    // The build in use: the widest, unless the environment forces one.
    let in_use = std::env::var("TOLRAY_SIMD").unwrap_or_else(|_| isas[0].to_string());
    assert!(
        isas.contains(&"baseline") && v["isa"] == in_use.as_str(),
        "{out}"
    );
    let figs = v["figures"].as_array().unwrap();
    for f in figs {
        let x = f["value"].as_f64().unwrap();
        assert!(x.is_finite() && x > 0.0, "{f}");
    }
    let named = |what: &'static str| {
        figs.iter()
            .filter(move |f| f["what"].as_str().unwrap().starts_with(what))
    };
    // Each build's kernel in f32 and f64 on one thread and on all.
    let threads = v["threads"].as_u64().unwrap();
    let per_build = if threads > 1 { 4 } else { 2 };
    for isa in &isas {
        assert_eq!(
            named("kernel f").filter(|f| f["isa"] == *isa).count(),
            per_build,
            "{isa}"
        );
    }
    assert!(named("kernel dual").all(|f| f["note"].as_str().unwrap().contains("f64 value")));
    assert!(named("spot").all(|f| f["note"].as_str().unwrap().contains("% of the f64 kernel")));
    assert_eq!(named("PSF map").count(), 1);

    let spot = [
        "spot", "lens2", "--fields", "0,0.7", "--pupil", "grid:64", "--json",
    ];
    let (code, reference, err) = tolray(&spot);
    assert_eq!(code, 0, "{err}");
    let psf = ["psf", "lens2", "--field", "0.7", "--json"];
    let (code, psf_reference, err) = tolray(&psf);
    assert_eq!(code, 0, "{err}");
    for isa in &isas {
        let (code, out, err) = run_env(isa, &spot);
        assert_eq!((code, &out), (0, &reference), "spot with {isa}: {err}");
        let (code, out, err) = run_env(isa, &psf);
        assert_eq!((code, &out), (0, &psf_reference), "psf with {isa}: {err}");
    }
    let (code, _, err) = run_env("avx9000", &["info", "lens1"]);
    assert_eq!(code, 2);
    assert!(
        err.contains("TOLRAY_SIMD") && err.contains("avx9000"),
        "{err}"
    );
    if !isas.contains(&"avx512") {
        let (code, _, err) = run_env("avx512", &["info", "lens1"]);
        assert_eq!(code, 2);
        assert!(err.contains("does not run"), "{err}");
    }
    let (code, _, err) = tolray(&["bench", "--seconds", "0"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--seconds"), "{err}");
}
