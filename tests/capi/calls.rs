//! The analysis, rendering, training and wave-optics calls against the library, and their errors.

use super::*;

/// `tolray_psf_options_default` never hands out options `tolray_psf` refuses: a lens whose
/// sensor pitch (70.7 mm: 2 x 2 pixels on a 100 mm half-diagonal) is outside 1e-5 to 10 mm gets
/// `TOLRAY_ERROR_ARGUMENT` naming the pitch, and `out` is left as it was.
#[test]
fn psf_defaults_are_options_tolray_psf_takes() {
    use std::ptr::null_mut;
    use tolray::ffi::*;
    let mut v: serde_json::Value =
        serde_json::from_str(include_str!("../../src/lens/builtin/lens1.json")).unwrap();
    v["r_sensor"] = serde_json::json!(100.0);
    v["sensor_res"] = serde_json::json!([2, 2]);
    let text = std::ffi::CString::new(v.to_string()).unwrap();
    let mut lens = null_mut();
    let sys;
    let mut opts = std::mem::MaybeUninit::<tolray_psf_options>::zeroed();
    // SAFETY: valid pointers; handles freed below.
    unsafe {
        assert_eq!(
            tolray_lens_from_json(text.as_ptr(), &mut lens),
            tolray_status::TOLRAY_OK
        );
        sys = nominal_system(lens);
        assert_eq!(
            tolray_psf_options_default(sys, opts.as_mut_ptr()),
            tolray_status::TOLRAY_ERROR_ARGUMENT
        );
        let msg = last_error();
        assert!(
            msg.contains("sensor pitch") && msg.contains("70.7"),
            "{msg}"
        );
        assert_eq!(opts.assume_init().kernel_px, 0);
        tolray_system_free(sys);
        tolray_lens_free(lens);
    }
}

