//! The `tolray` binary end to end: numbers against the reference values, files, exit codes.

mod common;

use common::tolray;
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    common::scratch_dir("cli").join(name)
}

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
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zemax/");
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
        out.contains("effective focal length                                 afocal")
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

fn image_size(p: &std::path::Path) -> (u32, u32) {
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

#[test]
fn convert_between_zmx_and_json() {
    let fixture = |n: &str| format!("{}/tests/data/zemax/{n}", env!("CARGO_MANIFEST_DIR"));
    // A .zmx file's field points are the default fields of `spot` and `layout` (issue 14): the
    // triplet file's YFLN 0, 10, 14, 20 (degrees), not fractions 0, 0.5, 0.7, 1, in tolray's
    // sign (OpticStudio's +10° rises toward +y: the object is below the axis, tolray's -10°),
    // so the image lies above the axis as in OpticStudio.
    let triplet = fixture("cooke-triplet.zmx");
    let (code, out, err) = tolray(&["spot", &triplet, "--pupil", "grid:8"]);
    assert_eq!(code, 0, "{err}");
    let fields: Vec<&str> = out
        .lines()
        .skip(1)
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert_eq!(
        fields,
        ["0.000deg", "-10.000deg", "-14.000deg", "-20.000deg"],
        "{out}"
    );
    let centroid_y: Vec<f64> = out
        .lines()
        .skip(1)
        .filter_map(|l| l.split_whitespace().last()?.parse().ok())
        .collect();
    assert!(centroid_y[1..].iter().all(|&y| y > 8.0), "{out}");
    // `info` lists a file's fields with their vignetting factors.
    let vignetted = format!(
        "{}/tests/data/zemax/real/rayoptics/US00583336-2-scaled.zmx",
        env!("CARGO_MANIFEST_DIR")
    );
    let (code, out, err) = tolray(&["info", &vignetted]);
    assert_eq!(code, 0, "{err}");
    let row = out
        .lines()
        .find(|l| l.contains("-24.000deg"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(row.ends_with("0.0000   0.0547   0.0020   0.3648"), "{row}");
    // A file's real image heights (FTYP 3) and its primary wavelength (248 nm, a UV
    // lithography lens) are the defaults; the real chief ray lands on each height.
    let uv = format!(
        "{}/tests/data/zemax/real/rayoptics/US05831776-1.zmx",
        env!("CARGO_MANIFEST_DIR")
    );
    let (code, out, err) = tolray(&["spot", &uv, "--pupil", "grid:8", "--json"]);
    assert_eq!(code, 0, "{err}");
    let rows: serde_json::Value = serde_json::from_str(&out).unwrap();
    let rows = rows.as_array().unwrap_or_else(|| panic!("{out}"));
    assert_eq!(rows.len(), 3, "{out}");
    for (r, h) in rows.iter().zip([0.0, 8.0, 12.0]) {
        assert_eq!(r["wavelength_nm"], 248.0, "{r}");
        assert_eq!(r["field"]["RealImageHeightMm"]["y"], h, "{r}");
        let chief_y = r["chief_mm"][1].as_f64().unwrap();
        assert!((chief_y - h).abs() < 1e-9, "{r}");
    }
    let (code, out, _) = tolray(&["spot", &triplet, "--pupil", "grid:8", "--fields", "0.5"]);
    assert_eq!(code, 0);
    assert_eq!(
        out.lines().count(),
        2,
        "--fields overrides the file's: {out}"
    );
    let dir = tmp("convert");
    std::fs::create_dir_all(&dir).unwrap();
    let p = |n: &str| dir.join(n).to_str().unwrap().to_string();
    // JSON -> .zmx -> JSON is exact, but for the fields: a lens without any is written with
    // paraxial image heights at 0, 0.5, 0.7 and 1 of the sensor's half-diagonal (OpticStudio
    // needs fields), which come back as the lens' fields.
    let (code, _, err) = tolray(&["convert", "lens1", &p("lens1.zmx")]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("wrote"), "{err}");
    let (code, _, err) = tolray(&["convert", &p("lens1.zmx"), &p("lens1.json")]);
    assert_eq!(code, 0, "{err}");
    let mut back = tolray::lens::json::read_file(std::path::Path::new(&p("lens1.json"))).unwrap();
    let lens1 = tolray::Lens::load("lens1").unwrap();
    let r = lens1.sensor.half_diagonal_mm();
    let heights: Vec<tolray::trace::Field> = back.fields.iter().map(|p| p.field).collect();
    let want =
        [0.0, 0.5, 0.7, 1.0].map(|f| tolray::trace::Field::ImageHeightMm { x: 0.0, y: f * r });
    assert_eq!(heights.len(), 4);
    for (h, w) in heights.iter().zip(want) {
        let (a, b) = (h.xy(), w.xy());
        assert!(
            matches!(h, tolray::trace::Field::ImageHeightMm { .. })
                && a.0 == 0.0
                && (a.1 - b.1).abs() < 1e-12 * r,
            "{h:?} vs {w:?}"
        );
    }
    back.fields.clear();
    assert_eq!(back, lens1);
    // Every command reads .zmx files.
    let (code, out, err) = tolray(&["info", &fixture("lens2.zmx")]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("50.277907 mm") && err.is_empty(),
        "{out}\n{err}"
    );
    // A perturbed lens becomes coordinate breaks.
    let pattern = dir.join("pattern.json");
    std::fs::write(
        &pattern,
        r#"{"elements": [{"element": 1, "decenter_mm": [0, 0.05], "tilt_deg": [0.1, 0, 0]}]}"#,
    )
    .unwrap();
    let (code, _, err) = tolray(&[
        "convert",
        "lens2",
        &p("fabricated.zmx"),
        "--perturb",
        pattern.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        std::fs::read_to_string(p("fabricated.zmx"))
            .unwrap()
            .matches("COORDBRK")
            .count(),
        4
    );
    // Warnings go to stderr and name the line.
    let text = std::fs::read_to_string(fixture("asphere.zmx")).unwrap();
    std::fs::write(
        p("odd.zmx"),
        text.replace("GCAT SCHOTT", "GCAT SCHOTT\nFOOB 1"),
    )
    .unwrap();
    let (code, _, err) = tolray(&["convert", &p("odd.zmx"), &p("odd.json")]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("warning: ") && err.contains("odd.zmx: line 7: 1 unknown command skipped (tolray does not read them): FOOB (line 7)"),
        "{err}"
    );
    // User glass catalogs.
    std::fs::write(
        p("user.zmx"),
        text.replace("GLAS N-BK7 0 0 1.5168 64.17", "GLAS NBK7-S5"),
    )
    .unwrap();
    let (code, _, err) = tolray(&["convert", &p("user.zmx"), &p("user.json")]);
    assert_eq!(code, 1);
    assert!(err.contains("unknown glass \"NBK7-S5\""), "{err}");
    let (code, _, err) = tolray(&[
        "info",
        &p("user.zmx"),
        "--glass-catalog",
        &fixture("test-catalog.agf"),
    ]);
    assert_eq!(code, 0, "{err}");
    // A malformed file: exit 1, the message names the file and the line, no output is left.
    std::fs::write(p("broken.zmx"), text.replace("CURV 0.05", "CURV 0.05x")).unwrap();
    let (code, _, err) = tolray(&["convert", &p("broken.zmx"), &p("never.json")]);
    assert_eq!(code, 1);
    let n = text.lines().position(|l| l.trim() == "CURV 0.05").unwrap() + 1;
    assert!(
        err.contains(&format!("broken.zmx: line {n}: CURV")),
        "{err}"
    );
    assert!(!dir.join("never.json").exists());
    let (code, _, err) = tolray(&[
        "convert",
        "lens1",
        &p("never.zmx"),
        "--glass-catalog",
        &p("missing.agf"),
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("missing.agf"), "{err}");
    assert!(!dir.join("never.zmx").exists());
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
    // Only .zmx and .json outputs: a usage error.
    let (code, _, err) = tolray(&["convert", "lens1", &p("lens1.txt")]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(".zmx or .json"), "{err}");
}

/// Without the `embree` feature, `validate --embree` says how to get it and exits with 1; without
/// `--embree` it is a usage error either way.
#[cfg(not(feature = "embree"))]
#[test]
fn validate_without_the_embree_feature_says_how_to_rebuild() {
    let (code, out, err) = tolray(&["validate", "lens1", "--embree", "--trials", "1"]);
    assert_eq!(code, 1, "{err}");
    assert!(out.is_empty());
    assert!(
        err.contains("`embree` feature") && err.contains("--features embree"),
        "{err}"
    );
    let (code, _, err) = tolray(&["validate", "lens1"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--embree"), "{err}");
}

/// Ctrl-C during `tolray train`: the run stops after the iteration in progress with exit code
/// 130, leaving a checkpoint equal to the state of an uninterrupted run after as many iterations,
/// a log of exactly those iterations, and a run that `--resume` finishes.
#[cfg(unix)]
#[test]
fn training_interrupted_by_ctrl_c_leaves_an_exact_checkpoint() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    use tolray::optim::train::{step, TrainState};
    let dir = tmp("ctrl-c");
    std::fs::create_dir_all(&dir).unwrap();
    let s = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let run_args = [
        "--stage",
        "both",
        "--pretrain-iters",
        "2",
        "--iters",
        "400",
        "--samples",
        "4",
        "--psf-spp",
        "64",
        "--eval-trials",
        "8",
        "--checkpoint-every",
        "1000",
    ];
    let err_file = std::fs::File::create(s("stderr.txt")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_tolray"))
        .args([&["train", "lens1", "--out", &s("run")][..], &run_args].concat())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err_file)
        .spawn()
        .unwrap();
    // Wait until a few iterations (some of stage 2) are logged, then send SIGINT.
    let log_lines = || {
        std::fs::read_to_string(s("run/log.jsonl"))
            .map(|t| t.lines().count())
            .unwrap_or(0)
    };
    let start = Instant::now();
    while log_lines() < 4 {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before it was interrupted"
        );
        assert!(start.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(5));
    }
    interrupt(&child);
    let status = child.wait().unwrap();
    let err = std::fs::read_to_string(s("stderr.txt")).unwrap();
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(
        err.contains("interrupted: checkpoint at iteration"),
        "{err}"
    );
    // The checkpoint is the exact state after its iterations, and the log holds each of them.
    let ck: TrainState =
        serde_json::from_str(&std::fs::read_to_string(s("run/checkpoint.json")).unwrap()).unwrap();
    let n = ck.next_iter;
    assert!(n >= 4 && n < ck.total_iters(), "stopped at {n}");
    assert_eq!(log_lines(), n);
    assert_eq!(
        std::fs::read_to_string(s("run/lens-latest.json")).unwrap(),
        tolray::lens::json::to_string(&ck.lens)
    );
    assert!(dir.join(format!("run/lens-iter{n}.json")).exists());
    let initial = std::fs::read_to_string(s("run/lens-initial.json")).unwrap();
    let mut state = TrainState::new(
        &tolray::lens::json::from_str(&initial).unwrap(),
        ck.config.clone(),
    );
    for _ in 0..n {
        step(&mut state).unwrap();
    }
    assert!(
        state == ck,
        "the checkpoint equals {n} uninterrupted iterations"
    );
    // --resume finishes the run.
    let (code, out, err) = tolray(&[
        "train",
        "--resume",
        &s("run"),
        "--out",
        &s("run"),
        "--eval-trials",
        "8",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("Held-out evaluation"), "{out}");
    assert_eq!(log_lines(), ck.total_iters());
}

/// Results that reach a user are finite or an error naming the cause, sizes are bounded before
/// anything is allocated, and an empty result is an error (defects 4, 5, 6 and 11 of the outside
/// review). Bad flag values exit 2, bad files exit 1.
#[test]
fn no_silent_non_finite_or_empty_results() {
    let lens = |name: &str, surf: &str| {
        let p = tmp(name);
        std::fs::write(
            &p,
            format!(
                "{{\"surfaces\": [{surf}, {{\"type\": \"Spheric\", \"r\": 5, \"roc\": -40, \"d_next\": 40, \"mat2\": \"air\"}}], \"r_sensor\": 5}}"
            ),
        )
        .unwrap();
        p.to_str().unwrap().to_string()
    };
    // A model glass with an absurd Abbe number: its index is not finite.
    let glass = lens(
        "nan-glass.json",
        r#"{"type": "Spheric", "r": 5, "roc": 40, "d_next": 3, "mat2": "1.6/1e-308"}"#,
    );
    let (code, out, err) = tolray(&["info", &glass]);
    assert_eq!(code, 1, "{out}");
    assert!(err.contains("surface 0") && err.contains("index"), "{err}");
    assert!(!out.contains("NaN"), "{out}");
    // A conic of -1e308 gave a NaN RMS spot; an image gap of 1e300 an infinite one.
    let conic = lens(
        "huge-conic.json",
        r#"{"type": "Aspheric", "r": 5, "roc": 40, "d_next": 3, "k": -1e308, "mat2": "N-BK7"}"#,
    );
    let (code, _, err) = tolray(&["spot", &conic]);
    assert_eq!(code, 1);
    assert!(err.contains("conic constant"), "{err}");
    let gap = lens(
        "huge-gap.json",
        r#"{"type": "Spheric", "r": 5, "roc": 40, "d_next": 1e300, "mat2": "N-BK7"}"#,
    );
    let (code, _, err) = tolray(&["spot", &gap]);
    assert_eq!(code, 1);
    assert!(err.contains("gap"), "{err}");
    // Flag values: empty or unaffordable sizes exit 2 with the limit in the message.
    let usage: &[(&[&str], &str)] = &[
        (&["tolerance", "lens1", "--trials", "0"], "trials"),
        (
            &["tolerance", "lens1", "--trials", "10000000000"],
            "10000000",
        ),
        (&["psf", "lens1", "--spp", "0"], "no rays"),
        (&["psf", "lens1", "--pitch-um", "1e-300"], "pitch"),
        (&["psf", "lens1", "--ks", "1"], "3 to 1025"),
        (
            &["spot", "lens1", "--pupil", "grid:100000"],
            "at most 4194304",
        ),
        (
            &["spot", "lens1", "--pupil", "random:100000000"],
            "at most 4194304",
        ),
        (
            &["psf-map", "lens1", "--grid", "64", "--ks", "1025"],
            "at most",
        ),
        (
            &["layout", "lens1", "--png", "x.png", "--rays", "100000000"],
            "--rays",
        ),
        (
            &["train", "lens1", "--lambda-spot", "nan", "--out", "x"],
            "lambda_spot",
        ),
        (
            &["train", "lens1", "--max-track=-1", "--out", "x"],
            "max_total_track_mm",
        ),
    ];
    for (args, says) in usage {
        let (code, _, err) = tolray(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    // A PSF window far too small for the blur: no ray lands, which is an error, not a zero PSF.
    let (code, _, err) = tolray(&[
        "psf",
        "lens1",
        "--ks",
        "3",
        "--pitch-um",
        "0.01",
        "--field",
        "1",
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("no ray landed"), "{err}");
}

/// Output paths are checked before any work (a missing directory used to fail only after the
/// whole computation), and Ctrl-C outside `train` exits 130 leaving no hidden temporary file.
#[test]
fn outputs_are_checked_first_and_ctrl_c_leaves_no_partial_file() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let dir = tmp("outputs");
    std::fs::create_dir_all(&dir).unwrap();
    let missing = dir.join("no-such-dir").join("r.json");
    let t = Instant::now();
    let (code, _, err) = tolray(&[
        "tolerance",
        "lens1",
        "--trials",
        "1000000",
        "--json",
        missing.to_str().unwrap(),
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("--json") && err.contains("does not exist"),
        "{err}"
    );
    assert!(
        t.elapsed() < Duration::from_secs(20),
        "checked only after the work"
    );
    let (code, _, err) = tolray(&["psf", "lens1", "--png", dir.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("is a directory"), "{err}");

    let out = dir.join("deep");
    let mut child = Command::new(env!("CARGO_BIN_EXE_tolray"))
        .args([
            "deep",
            "lens1",
            "--out",
            out.to_str().unwrap(),
            "--spot-iters",
            "100000",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !out.join("study.json").exists() {
        assert!(child.try_wait().unwrap().is_none(), "the run ended early");
        assert!(start.elapsed() < Duration::from_secs(60), "no progress");
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(300));
    interrupt(&child);
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(130), "{err}");
    // `deep` stops at the end of the iteration with a checkpoint to resume from.
    assert!(err.contains("tolray deep --resume"), "{err}");
    let ck: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("checkpoint.json")).unwrap())
            .unwrap();
    assert!(ck["spot"]["next_iter"].as_u64().unwrap() > 0, "{ck}");
    let (code, _, err) = tolray(&["deep", "lens1", "--resume", out.to_str().unwrap()]);
    assert_eq!(code, 2, "a lens with --resume is a usage error: {err}");
    let (code, _, err) = tolray(&["deep", "--resume", dir.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("checkpoint.json"), "{err}");
    let left: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// Sends SIGINT (what Ctrl-C sends) to a running `tolray`.
fn interrupt(child: &std::process::Child) {
    let pid = child.id().to_string();
    let kill = std::process::Command::new("sh")
        .args(["-c", "kill -INT \"$1\"", "sh", &pid])
        .status()
        .unwrap();
    assert!(kill.success());
}

/// `tolray glass`: a lookup in the built-in vendor catalogs.
#[test]
fn glass_lookup() {
    let (code, out, err) = tolray(&["glass", "n-bk7"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("N-BK7  (Schott)"), "{out}");
    assert!(out.contains("n_d 1.516800, V_d 64.17"), "{out}");
    // n at the d line from the formula, to the catalog's six digits.
    assert!(out.contains("n(587.5618 nm)d    1.516800"), "{out}");
    let (code, out, err) = tolray(&["glass", "S-LAH64", "--wavelengths", "450,650"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("(Ohara)") && out.contains("n(450.0000 nm)"),
        "{out}"
    );
    let (code, _, err) = tolray(&["glass", "S-LAH99"]);
    assert_eq!(code, 1);
    assert!(
        err.contains("in no catalog") && err.contains("S-LAH"),
        "{err}"
    );
}

/// `tolray train --decoder`: the image stage for one design. Stage 1 and the stage-2 design are
/// saved, logged and evaluated on the same units (the pair is stage 2 minus stage 1); a run
/// interrupted by Ctrl-C and resumed ends in exactly the files of an uninterrupted one; the
/// ablations and a start from a saved design; flags that belong to the other mode are usage
/// errors.
#[test]
fn train_with_a_decoder_runs_the_image_stage_and_resumes_exactly() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let dir = tmp("train-image");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let base = |out: &std::path::Path| -> Vec<String> {
        [
            "train",
            "lens1",
            "--decoder",
            "wiener",
            "--focus-iters",
            "40",
            "--pretrain-iters",
            "8",
            "--iters",
            "8",
            "--samples",
            "2",
            "--crop",
            "16",
            "--eval-trials",
            "2",
            "--validate-every",
            "4",
            "--checkpoint-every",
            "1",
            "--out",
            out.to_str().unwrap(),
        ]
        .map(String::from)
        .to_vec()
    };
    let whole = dir.join("whole");
    let args = base(&whole);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, out, err) = tolray(&args);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("tolerance-aware − stage1"), "{out}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(whole.join("report.json")).unwrap()).unwrap();
    let names: Vec<&str> = report["designs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["stage1", "tolerance-aware"]);
    assert_eq!(report["pairs"][0]["a"], "tolerance-aware");
    assert_eq!(report["pairs"][0]["b"], "stage1");
    for f in [
        "stage1/lens.json",
        "stage1/decoder.bin",
        "tolerance-aware/decoder.bin",
        "training.png",
        "report.html",
    ] {
        assert!(whole.join(f).exists(), "{f}");
    }
    // Stage 1's log, then stage 1's and stage 2's in the design's; validation every 4 and at
    // the end of each stage.
    let lines = |p: &str| -> Vec<serde_json::Value> {
        std::fs::read_to_string(whole.join(p))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    };
    assert_eq!(lines("stage1/log.jsonl").len(), 8);
    let log = lines("tolerance-aware/log.jsonl");
    assert_eq!(log.len(), 16);
    assert_eq!(log[15]["phase"], "tolerance");
    assert!(log[15]["psf_similarity"].as_f64().is_some());
    let validated = log
        .iter()
        .filter(|l| l.get("val_psnr_db").is_some())
        .count();
    assert_eq!(validated, 4, "{log:?}");

    let x = dir.join("x");
    let x = x.to_str().unwrap();
    // Interrupted anywhere (Ctrl-C as soon as training has begun), then resumed: the same files.
    let cut = dir.join("cut");
    let args = base(&cut);
    let mut child = Command::new(env!("CARGO_BIN_EXE_tolray"))
        .args(&args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !cut.join("checkpoint.json").exists() {
        assert!(child.try_wait().unwrap().is_none(), "the run ended early");
        assert!(start.elapsed() < Duration::from_secs(60), "no progress");
        std::thread::sleep(Duration::from_millis(2));
    }
    interrupt(&child);
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    if done.status.code() == Some(130) {
        assert!(err.contains("tolray train --resume"), "{err}");
        let (code, _, err) = tolray(&["train", "--resume", cut.to_str().unwrap(), "--out", x]);
        assert_eq!(code, 2, "another --out: {err}");
        let (code, _, err) = tolray(&["train", "--resume", cut.to_str().unwrap()]);
        assert_eq!(code, 0, "{err}");
    } else {
        // The stop came after the last iteration (a very fast machine): the run finished.
        assert_eq!(done.status.code(), Some(0), "{err}");
    }
    for f in [
        "stage1/lens.json",
        "stage1/decoder.bin",
        "tolerance-aware/lens.json",
        "tolerance-aware/decoder.bin",
        "tolerance-aware/log.jsonl",
        "report.json",
    ] {
        assert!(
            std::fs::read(whole.join(f)).unwrap() == std::fs::read(cut.join(f)).unwrap(),
            "{f} differs after the resume"
        );
    }

    // Stage 2 from the saved stage-1 design, training only the decoder (the paper's Table 3
    // row): its lens is the start's, and it is evaluated against it.
    let from = dir.join("from");
    let (code, out, err) = tolray(&[
        "train",
        whole.join("stage1").to_str().unwrap(),
        "--decoder",
        "wiener",
        "--stage",
        "tolerance",
        "--stage2-trains",
        "decoder",
        "--iters",
        "2",
        "--samples",
        "2",
        "--crop",
        "16",
        "--eval-trials",
        "2",
        "--out",
        from.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("decoder-only − stage1"), "{out}");
    assert_eq!(
        std::fs::read_to_string(from.join("decoder-only/lens.json")).unwrap(),
        std::fs::read_to_string(whole.join("stage1/lens.json")).unwrap()
    );
    assert_ne!(
        std::fs::read(from.join("decoder-only/decoder.bin")).unwrap(),
        std::fs::read(whole.join("stage1/decoder.bin")).unwrap()
    );
    // A design start keeps the sensor it was trained under (its sensor.json) for training and
    // evaluation unless told otherwise.
    let shot = dir.join("shot-start");
    std::fs::create_dir_all(&shot).unwrap();
    for f in ["lens.json", "decoder.bin"] {
        std::fs::copy(whole.join("stage1").join(f), shot.join(f)).unwrap();
    }
    let sensor = "{\n  \"sigma\": 0.02,\n  \"full_well_electrons\": 500.0\n}\n";
    std::fs::write(shot.join("sensor.json"), sensor).unwrap();
    let from_shot = dir.join("from-shot");
    let (code, _, err) = tolray(&[
        "train",
        shot.to_str().unwrap(),
        "--decoder",
        "wiener",
        "--stage",
        "tolerance",
        "--stage2-trains",
        "decoder",
        "--iters",
        "1",
        "--samples",
        "2",
        "--crop",
        "16",
        "--eval-trials",
        "1",
        "--out",
        from_shot.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        std::fs::read_to_string(from_shot.join("decoder-only/sensor.json")).unwrap(),
        sensor
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(from_shot.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(report["config"]["noise_sigma"], 0.02);
    assert_eq!(report["config"]["full_well_electrons"], 500.0);

    let stage1 = whole.join("stage1");
    let stage1 = stage1.to_str().unwrap();
    for (args, says) in [
        (vec!["train", "lens1", "--crop", "16", "--out", x], "--crop"),
        (
            vec![
                "train",
                "lens1",
                "--decoder",
                "wiener",
                "--tolerance-lr-scale",
                "0.2",
                "--out",
                x,
            ],
            "--tolerance-lr-scale",
        ),
        (
            vec![
                "train",
                "lens1",
                "--decoder",
                "wiener",
                "--stage",
                "tolerance",
                "--out",
                x,
            ],
            "design",
        ),
        (
            vec![
                "train",
                stage1,
                "--decoder",
                "unet",
                "--stage",
                "tolerance",
                "--out",
                x,
            ],
            "give --decoder wiener",
        ),
        (
            vec!["train", "lens1", "--decoder", "vgg", "--out", x],
            "vgg",
        ),
    ] {
        let (code, _, err) = tolray(&args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

/// `tolray render` simulates the capture the library simulates, bit for bit in its linear EXR:
/// the RGB PSF map's blur plus Gaussian noise, or with `--full-well-electrons` plus photon shot
/// noise ([`tolray::image::render::SensorNoise`]); bad noise flags are usage errors naming the
/// flag, and write nothing.
#[test]
fn render_simulates_the_library_s_capture_with_sensor_noise() {
    use tolray::image::render::{render, Blend, PsfMap, SensorNoise};
    let dir = tmp("render");
    std::fs::create_dir_all(&dir).unwrap();
    let input = dir.join("in.png");
    tolray::image::deadleaves::DeadLeaves::default()
        .generate(64, 48, 1, 2)
        .unwrap()
        .to_srgb()
        .save_png(&input)
        .unwrap();
    let lens = tolray::Lens::load("lens1").unwrap();
    let opts = tolray::deep::psf_options(&lens, 15, 256, 3);
    let psfs =
        tolray::deep::rgb_psf_map(&lens, &lens.compile(), 2, &lens.rgb_wavelengths_nm, &opts)
            .unwrap();
    let clean = render(
        &tolray::image::Image::load(&input).unwrap(),
        &PsfMap::new(2, 15, psfs).unwrap(),
        Blend::Tiles,
    )
    .unwrap();
    let read_exr = |p: &std::path::Path| -> Vec<f32> {
        let img = exr::prelude::read_first_rgba_layer_from_file(
            p,
            |res, _| vec![[0f32; 3]; res.width() * res.height()],
            |px: &mut Vec<[f32; 3]>, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * 64 + pos.x()] = [r, g, b];
            },
        )
        .unwrap();
        let px = img.layer_data.channel_data.pixels;
        (0..3).flat_map(|c| px.iter().map(move |p| p[c])).collect()
    };
    for (extra, noise) in [
        (vec!["--noise", "0"], SensorNoise::gaussian(0.0)),
        (vec!["--noise", "0.01"], SensorNoise::gaussian(0.01)),
        (
            vec!["--noise", "0.002", "--full-well-electrons", "500"],
            SensorNoise {
                sigma: 0.002,
                full_well_electrons: Some(500.0),
            },
        ),
    ] {
        let (out, exr) = (dir.join("out.png"), dir.join("out.exr"));
        let mut args = vec![
            "render",
            "lens1",
            "--image",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--exr",
            exr.to_str().unwrap(),
            "--grid",
            "2",
            "--ks",
            "15",
            "--spp",
            "256",
            "--seed",
            "3",
        ];
        args.extend(&extra);
        let (code, stdout, err) = tolray(&args);
        assert_eq!(code, 0, "{extra:?}: {err}");
        assert_eq!(
            stdout.contains("full well"),
            noise.full_well_electrons.is_some(),
            "{stdout}"
        );
        let mut want = clean.data.clone();
        noise.add(&mut want, 3, 0);
        assert_eq!(read_exr(&exr), want, "{extra:?}");
        assert_eq!(image_size(&out), (64, 48));
    }
    for (flag, value) in [
        ("--full-well-electrons", "0"),
        ("--full-well-electrons", "inf"),
        ("--noise", "-0.01"),
    ] {
        let out = dir.join("refused.png");
        let (code, _, err) = tolray(&[
            "render",
            "lens1",
            "--image",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            flag,
            value,
        ]);
        assert_eq!(code, 2, "{flag} {value}: {err}");
        assert!(err.contains(flag), "{flag} {value}: {err}");
        assert!(!out.exists(), "{flag} {value}: wrote {}", out.display());
    }
    // The output's folder is checked before any work (render's --out is a file: an existing one
    // is replaced, as the loop above does; it was refused as "not a directory" before).
    let missing = dir.join("no-such-dir").join("out.png");
    let (code, _, err) = tolray(&[
        "render",
        "lens1",
        "--image",
        input.to_str().unwrap(),
        "--out",
        missing.to_str().unwrap(),
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("--out") && err.contains("does not exist"),
        "{err}"
    );
}

/// `tolray evaluate` scores designs under the sensor they were trained under (their
/// `sensor.json`) unless told otherwise, warns when told otherwise, refuses designs trained under
/// different sensors without a flag, and keeps the paper's σ = 0.01 for designs without the file.
#[test]
fn evaluation_defaults_to_the_designs_training_sensor() {
    use tolray::decoder::DecoderKind;
    use tolray::deep::study::{save_design, save_sensor};
    use tolray::deep::{DeepConfig, DeepState, Phase};
    use tolray::image::render::SensorNoise;
    let dir = tmp("eval-sensor");
    std::fs::create_dir_all(&dir).unwrap();
    let lens = tolray::Lens::load("lens1").unwrap();
    let mut cfg = DeepConfig::for_lens(&lens);
    cfg.decoder = DecoderKind::Wiener;
    cfg.optics.psf_spp = 64;
    let st = DeepState::new(cfg, lens, None, Phase::Nominal, 1, 0).unwrap();
    let shot = SensorNoise {
        sigma: 0.02,
        full_well_electrons: Some(500.0),
    };
    for (name, sensor) in [
        ("a", Some(shot)),
        ("b", Some(shot)),
        ("c", Some(SensorNoise::gaussian(0.03))),
        ("old", None),
    ] {
        save_design(&st.design, &dir.join(name)).unwrap();
        if let Some(s) = sensor {
            save_sensor(&dir.join(name), &s).unwrap();
        }
    }
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let json = dir.join("r.json");
    let run = |designs: &[&str], extra: &[&str]| {
        let mut args = vec!["evaluate".to_string()];
        args.extend(designs.iter().map(|n| d(n)));
        for a in [
            "--trials",
            "2",
            "--eval-spp",
            "256",
            "--patch",
            "8",
            "--photos",
            "0",
            "--json",
        ] {
            args.push(a.to_string());
        }
        args.push(json.to_str().unwrap().to_string());
        args.extend(extra.iter().map(|s| s.to_string()));
        let refs: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        let (code, _, err) = tolray(&refs);
        let config = std::fs::read_to_string(&json)
            .ok()
            .map(|t| serde_json::from_str::<serde_json::Value>(&t).unwrap()["config"].clone());
        let _ = std::fs::remove_file(&json);
        (code, err, config)
    };
    let (code, err, config) = run(&["a", "b"], &[]);
    assert_eq!(code, 0, "{err}");
    let c = config.unwrap();
    assert_eq!(c["noise_sigma"], 0.02);
    assert_eq!(c["full_well_electrons"], 500.0);
    assert!(!err.contains("warning"), "{err}");
    let (code, err, config) = run(&["a", "old"], &["--noise", "0.01"]);
    assert_eq!(code, 0, "{err}");
    let c = config.unwrap();
    assert_eq!(c["noise_sigma"], 0.01);
    assert!(c.get("full_well_electrons").is_none(), "{c}");
    assert!(
        err.contains(
            "warning: design a was trained with noise σ 0.02 and a 500-electron full well"
        ),
        "{err}"
    );
    let (code, err, config) = run(&["a", "c"], &[]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("designs a and c") && err.contains("--noise"),
        "{err}"
    );
    assert!(config.is_none());
    let (code, err, config) = run(&["old"], &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(config.unwrap()["noise_sigma"], 0.01);
    std::fs::write(dir.join("old").join("sensor.json"), "{\"sigma\": -1}").unwrap();
    let (code, err, _) = run(&["old"], &[]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("sensor.json"), "{err}");
}

/// `tolray wavefront`, `mtf` and `psf --method fft|huygens`: the JSON keys the issue names, a
/// number an independent engine gives (optiland 0.6.3, `tests/data/wave/optiland_wave.json`:
/// the AC254-100-A achromat on axis), pictures, and bad input refused with its reason.
#[test]
fn wave_optics_commands() {
    let ac254 = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/zemax/real/dcclab_raytracing/AC254-100-A-Zemax(ZMX).zmx"
    );
    let png = tmp("opd.png");
    let zpng = tmp("zernike.svg");
    let (code, out, err) = tolray(&[
        "wavefront",
        ac254,
        "--fields",
        "0",
        "--json",
        "--png",
        png.to_str().unwrap(),
        "--zernike-png",
        zpng.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let r = &v[0];
    assert_eq!(r["field"], "0");
    assert!((r["wavelength_nm"].as_f64().unwrap() - 587.6).abs() < 1e-9);
    // optiland's OPD over its 12 x 36 quadrature: 0.0691251 waves RMS, Z4 0.0212518.
    let rms = r["rms_to_chief_waves"].as_f64().unwrap();
    assert!((rms - 0.0691251).abs() < 1e-6, "RMS {rms}");
    let z = r["zernike_standard_waves"].as_array().unwrap();
    assert_eq!(z.len(), 37);
    assert!((z[3].as_f64().unwrap() - 0.0212518).abs() < 1e-6);
    assert_eq!(r["zernike_fringe_waves"].as_array().unwrap().len(), 37);
    let sigma = r["rms_to_centroid_waves"].as_f64().unwrap();
    let strehl = r["strehl_marechal"].as_f64().unwrap();
    assert!((strehl - (-(std::f64::consts::TAU * sigma).powi(2)).exp()).abs() < 1e-12);
    assert!(r["pv_to_chief_waves"].as_f64().unwrap() >= rms);
    assert!(image_size(&png).0 > 0);
    assert!(std::fs::read_to_string(&zpng).unwrap().contains("Zernike"));

    let (code, out, err) = tolray(&[
        "mtf",
        "cooke-triplet",
        "--fields",
        "0,0.7",
        "--freq-lpmm",
        "10,20,40",
        "--method",
        "fft",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v.as_array().unwrap().len(), 2);
    for r in v.as_array().unwrap() {
        assert_eq!(r["freq_lpmm"], serde_json::json!([10.0, 20.0, 40.0]));
        for k in 0..3 {
            let (t, s, d) = (
                r["tangential"][k].as_f64().unwrap(),
                r["sagittal"][k].as_f64().unwrap(),
                r["diffraction_limit"][k].as_f64().unwrap(),
            );
            assert!((0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&s));
            assert!(
                t <= d + 1e-6 && s <= d + 1e-6,
                "below the diffraction limit"
            );
        }
    }
    // On axis tangential and sagittal are one.
    assert!(
        (v[0]["tangential"][1].as_f64().unwrap() - v[0]["sagittal"][1].as_f64().unwrap()).abs()
            < 1e-3
    );
    // Geometric MTF and through focus.
    let (code, out, err) = tolray(&[
        "mtf",
        "cooke-triplet",
        "--fields",
        "0",
        "--method",
        "geometric",
        "--freq-lpmm",
        "20",
        "--through-focus",
        "0.1,5",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v.as_array().unwrap().len(), 5);
    assert_eq!(v[2]["focus_shift_mm"], 0.0);

    for method in ["fft", "huygens"] {
        let (code, out, err) = tolray(&[
            "psf",
            "cooke-triplet",
            "--method",
            method,
            "--field",
            "0.5",
            "--ks",
            "32",
            "--json",
        ]);
        assert_eq!(code, 0, "{method}: {err}");
        let line = out.lines().last().unwrap();
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let s = v["strehl"].as_f64().unwrap();
        assert!(s > 0.0 && s <= 1.0, "{method} Strehl {s}");
    }

    // Bad input: a frequency above the cutoff, a field beyond reach, a grid that wraps.
    let (code, _, err) = tolray(&["mtf", "lens2", "--fields", "0", "--freq-lpmm", "5000"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("cutoff"), "{err}");
    let (code, _, err) = tolray(&["wavefront", "lens2", "--fields", "80deg"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("chief ray"), "{err}");
    let (code, _, err) = tolray(&["mtf", "lens2", "--pupil-samples", "64", "--grid", "100"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("twice"), "{err}");
    let (code, _, err) = tolray(&[
        "wavefront",
        "lens2",
        "--rings",
        "100000",
        "--spokes",
        "100000",
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn tolerance_criteria() {
    // The MTF criterion with its compensator: a yield of lenses reaching at least a value.
    let json = tmp("mtf-criterion.json");
    let png = tmp("mtf-criterion.png");
    let (code, out, err) = tolray(&[
        "tolerance",
        "cooke-triplet",
        "--trials",
        "8",
        "--fields",
        "0,0.7",
        "--criterion",
        "mtf@30:t",
        "--compensate",
        "focus",
        "--json",
        json.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("MTF at 30 cycles/mm, tangential") && out.contains("have at least"),
        "{out}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["options"]["criterion"]["kind"], "mtf");
    let c = &v["summary"]["criterion"]["mean_over_fields"];
    assert_eq!(c["yield_above"].as_array().unwrap().len(), 4);
    let t0 = &v["trials"][0];
    assert_eq!(t0["criterion"].as_array().unwrap().len(), 2);
    assert!(t0["mean_criterion"].as_f64().unwrap() > 0.0);
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);

    // Sensitivity by RMS wavefront error: rows sorted by the change of the criterion.
    let json = tmp("wavefront-sensitivity.json");
    let (code, out, err) = tolray(&[
        "sensitivity",
        "cooke-triplet",
        "--criterion",
        "rms-wavefront",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("RMS wavefront error (waves)"), "{out}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    let d: Vec<f64> = rows
        .iter()
        .map(|r| r["worst_delta_criterion"].as_f64().unwrap())
        .collect();
    assert!(d.windows(2).all(|w| w[0] >= w[1]));

    // Bad criteria: usage errors naming the flag, or the cutoff.
    for (c, says) in [
        ("sharpness", "--criterion"),
        ("mtf@30:q", "\"q\""),
        ("mtf@5000", "cutoff"),
    ] {
        let (code, _, err) = tolray(&[
            "tolerance",
            "cooke-triplet",
            "--trials",
            "2",
            "--criterion",
            c,
        ]);
        assert_eq!(code, 2, "{c}: {err}");
        assert!(err.contains(says), "{c}: {err}");
    }
}

#[test]
fn aberrations_command() {
    let prefix = tmp("aberr");
    let (code, out, err) = tolray(&[
        "aberrations",
        "cooke-triplet",
        "--points",
        "5",
        "--fields",
        "0,1",
        "--wavelengths",
        "F,d,C",
        "--json",
        "--png",
        prefix.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["field_fraction"].as_array().unwrap().len(), 5);
    assert_eq!(v["field_curvature"].as_array().unwrap().len(), 3);
    assert_eq!(
        v["field_curvature"][0]["tangential_mm"]
            .as_array()
            .unwrap()
            .len(),
        5
    );
    assert_eq!(v["relative_illumination"][0].as_f64().unwrap(), 1.0);
    assert_eq!(v["distortion_f_tan_percent"][0].as_f64().unwrap(), 0.0);
    assert!(
        v["distortion_f_theta_percent"].is_null(),
        "a finite object has no f-θ"
    );
    // Lateral colour of the primary (d) is zero by definition.
    assert!(v["lateral_colour"][1]["um"]
        .as_array()
        .unwrap()
        .iter()
        .all(|x| x.as_f64().unwrap().abs() < 1e-9));
    assert_eq!(v["fans"].as_array().unwrap().len(), 6);
    for name in [
        "field-curvature",
        "distortion",
        "lateral-colour",
        "relative-illumination",
        "ray-fan",
        "opd-fan",
    ] {
        let p = format!("{}-{name}.png", prefix.display());
        assert!(std::fs::metadata(&p).unwrap().len() > 10_000, "{p}");
    }
    let (code, out, err) = tolray(&["aberrations", "cooke-triplet", "--points", "3"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("rel. ill.") && out.contains("Ray fans"),
        "{out}"
    );
    for bad in [["--points", "1"], ["--fan-points", "2"]] {
        let (code, _, err) = tolray(&["aberrations", "cooke-triplet", bad[0], bad[1]]);
        assert_eq!(code, 2, "{err}");
        assert!(err.contains(bad[0]), "{err}");
    }
}

#[test]
fn polychromatic_and_direct_mtf() {
    let (code, out, err) = tolray(&[
        "mtf",
        "cooke-triplet",
        "--fields",
        "0.7",
        "--wavelengths",
        "F,d,C",
        "--freq-lpmm",
        "10,30",
        "--method",
        "direct",
        "--polychromatic",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let rows = v.as_array().unwrap();
    assert_eq!(rows.len(), 4);
    let poly = &rows[3];
    assert_eq!(poly["polychromatic"], true);
    assert!(poly["wavelength_nm"].is_null());
    for k in 0..2 {
        for dir in ["tangential", "sagittal"] {
            // |Σ w OTF_λ e^{iφ}| ≤ Σ w |OTF_λ|: lateral colour only lowers it.
            let mean: f64 = rows[..3]
                .iter()
                .map(|r| r[dir][k].as_f64().unwrap())
                .sum::<f64>()
                / 3.0;
            let p = poly[dir][k].as_f64().unwrap();
            assert!(p > 0.0 && p <= mean + 1e-12, "{dir} {k}: {p} vs {mean}");
        }
    }
    // The table names the polychromatic row.
    let (code, out, err) = tolray(&[
        "mtf",
        "cooke-triplet",
        "--fields",
        "0.7",
        "--wavelengths",
        "F,d,C",
        "--polychromatic",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("poly"), "{out}");
}
