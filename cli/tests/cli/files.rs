//! Conversions, output paths checked first, Ctrl-C, non-finite results refused, glass lookup.

use super::*;

#[test]
fn convert_between_zmx_and_json() {
    let fixture = |n: &str| format!("{}/tests/data/zemax/{n}", env!("TOLRAY_ROOT"));
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
        env!("TOLRAY_ROOT")
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
        env!("TOLRAY_ROOT")
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
pub(super) fn interrupt(child: &std::process::Child) {
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