/// `tolray_render` gives the library's capture (same PSF map, same noise), and refuses a short
/// output buffer, a NULL input and a bad grid with a status.
#[test]
fn render_through_the_c_abi_matches_the_library() {
    use std::ptr::null_mut;
    use tolray::ffi::*;
    let name = std::ffi::CString::new("lens2").unwrap();
    let mut lens = null_mut();
    let sys;
    let mut opts = std::mem::MaybeUninit::<tolray_psf_options>::uninit();
    // SAFETY: valid pointers; handles freed below.
    unsafe {
        assert_eq!(
            tolray_lens_load(name.as_ptr(), &mut lens),
            tolray_status::TOLRAY_OK
        );
        sys = nominal_system(lens);
        assert_eq!(
            tolray_psf_options_default(sys, opts.as_mut_ptr()),
            tolray_status::TOLRAY_OK
        );
    }
    // SAFETY: written by the call above.
    let mut opts = unsafe { opts.assume_init() };
    opts.kernel_px = 31;
    opts.pupil.n = 512;
    let (w, h) = (64u32, 48u32);
    let img = tolray::image::deadleaves::DeadLeaves::default()
        .generate(64, 48, 1, 2)
        .unwrap();
    let mut out = vec![0f32; img.data.len()];
    // SAFETY: buffers of the stated sizes.
    let st = unsafe {
        tolray_render(
            sys,
            &opts,
            4,
            0.01,
            5,
            w,
            h,
            img.data.as_ptr(),
            out.as_mut_ptr(),
            out.len(),
        )
    };
    assert_eq!(st, tolray_status::TOLRAY_OK);
    let l = tolray::Lens::load("lens2").unwrap();
    let mut o = tolray::deep::psf_options(&l, 31, 512, 0);
    o.pupil = tolray::trace::Pupil {
        pattern: tolray::trace::PupilPattern::Random {
            n: 512,
            seed: opts.pupil.seed,
        },
        scale: 1.0,
        aim: false,
    };
    let map = tolray::deep::rgb_psf_map(&l, &l.compile(), 4, &l.rgb_wavelengths_nm, &o).unwrap();
    let mut y = tolray::image::render::render_map(
        &img,
        &tolray::image::render::PsfMap::new(4, 31, map).unwrap(),
    )
    .unwrap();
    tolray::image::render::add_gaussian_noise(&mut y.data, 0.01, 5, 0);
    assert_eq!(out, y.data);
    // SAFETY: as above; the error cases write nothing.
    unsafe {
        let short = out.len() - 1;
        let p = out.as_mut_ptr();
        let x = img.data.as_ptr();
        let n = out.len();
        let render = |grid: u32, sigma: f64, input: *const f32, len: usize| {
            tolray_render(sys, &opts, grid, sigma, 5, w, h, input, p, len)
        };
        use tolray_status::*;
        assert_eq!(render(4, 0.01, x, short), TOLRAY_ERROR_BUFFER_SIZE);
        assert_eq!(
            render(4, 0.01, std::ptr::null(), n),
            TOLRAY_ERROR_NULL_ARGUMENT
        );
        // A grid out of 1..=64 or larger than the image is a bad argument, not a buffer size.
        assert_eq!(render(0, 0.01, x, n), TOLRAY_ERROR_ARGUMENT);
        assert_eq!(render(49, 0.01, x, n), TOLRAY_ERROR_ARGUMENT);
        assert_eq!(render(4, f64::NAN, x, n), TOLRAY_ERROR_ARGUMENT);
        assert_eq!(render(4, -0.1, x, n), TOLRAY_ERROR_ARGUMENT);
        // The noise-free capture plus tolray_add_sensor_noise without a full well is exactly
        // tolray_render's noisy capture; a full well adds the shot noise the library adds.
        let mut clean = vec![0f32; n];
        assert_eq!(render(4, 0.0, x, n), TOLRAY_OK);
        clean.copy_from_slice(&out);
        let mut noisy = clean.clone();
        assert_eq!(
            tolray_add_sensor_noise(noisy.as_mut_ptr(), n, 0.01, 0.0, 5),
            TOLRAY_OK
        );
        assert_eq!(render(4, 0.01, x, n), TOLRAY_OK);
        assert_eq!(noisy, out);
        let mut shot = clean.clone();
        assert_eq!(
            tolray_add_sensor_noise(shot.as_mut_ptr(), n, 0.002, 5000.0, 9),
            TOLRAY_OK
        );
        let mut want = clean.clone();
        tolray::image::render::SensorNoise {
            sigma: 0.002,
            full_well_electrons: Some(5000.0),
        }
        .add(&mut want, 9, 0);
        assert_eq!(shot, want);
        assert_ne!(shot, clean);
        let q = shot.as_mut_ptr();
        assert_eq!(
            tolray_add_sensor_noise(q, n, -0.01, 0.0, 1),
            TOLRAY_ERROR_ARGUMENT
        );
        assert_eq!(
            tolray_add_sensor_noise(q, n, 0.01, 0.5, 1),
            TOLRAY_ERROR_ARGUMENT
        );
        assert_eq!(
            tolray_add_sensor_noise(q, n, 0.01, f64::NAN, 1),
            TOLRAY_ERROR_ARGUMENT
        );
        assert_eq!(
            tolray_add_sensor_noise(std::ptr::null_mut(), n, 0.01, 0.0, 1),
            TOLRAY_ERROR_NULL_ARGUMENT
        );
        assert_eq!(
            tolray_add_sensor_noise(std::ptr::null_mut(), 0, 0.01, 0.0, 1),
            TOLRAY_OK
        );
        assert_eq!(shot, want, "a refused call writes nothing");
        tolray_system_free(sys);
        tolray_lens_free(lens);
    }
}

/// A spot pupil of more rays than `MAX_PUPIL_RAYS` is refused with a status before anything is
/// allocated (a 3000 x 3000 grid was accepted and traced; a larger one could abort the host).
#[test]
fn oversized_spot_pupils_are_refused_with_a_status() {
    use std::ptr::null_mut;
    use tolray::ffi::*;
    let name = std::ffi::CString::new("lens2").unwrap();
    let mut lens = null_mut();
    let sys;
    // SAFETY: valid pointers; handles freed below.
    unsafe {
        assert_eq!(
            tolray_lens_load(name.as_ptr(), &mut lens),
            tolray_status::TOLRAY_OK
        );
        sys = nominal_system(lens);
    }
    let field = tolray_field {
        kind: TOLRAY_FIELD_FRACTION,
        x: 0.0,
        y: 0.7,
    };
    let wl = [587.5618];
    let mut stats = std::mem::MaybeUninit::<tolray_spot_stats>::uninit();
    for (n, want) in [
        (2048u32, tolray_status::TOLRAY_OK),
        (3000, tolray_status::TOLRAY_ERROR_ARGUMENT),
        (100_000_000, tolray_status::TOLRAY_ERROR_ARGUMENT),
    ] {
        let pupil = tolray_pupil {
            pattern: TOLRAY_PUPIL_GRID,
            n,
            seed: 0,
            scale: 1.0,
            aim: 0,
        };
        // SAFETY: valid handle, field, wavelength and pupil; `stats` is writable.
        let st = unsafe { tolray_spot(sys, &field, wl.as_ptr(), 1, &pupil, 1, stats.as_mut_ptr()) };
        assert_eq!(st, want, "grid {n}");
        if n == 3000 {
            let msg = last_error();
            assert!(msg.contains("at most 4194304"), "{msg}");
        }
    }
    // SAFETY: handles from the calls above.
    unsafe {
        tolray_system_free(sys);
        tolray_lens_free(lens);
    }
}

