//! The image stage: training with a decoder, rendering, evaluation under the training sensor.

use super::*;

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
    assert!(
        c.get("psf").is_none(),
        "the geometric default is not written: {c}"
    );
    // Diffraction PSFs (issue 40): the same units imaged through the wavefront's PSFs.
    let (code, err, config) = run(&["a"], &["--psf", "diffraction"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(config.unwrap()["psf"], "diffraction");
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
