//! Wave optics, tolerance criteria, aberrations, and the generated command-line reference.

use super::*;

/// `tolray wavefront`, `mtf` and `psf --method fft|huygens`: the JSON keys the issue names, a
/// number an independent engine gives (optiland 0.6.3, `tests/data/wave/optiland_wave.json`:
/// the AC254-100-A achromat on axis), pictures, and bad input refused with its reason.
#[test]
fn wave_optics_commands() {
    let ac254 = concat!(
        env!("TOLRAY_ROOT"),
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
    let g = &v["grid_distortion"];
    assert_eq!(g["real_mm"].as_array().unwrap().len(), 121, "{g}");
    assert_eq!(g["distortion_pct"][60].as_f64().unwrap(), 0.0, "the centre");
    for name in [
        "field-curvature",
        "distortion",
        "grid-distortion",
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
    assert!(out.contains("Grid distortion (11 x 11"), "{out}");
    for bad in [
        ["--points", "1"],
        ["--fan-points", "2"],
        ["--grid-points", "1"],
    ] {
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

/// docs/cli.md is the parser's own reference (`tolray --markdown-help`); it fails when a flag,
/// default or help text changes without it (`TOLRAY_BLESS=1 cargo test --release --test cli
/// reference` rewrites it), as tests/capi/ does for the C header.
#[test]
fn cli_reference_is_generated_from_the_parser() {
    let (code, out, err) = tolray(&["--markdown-help"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("# Command-line reference"), "{out}");
    for cmd in [
        "info",
        "spot",
        "tolerance",
        "mtf",
        "wavefront",
        "deep",
        "render",
    ] {
        assert!(out.contains(&format!("## `tolray {cmd}`")), "{cmd} missing");
    }
    let path = concat!(env!("TOLRAY_ROOT"), "/docs/cli.md");
    if std::env::var_os("TOLRAY_BLESS").is_some() {
        std::fs::write(path, &out).unwrap();
    }
    let stored = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        stored == out,
        "docs/cli.md differs from the parser; regenerate it with \
         TOLRAY_BLESS=1 cargo test --release --test cli reference"
    );
}

/// `tolray train --loss rms-wavefront` (issue 40): stage 1 lowers lens2's RMS wavefront error
/// (its sensor sits 20 waves of defocus from the best focus), every iteration logs the
/// wavefront, stage 2 runs with it, the checkpoint keeps the loss so that a resume trains the
/// same objective, and the image stage refuses it.
#[test]
fn train_on_the_rms_wavefront() {
    let dir = tmp("train-wavefront");
    let out = dir.join("run");
    let (code, _, err) = tolray(&[
        "train",
        "lens2",
        "--loss",
        "rms-wavefront",
        "--pretrain-iters",
        "12",
        "--iters",
        "2",
        "--samples",
        "2",
        "--psf-spp",
        "64",
        "--eval-trials",
        "4",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let log: Vec<serde_json::Value> = std::fs::read_to_string(out.join("log.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(log.len(), 14);
    let w: Vec<f64> = log
        .iter()
        .map(|l| l["wavefront_waves"].as_f64().unwrap())
        .collect();
    assert!(w.iter().all(|v| v.is_finite() && *v > 0.0), "{w:?}");
    assert!(
        w[11] < 0.7 * w[0],
        "stage 1 lowers the wavefront error: {w:?}"
    );
    let ck: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("checkpoint.json")).unwrap())
            .unwrap();
    let per_wave = ck["config"]["loss"]["rms-wavefront"]["mm_per_wave"]
        .as_f64()
        .unwrap();
    assert!(per_wave > 0.0 && per_wave < 0.1, "{per_wave}");
    let (code, _, err) = tolray(&[
        "train",
        "lens2",
        "--loss",
        "rms-wavefront",
        "--decoder",
        "wiener",
        "--out",
        dir.join("x").to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--loss rms-wavefront"), "{err}");
    let (code, _, err) = tolray(&["train", "lens2", "--loss", "strehl", "--out", "x"]);
    assert_eq!(code, 2);
    assert!(err.contains("strehl"), "{err}");
}

/// `tolray train --loss mtf@30` (issue 40): fine-tuning a spot-trained lens1 in stage 2 (the
/// tenth-size learning rates; the full stage-1 rates throw a design out of the MTF's narrow
/// basin) raises the logged diffraction MTF at 30 cycles/mm over the tolerance patterns, the
/// checkpoint keeps the loss and a resume reads it back; bad specifications, a frequency above
/// the cutoff and the image stage are refused.
#[test]
fn train_on_the_mtf() {
    let dir = tmp("train-mtf");
    let spot = dir.join("spot");
    let (code, _, err) = tolray(&[
        "train",
        "lens1",
        "--stage",
        "pretrain",
        "--pretrain-iters",
        "40",
        "--iters",
        "0",
        "--out",
        spot.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let out = dir.join("mtf");
    let start = spot.join("lens-final.json");
    let (code, _, err) = tolray(&[
        "train",
        start.to_str().unwrap(),
        "--loss",
        "mtf@30",
        "--stage",
        "tolerance",
        "--iters",
        "6",
        "--samples",
        "4",
        "--psf-spp",
        "64",
        "--eval-trials",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let mtf = |dir: &std::path::Path| -> Vec<f64> {
        std::fs::read_to_string(dir.join("log.jsonl"))
            .unwrap()
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["mtf"]
                    .as_f64()
                    .unwrap()
            })
            .collect()
    };
    let m = mtf(&out);
    assert_eq!(m.len(), 6);
    assert!(m.iter().all(|v| (0.0..=1.0).contains(v)), "{m:?}");
    // Measured 2026-11-29: 0.069 -> 0.214 by the fifth iteration.
    assert!(
        m[3..].iter().all(|v| *v > 2.0 * m[0]),
        "stage 2 raises the MTF at 30 cycles/mm: {m:?}"
    );
    let ck: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("checkpoint.json")).unwrap())
            .unwrap();
    let loss = &ck["config"]["loss"]["mtf"];
    assert_eq!(loss["freq_lpmm"], 30.0);
    assert_eq!(loss["direction"], "mean");
    assert!((loss["mm_per_unit"].as_f64().unwrap() - 1.0 / 60.0).abs() < 1e-15);
    // A resume reads the loss back from the checkpoint (the run is finished: nothing to add).
    let (code, _, err) = tolray(&["train", "--resume", out.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(mtf(&out).len(), 6);
    let x = dir.join("x");
    for (bad, why) in [
        ("mtf@0", "positive number of cycles/mm"),
        ("mtf@30:q", "mtf@FREQ[:t|s|mean]"),
        ("mtf", "give spot, rms-wavefront or mtf@"),
    ] {
        let (code, _, err) = tolray(&[
            "train",
            "lens1",
            "--loss",
            bad,
            "--out",
            x.to_str().unwrap(),
        ]);
        assert_eq!(code, 2, "{bad}: {err}");
        assert!(err.contains(why), "{bad}: {err}");
    }
    let (code, _, err) = tolray(&[
        "train",
        "lens1",
        "--loss",
        "mtf@5000",
        "--out",
        x.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("cutoff"), "{err}");
    let (code, _, err) = tolray(&[
        "train",
        "lens1",
        "--loss",
        "mtf@30",
        "--decoder",
        "wiener",
        "--out",
        dir.join("x").to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--loss mtf@30"), "{err}");
}

/// `tolray psf --method huygens --polychromatic`: the polychromatic PSF in the JSON and the
/// picture, on axis the mean of the wavelengths' PSFs on one pitch; refused with the FFT.
#[test]
fn polychromatic_huygens_psf_command() {
    let png = tmp("poly-psf.png");
    let (code, out, err) = tolray(&[
        "psf",
        "cooke-triplet",
        "--method",
        "huygens",
        "--wavelengths",
        "F,d,C",
        "--polychromatic",
        "--ks",
        "17",
        "--pitch-um",
        "1",
        "--pupil-samples",
        "32",
        "--grid",
        "128",
        "--json",
        "--png",
        png.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("polychromatic huygens PSF"), "{out}");
    let v: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    let poly = &v["polychromatic"];
    let p: Vec<f64> = serde_json::from_value(poly["psf"].clone()).unwrap();
    let mono: Vec<Vec<f64>> = serde_json::from_value(v["psf"].clone()).unwrap();
    assert_eq!(p.len(), 17 * 17);
    for k in 0..p.len() {
        let mean = (mono[0][k] + mono[1][k] + mono[2][k]) / 3.0;
        assert!((p[k] - mean).abs() < 1e-12, "pixel {k}: {} vs {mean}", p[k]);
    }
    let s = poly["strehl"].as_f64().unwrap();
    assert!(s > 0.0 && s < 1.0, "{s}");
    assert!(png.exists());
    let (code, _, err) = tolray(&["psf", "lens2", "--method", "fft", "--polychromatic"]);
    assert_eq!(code, 2);
    assert!(
        err.contains("--polychromatic needs --method huygens"),
        "{err}"
    );
}