/// `tolray_train` and `tolray_train_resume`: the training runner through the C ABI. A run that
/// the progress callback stops (as a Ctrl-C handler would) and that is resumed writes exactly
/// the files of an uninterrupted run; the settings JSON overrides the defaults and refuses
/// unknown keys; bad arguments are statuses with messages.
#[test]
fn training_runs_stops_and_resumes_through_the_c_abi() {
    use std::ffi::{c_void, CString};
    use tolray::ffi::tolray_status::*;
    use tolray::ffi::{tolray_lens_free, tolray_lens_load, tolray_train, tolray_train_resume};
    struct Calls {
        seen: Vec<(usize, usize, f64, f64)>,
        stop_at: usize,
    }
    unsafe extern "C" fn progress(
        user: *mut c_void,
        iter: usize,
        total: usize,
        loss: f64,
        spot: f64,
    ) -> i32 {
        // SAFETY: `user` is the `Calls` this test passes.
        let c = unsafe { &mut *user.cast::<Calls>() };
        c.seen.push((iter, total, loss, spot));
        i32::from(iter + 1 == c.stop_at)
    }
    let dir = std::env::temp_dir().join(format!("tolray-capi-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let c = |s: &str| CString::new(s).unwrap();
    let cfg = c(r#"{"pretrain_iters": 4, "tolerance_iters": 3, "samples": 4, "seed": 5}"#);
    let mut lens = std::ptr::null_mut();
    // SAFETY: valid C strings and out-pointers throughout; handles are freed at the end.
    unsafe {
        assert_eq!(tolray_lens_load(c"lens1".as_ptr(), &mut lens), TOLRAY_OK);
        let whole = c(dir.join("whole").to_str().unwrap());
        let mut calls = Calls {
            seen: Vec::new(),
            stop_at: usize::MAX,
        };
        let mut stopped = 9u32;
        let user = (&mut calls as *mut Calls).cast::<c_void>();
        let st = tolray_train(
            lens,
            cfg.as_ptr(),
            whole.as_ptr(),
            2,
            4,
            Some(progress),
            user,
            &mut stopped,
        );
        assert_eq!(st, TOLRAY_OK, "{}", last_error());
        assert_eq!(stopped, 0);
        let iters: Vec<usize> = calls.seen.iter().map(|s| s.0).collect();
        assert_eq!(iters, (0..7).collect::<Vec<_>>());
        assert!(calls
            .seen
            .iter()
            .all(|s| s.1 == 7 && s.2.is_finite() && s.3 > 0.0));

        // Stopped by the callback after iteration 2 (in stage 1), resumed, stopped again in
        // stage 2 and resumed again: the same files.
        let cut = c(dir.join("cut").to_str().unwrap());
        let mut calls = Calls {
            seen: Vec::new(),
            stop_at: 3,
        };
        let user = (&mut calls as *mut Calls).cast::<c_void>();
        let st = tolray_train(
            lens,
            cfg.as_ptr(),
            cut.as_ptr(),
            2,
            4,
            Some(progress),
            user,
            &mut stopped,
        );
        assert_eq!((st, stopped), (TOLRAY_OK, 1), "{}", last_error());
        assert!(!dir.join("cut/report.json").exists());
        calls.stop_at = 6;
        let st = tolray_train_resume(cut.as_ptr(), 2, 4, Some(progress), user, &mut stopped);
        assert_eq!((st, stopped), (TOLRAY_OK, 1), "{}", last_error());
        let st = tolray_train_resume(cut.as_ptr(), 2, 4, None, std::ptr::null_mut(), &mut stopped);
        assert_eq!((st, stopped), (TOLRAY_OK, 0), "{}", last_error());
        let iters: Vec<usize> = calls.seen.iter().map(|s| s.0).collect();
        assert_eq!(iters, [0, 1, 2, 3, 4, 5]);
        for f in [
            "lens-final.json",
            "log.jsonl",
            "report.json",
            "report.txt",
            "lens-initial.json",
        ] {
            assert!(
                std::fs::read(dir.join("whole").join(f)).unwrap()
                    == std::fs::read(dir.join("cut").join(f)).unwrap(),
                "{f} differs after the resumes"
            );
        }
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("whole/report.json")).unwrap())
                .unwrap();
        assert_eq!(report["config"]["samples"], 4);
        assert_eq!(report["config"]["seed"], 5);
        assert_eq!(report["designs"].as_array().unwrap().len(), 3);
        assert!(dir.join("whole/training.png").exists());

        // Errors: statuses with messages, nothing written where nothing could start.
        let x = c(dir.join("x").to_str().unwrap());
        let bad = [
            (
                c(r#"{"pretrain_itrs": 4}"#),
                TOLRAY_ERROR_ARGUMENT,
                "unknown key \"pretrain_itrs\"",
            ),
            (c("{"), TOLRAY_ERROR_PARSE, "config_json"),
            (c("[1]"), TOLRAY_ERROR_PARSE, "not a JSON object"),
            (
                c(r#"{"samples": "many"}"#),
                TOLRAY_ERROR_INVALID_INPUT,
                "samples",
            ),
        ];
        for (json, status, says) in bad {
            let st = tolray_train(
                lens,
                json.as_ptr(),
                x.as_ptr(),
                1,
                4,
                None,
                std::ptr::null_mut(),
                &mut stopped,
            );
            assert_eq!(st, status, "{json:?}");
            assert!(last_error().contains(says), "{json:?}: {}", last_error());
        }
        let st = tolray_train(
            lens,
            cfg.as_ptr(),
            x.as_ptr(),
            1,
            0,
            None,
            std::ptr::null_mut(),
            &mut stopped,
        );
        assert_eq!(st, TOLRAY_ERROR_ARGUMENT);
        assert!(last_error().contains("eval_trials 0"), "{}", last_error());
        let st = tolray_train(
            lens,
            cfg.as_ptr(),
            x.as_ptr(),
            1,
            4,
            None,
            std::ptr::null_mut(),
            std::ptr::null_mut(),
        );
        assert_eq!(st, TOLRAY_ERROR_NULL_ARGUMENT);
        assert!(
            !dir.join("x").exists(),
            "nothing written before the arguments are checked"
        );
        let st = tolray_train_resume(x.as_ptr(), 1, 4, None, std::ptr::null_mut(), &mut stopped);
        assert_eq!(st, TOLRAY_ERROR_IO);
        assert!(last_error().contains("checkpoint.json"), "{}", last_error());
        tolray_lens_free(lens);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// This thread's last C ABI error message.
pub(super) fn last_error() -> String {
    let mut buf = [0 as std::ffi::c_char; 4096];
    // SAFETY: `buf` holds 4096 bytes.
    unsafe { tolray::ffi::tolray_last_error(buf.as_mut_ptr(), buf.len()) };
    // SAFETY: NUL-terminated by tolray_last_error.
    unsafe { std::ffi::CStr::from_ptr(buf.as_ptr()) }
        .to_string_lossy()
        .into_owned()
}

/// `tolray_lens_paraxial` at the d line of a lens made by `tolray_lens_from_json` (for `Json`)
/// or `tolray_lens_load` (for `Name`), both calls asserted to succeed, the handle freed.
fn paraxial_through_c(lens: LensText) -> tolray::ffi::tolray_paraxial {
    use tolray::ffi::*;
    type Make =
        unsafe extern "C" fn(*const std::ffi::c_char, *mut *mut tolray_lens) -> tolray_status;
    let (text, load): (&str, Make) = match lens {
        LensText::Json(t) => (t, tolray_lens_from_json),
        LensText::Name(n) => (n, tolray_lens_load),
    };
    let text = std::ffi::CString::new(text).unwrap();
    let mut handle = std::ptr::null_mut();
    let mut p = tolray_paraxial::default();
    // SAFETY: valid pointers; the handle is freed below.
    unsafe {
        assert_eq!(load(text.as_ptr(), &mut handle), tolray_status::TOLRAY_OK);
        assert_eq!(
            tolray_lens_paraxial(handle, 587.5618, &mut p),
            tolray_status::TOLRAY_OK
        );
        tolray_lens_free(handle);
    }
    p
}

/// A lens for [`paraxial_through_c`]: DeepLens JSON text or a built-in or file name.
enum LensText<'a> {
    Json(&'a str),
    Name(&'a str),
}

/// An afocal lens is an answer of `tolray_lens_paraxial`, not an error: `afocal` = 1, the
/// angular magnification set (a 2x Keplerian reducer of two ideal thin lenses: -2), the focal
/// numbers 0 as documented, and the image of an object at infinity at infinity.
#[test]
fn an_afocal_lens_has_paraxial_data_through_the_c_abi() {
    let p = paraxial_through_c(LensText::Json(
        r#"{"surfaces": [
            {"type": "ThinLens", "f": 100, "r": 10, "mat2": "air", "d_next": 150, "is_aperture": true},
            {"type": "ThinLens", "f": 50, "r": 10, "mat2": "air", "d_next": 30}], "r_sensor": 5}"#,
    ));
    assert_eq!((p.afocal, p.image_at_infinity), (1, 1));
    assert!((p.angular_magnification + 2.0).abs() < 1e-12, "{p:?}");
    assert_eq!(
        (
            p.efl_mm,
            p.efl_image_space_mm,
            p.bfd_mm,
            p.fnum,
            p.power_per_mm
        ),
        (0.0, 0.0, 0.0, 0.0, 0.0)
    );
    assert!((p.entrance_pupil_diameter_mm - 20.0).abs() < 1e-12, "{p:?}");
}

/// Issue 41: the C ABI gives OpticStudio's two focal lengths as `tolray info` does: a concave
/// mirror of radius -400 mm has 1/Φ = 200 mm "in air" and n'/Φ = -200 mm "in image space"
/// (closed form); lens1 images in air, so the two are equal.
#[test]
fn the_c_abi_gives_the_focal_length_in_image_space() {
    let pa = paraxial_through_c(LensText::Json(
        r#"{"primary_wvln": 0.5875618, "r_sensor": 1, "sensor_res": [512, 512],
        "surfaces": [{"type": "Mirror", "r": 20, "c": -0.0025, "d_next": -200, "mat2": "air",
        "is_aperture": true}]}"#,
    ));
    let pb = paraxial_through_c(LensText::Name("lens1"));
    assert!((pa.efl_mm - 200.0).abs() < 1e-9, "{pa:?}");
    assert!((pa.efl_image_space_mm + 200.0).abs() < 1e-9, "{pa:?}");
    let rust = tolray::Lens::load("lens1")
        .unwrap()
        .paraxial(587.5618)
        .unwrap();
    assert_eq!(pb.efl_image_space_mm, rust.efl_image_space_mm.unwrap());
    assert_eq!(pb.efl_image_space_mm, pb.efl_mm);
}

/// The wave-optics calls give the Rust API's numbers, and refuse bad sizes, NULLs and
/// frequencies beyond the cutoff with statuses (never an abort: a pupil grid of 10^5 samples
/// is refused before anything is allocated).
#[test]
fn wave_optics_through_the_c_abi() {
    use std::ptr::{null, null_mut};
    use tolray::ffi::tolray_status::*;
    use tolray::ffi::*;
    use tolray::wave::{self, mtf, psf, Sampling, WaveOptions};
    let name = std::ffi::CString::new("cooke-triplet").unwrap();
    let mut lens = null_mut();
    let sys;
    // SAFETY: valid pointers; handles freed below.
    unsafe {
        assert_eq!(tolray_lens_load(name.as_ptr(), &mut lens), TOLRAY_OK);
        sys = nominal_system(lens);
    }
    let l = tolray::Lens::load("cooke-triplet").unwrap();
    let s = l.compile();
    let field = tolray_field {
        kind: TOLRAY_FIELD_FRACTION,
        x: 0.0,
        y: 0.7,
    };
    let f = tolray::trace::Field::fraction(0.7);
    let wl = 587.5618;

    // Wavefront statistics and Zernike coefficients.
    let mut o = std::mem::MaybeUninit::<tolray_wave_options>::uninit();
    // SAFETY: `o` is writable.
    assert_eq!(
        unsafe { tolray_wave_options_default(o.as_mut_ptr()) },
        TOLRAY_OK
    );
    // SAFETY: initialised by the call above.
    let o = unsafe { o.assume_init() };
    let mut st = tolray_wavefront_stats::default();
    let mut z = vec![0.0; 37];
    // SAFETY: valid handle and pointers; `z` holds 37 doubles.
    let r = unsafe { tolray_wavefront(sys, &field, wl, &o, &mut st, z.as_mut_ptr(), z.len()) };
    assert_eq!(r, TOLRAY_OK, "{}", last_error());
    let w = wave::wavefront(&l, &s, f, wl, &WaveOptions::default()).unwrap();
    let want = w.stats(37).unwrap();
    assert_eq!(st.rms_to_chief_waves, want.rms_to_chief_waves);
    assert_eq!(st.strehl_marechal, want.strehl_marechal);
    assert_eq!(z, want.zernike_standard.coefficients);
    assert_eq!(st.n_rays, w.opd_waves.len() as u64);
    // A wrong Zernike buffer, bad options.
    // SAFETY: as above; the calls must refuse.
    unsafe {
        assert_eq!(
            tolray_wavefront(sys, &field, wl, &o, &mut st, z.as_mut_ptr(), 36),
            TOLRAY_ERROR_BUFFER_SIZE
        );
        assert_eq!(
            tolray_wavefront(sys, &field, wl, &o, &mut st, null_mut(), 0),
            TOLRAY_OK
        );
        let bad = tolray_wave_options {
            zernike_terms: 500,
            ..o
        };
        assert_eq!(
            tolray_wavefront(sys, &field, wl, &bad, &mut st, null_mut(), 0),
            TOLRAY_ERROR_ARGUMENT
        );
        let far = tolray_field {
            kind: TOLRAY_FIELD_ANGLE_DEG,
            x: 0.0,
            y: 80.0,
        };
        assert_eq!(
            tolray_wavefront(sys, &far, wl, &o, &mut st, null_mut(), 0),
            TOLRAY_ERROR_NUMERICAL
        );
        assert_eq!(
            tolray_wavefront(sys, &field, wl, null(), &mut st, null_mut(), 0),
            TOLRAY_ERROR_NULL_ARGUMENT
        );
    }

    // The OPD map.
    let n = 32;
    let mut opd = vec![f64::NAN; n * n];
    let mut valid = vec![9u8; n * n];
    // SAFETY: buffers of n² elements.
    let r = unsafe {
        tolray_opd_map(
            sys,
            &field,
            wl,
            n as u32,
            0,
            1,
            opd.as_mut_ptr(),
            valid.as_mut_ptr(),
            n * n,
        )
    };
    assert_eq!(r, TOLRAY_OK, "{}", last_error());
    let g = wave::wavefront(
        &l,
        &s,
        f,
        wl,
        &WaveOptions {
            sampling: Sampling::Grid(n),
            ..WaveOptions::default()
        },
    )
    .unwrap();
    assert_eq!(valid.iter().filter(|&&v| v == 1).count(), g.opd_waves.len());
    assert!(valid.iter().all(|&v| v <= 1) && opd.iter().all(|v| v.is_finite()));
    let sum: f64 = opd.iter().sum();
    assert!((sum - g.opd_waves.iter().sum::<f64>()).abs() < 1e-9);

    // Diffraction PSFs and MTFs.
    let d = tolray_diffraction_options {
        method: TOLRAY_DIFFRACTION_FFT,
        pupil_samples: 32,
        grid: 64,
        pitch_um: 1.0,
        aim: 0,
        apertures: 1,
    };
    let mut img = vec![0.0; 64 * 64];
    let (mut strehl, mut pitch) = (0.0, [0.0; 2]);
    // SAFETY: `img` holds 64² doubles, `pitch` two.
    let r = unsafe {
        tolray_diffraction_psf(
            sys,
            &field,
            wl,
            &d,
            img.as_mut_ptr(),
            img.len(),
            &mut strehl,
            pitch.as_mut_ptr(),
        )
    };
    assert_eq!(r, TOLRAY_OK, "{}", last_error());
    let want = psf::fft_psf(
        &g_of(&l, &s, f, wl, 32),
        &psf::FftOptions {
            pupil_samples: 32,
            grid: 64,
        },
    )
    .unwrap();
    assert_eq!(strehl, want.strehl);
    assert_eq!(img, want.values);
    assert_eq!(pitch, want.pitch_um);
    let h = tolray_diffraction_options {
        method: TOLRAY_DIFFRACTION_HUYGENS,
        grid: 16,
        pitch_um: 0.5,
        ..d
    };
    let mut small = vec![0.0; 16 * 16];
    // SAFETY: `small` holds 16² doubles.
    let r = unsafe {
        tolray_diffraction_psf(
            sys,
            &field,
            wl,
            &h,
            small.as_mut_ptr(),
            small.len(),
            &mut strehl,
            pitch.as_mut_ptr(),
        )
    };
    assert_eq!(r, TOLRAY_OK, "{}", last_error());
    assert_eq!(pitch, [0.5, 0.5]);
    for (bad, want) in [
        (
            tolray_diffraction_options { grid: 40, ..d },
            TOLRAY_ERROR_ARGUMENT,
        ),
        (
            tolray_diffraction_options {
                pupil_samples: 100_000,
                grid: 8192,
                ..d
            },
            TOLRAY_ERROR_ARGUMENT,
        ),
        (
            tolray_diffraction_options { method: 7, ..d },
            TOLRAY_ERROR_ARGUMENT,
        ),
    ] {
        // SAFETY: as above; refused before writing.
        let r = unsafe {
            tolray_diffraction_psf(
                sys,
                &field,
                wl,
                &bad,
                img.as_mut_ptr(),
                img.len(),
                &mut strehl,
                pitch.as_mut_ptr(),
            )
        };
        assert_eq!(r, want, "{bad:?}: {}", last_error());
    }
    // SAFETY: a wrong length is refused.
    let r = unsafe {
        tolray_diffraction_psf(
            sys,
            &field,
            wl,
            &d,
            img.as_mut_ptr(),
            100,
            &mut strehl,
            pitch.as_mut_ptr(),
        )
    };
    assert_eq!(r, TOLRAY_ERROR_BUFFER_SIZE);

    let freqs = [0.0, 20.0, 40.0];
    let (mut t, mut sg, mut lim) = ([0.0; 3], [0.0; 3], [0.0; 3]);
    for method in [TOLRAY_MTF_FFT, TOLRAY_MTF_DIRECT] {
        let m = tolray_diffraction_options { method, ..d };
        // SAFETY: outputs of three doubles each.
        let r = unsafe {
            tolray_mtf(
                sys,
                &field,
                wl,
                &m,
                freqs.as_ptr(),
                3,
                t.as_mut_ptr(),
                sg.as_mut_ptr(),
                lim.as_mut_ptr(),
            )
        };
        assert_eq!(r, TOLRAY_OK, "{}", last_error());
        let want = if method == TOLRAY_MTF_FFT {
            mtf::fft_mtf(
                &g_of(&l, &s, f, wl, 32),
                &psf::FftOptions {
                    pupil_samples: 32,
                    grid: 64,
                },
                &freqs,
            )
            .unwrap()
        } else {
            mtf::direct_mtf(
                &l,
                &s,
                f,
                wl,
                &WaveOptions {
                    sampling: Sampling::Grid(32),
                    ..WaveOptions::default()
                },
                &freqs,
            )
            .unwrap()
        };
        assert_eq!(t.to_vec(), want.tangential);
        assert_eq!(sg.to_vec(), want.sagittal);
        assert_eq!(lim.to_vec(), want.diffraction_limit);
    }
    let above = [5000.0];
    // SAFETY: one frequency, outputs of three doubles.
    let r = unsafe {
        tolray_mtf(
            sys,
            &field,
            wl,
            &d,
            above.as_ptr(),
            1,
            t.as_mut_ptr(),
            sg.as_mut_ptr(),
            null_mut(),
        )
    };
    assert_eq!(r, TOLRAY_ERROR_ARGUMENT);
    assert!(last_error().contains("cutoff"), "{}", last_error());
    // SAFETY: no frequency.
    let r = unsafe {
        tolray_mtf(
            sys,
            &field,
            wl,
            &d,
            freqs.as_ptr(),
            0,
            t.as_mut_ptr(),
            sg.as_mut_ptr(),
            null_mut(),
        )
    };
    assert_eq!(r, TOLRAY_ERROR_BUFFER_SIZE);
    // SAFETY: handles from above.
    unsafe {
        tolray_system_free(sys);
        tolray_lens_free(lens);
    }
}

pub(super) fn g_of(
    l: &tolray::Lens,
    s: &tolray::lens::System<f64>,
    f: tolray::trace::Field,
    wl: f64,
    n: usize,
) -> tolray::wave::Wavefront {
    tolray::wave::wavefront(
        l,
        s,
        f,
        wl,
        &tolray::wave::WaveOptions {
            sampling: tolray::wave::Sampling::Grid(n),
            ..tolray::wave::WaveOptions::default()
        },
    )
    .unwrap()
}

/// `tolray_trace` reads, traces and writes chunks of rays on the thread pool when no arrays
/// overlap at an offset: its output equals the library's trace of the same rays, with arrays
/// apart, traced in place (outputs on the inputs), and overlapping at an offset (the whole-set
/// path: every input read before any output is written), at 1 and 3 threads.
#[test]
fn trace_through_the_c_abi_in_chunks_and_in_place() {
    use std::ptr::null_mut;
    use tolray::ffi::*;
    use tolray::lens::Lens;
    use tolray::math::Vec3;
    use tolray::trace::{trace, RayBatch, TraceOptions};
    let n = 40_000; // three chunks, the last partial
    let rays: Vec<[f64; 6]> = (0..n)
        .map(|i| {
            let t = i as f64 * 0.618_033_988_749_895;
            let (r, a) = ((t.fract()).sqrt() * 14.0, i as f64 * 2.399_963);
            let (dx, dy) = (
                0.004 * (t * 7.0).sin(),
                0.03 * ((i % 17) as f64 / 16.0 - 0.5),
            );
            let m = (1.0 + dx * dx + dy * dy).sqrt();
            [r * a.cos(), r * a.sin(), -5.0, dx / m, dy / m, 1.0 / m]
        })
        .collect();
    let lens = Lens::load("lens2").unwrap();
    let mut b = RayBatch::<f64>::new();
    for r in &rays {
        b.push(Vec3::new(r[0], r[1], r[2]), Vec3::new(r[3], r[4], r[5]));
    }
    let opts = TraceOptions { apertures: true };
    trace(&lens.compile(), 550.0, &mut b, opts);
    let want: Vec<[f64; 8]> = b
        .iter()
        .map(|r| {
            let s = r.status.code() as f64;
            [r.o.x, r.o.y, r.o.z, r.d.x, r.d.y, r.d.z, r.opl, s]
        })
        .collect();
    assert!(want.iter().any(|w| w[7] != 0.0) && want.iter().any(|w| w[7] == 0.0));
    let name = std::ffi::CString::new("lens2").unwrap();
    let mut lh = null_mut();
    // SAFETY: valid pointers; handles freed below.
    let sys = unsafe {
        assert_eq!(
            tolray_lens_load(name.as_ptr(), &mut lh),
            tolray_status::TOLRAY_OK
        );
        nominal_system(lh)
    };
    // Columns of n + 8 doubles: inputs from 0, outputs from `shift` (in the inputs' columns
    // when `shared`).
    let run = |threads: usize, shared: bool, shift: usize| {
        let mut cols = vec![vec![0f64; n + 8]; 13];
        for (j, col) in cols.iter_mut().take(6).enumerate() {
            for (i, r) in rays.iter().enumerate() {
                col[i] = r[j];
            }
        }
        let mut status = vec![0u32; n];
        let p: Vec<*mut f64> = cols.iter_mut().map(|c| c.as_mut_ptr()).collect();
        // SAFETY: every pointer below stays within its column of n + 8 doubles.
        let (rin, rout) = unsafe {
            let at = |k: usize, off: usize| p[k].add(off);
            let rin = tolray_rays_in {
                x: at(0, 0),
                y: at(1, 0),
                z: at(2, 0),
                dx: at(3, 0),
                dy: at(4, 0),
                dz: at(5, 0),
            };
            let o = |k: usize| at(if shared { k - 6 } else { k }, shift);
            let rout = tolray_rays_out {
                x: o(6),
                y: o(7),
                z: o(8),
                dx: o(9),
                dy: o(10),
                dz: o(11),
                opl: at(12, shift),
                status: status.as_mut_ptr(),
            };
            (rin, rout)
        };
        /// The call's pointers, moved to the pool's thread (the test owns what they point to).
        struct Call(*const tolray_system, tolray_rays_in, tolray_rays_out);
        // SAFETY: the pointees outlive the call, and nothing else touches them meanwhile.
        unsafe impl Send for Call {}
        let call = Call(sys, rin, rout);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let st = pool.install(move || {
            let c = call;
            // SAFETY: live system; every array holds n elements from its pointer.
            unsafe { tolray_trace(c.0, 550.0, TOLRAY_TRACE_APERTURES, n, &c.1, &c.2) }
        });
        assert_eq!(st, tolray_status::TOLRAY_OK);
        let first = if shared { 0 } else { 6 };
        (0..n)
            .map(|i| {
                let c = |k: usize| cols[k][i + shift];
                let s = status[i] as f64;
                [
                    c(first),
                    c(first + 1),
                    c(first + 2),
                    c(first + 3),
                    c(first + 4),
                    c(first + 5),
                    c(12),
                    s,
                ]
            })
            .collect::<Vec<_>>()
    };
    for threads in [1, 3] {
        assert!(
            run(threads, false, 0) == want,
            "arrays apart, {threads} threads"
        );
        assert!(run(threads, true, 0) == want, "in place, {threads} threads");
        // Outputs 8 doubles after the inputs in the same columns: a chunk would overwrite the
        // first inputs of the next; the whole-set path reads them all first.
        assert!(
            run(threads, true, 8) == want,
            "overlapping, {threads} threads"
        );
    }
    // SAFETY: handles from the calls above.
    unsafe {
        tolray_system_free(sys);
        tolray_lens_free(lh);
    }
}
