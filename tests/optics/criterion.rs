//! Tolerance criteria beyond the RMS spot (`--criterion rms-wavefront | strehl | mtf@F`): the
//! direct MTF and Strehl they use against the FFT ones and closed forms, the numbers a Monte
//! Carlo trial records against the wave analyses run by hand, and the focus compensator
//! against a scan of the sensor.

use super::wave::{marginal_sine, oval_of, N};
use tolray::analysis::aberrations::field_curvature;
use tolray::lens::material::{LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use tolray::tolerance::criterion::MTF_GRID;
use tolray::tolerance::{
    monte_carlo, perturbed_criterion, sensitivity, Criterion, McOptions, MtfDirection,
    Perturbation, SurfacePerturbation, ToleranceSpec,
};
use tolray::trace::{Field, Pupil, PupilPattern};
use tolray::wave::mtf::{circular_pupil_mtf, direct_mtf, fft_mtf};
use tolray::wave::psf::{fft_psf, strehl, FftOptions};
use tolray::wave::{wavefront, Sampling, WaveOptions};
use tolray::{ErrorKind, Lens};

const WL: f64 = 587.5618;

fn grid(n: usize) -> WaveOptions {
    WaveOptions {
        sampling: Sampling::Grid(n),
        ..WaveOptions::default()
    }
}

#[test]
fn the_direct_mtf_is_the_circular_pupils_on_a_perfect_focus() {
    // The oval at f/30 (see wave.rs): the MTF of a full circular pupil, cutoff 2 NA / λ.
    let h = 1.0;
    let l = oval_of(0.0, h);
    let cutoff = 2.0 * N * marginal_sine(h) / (WL * 1e-6);
    let freqs: Vec<f64> = [0.1, 0.25, 0.5, 0.75, 0.9]
        .iter()
        .map(|f| f * cutoff)
        .collect();
    let m = direct_mtf(&l, &l.compile(), Field::angle(0.0), WL, &grid(128), &freqs).unwrap();
    for (k, &f) in freqs.iter().enumerate() {
        let exact = circular_pupil_mtf(f, cutoff);
        for (what, v) in [
            ("tangential", m.tangential[k]),
            ("sagittal", m.sagittal[k]),
            ("limit", m.diffraction_limit[k]),
        ] {
            assert!(
                (v - exact).abs() < 5e-3,
                "{what} at {f:.1} cycles/mm: {v} against {exact}"
            );
        }
    }
    assert!((m.cutoff_lpmm[0] / cutoff - 1.0).abs() < 1e-3);
}

#[test]
fn the_direct_mtf_and_strehl_agree_with_the_fft_ones() {
    // Both methods converge to one MTF as the pupil grid is refined; the criterion's 32 x 32
    // grid is within 0.01 of the converged value (the FFT's default 64 samples in 256 is within
    // 0.005 too: it reads its OTF bilinearly between bins 5 cycles/mm apart).
    let (mut worst32, mut worst_conv) = (0.0f64, 0.0f64);
    for (name, field, freqs) in [
        ("cooke-triplet", 0.0, [10.0, 30.0, 60.0]),
        ("cooke-triplet", 0.7, [10.0, 30.0, 60.0]),
        ("lens1", 0.0, [20.0, 50.0, 100.0]),
        ("lens1", 0.7, [20.0, 50.0, 100.0]),
    ] {
        let l = Lens::load(name).unwrap();
        // lens1's sensor sits 2.8 mm before its paraxial focus (9 waves RMS of defocus): judge
        // it at that focus.
        let mut sys = l.compile();
        if name == "lens1" {
            let [t, _] = field_curvature(&l, &sys, Field::fraction(0.0), WL, false).unwrap();
            sys.image.translation.z += t;
        }
        let f = Field::fraction(field);
        let fine = wavefront(&l, &sys, f, WL, &grid(256)).unwrap();
        let fft = fft_mtf(
            &fine,
            &FftOptions {
                pupil_samples: 256,
                grid: 1024,
            },
            &freqs,
        )
        .unwrap();
        let conv = direct_mtf(&l, &sys, f, WL, &grid(192), &freqs).unwrap();
        let coarse = direct_mtf(&l, &sys, f, WL, &grid(MTF_GRID), &freqs).unwrap();
        for (k, freq) in freqs.iter().enumerate() {
            let pairs = [
                (fft.tangential[k], conv.tangential[k], coarse.tangential[k]),
                (fft.sagittal[k], conv.sagittal[k], coarse.sagittal[k]),
            ];
            for (a, b, c) in pairs {
                worst_conv = worst_conv.max((a - b).abs());
                worst32 = worst32.max((c - b).abs());
                assert!(
                    (a - b).abs() < 3e-3 && (c - b).abs() < 0.01,
                    "{name} field {field} at {freq} cycles/mm: FFT 256/1024 {a:.4}, direct 192 {b:.4}, \
                     direct 32 {c:.4}"
                );
            }
        }
        // The FFT PSF on the first grid fine enough for the wavefront (it refuses the others).
        let psf = [64, 128, 256]
            .iter()
            .find_map(|&n| {
                let o = FftOptions {
                    pupil_samples: n,
                    grid: 4 * n,
                };
                fft_psf(&wavefront(&l, &sys, f, WL, &grid(n)).unwrap(), &o).ok()
            })
            .unwrap();
        let q = wavefront(&l, &sys, f, WL, &WaveOptions::default()).unwrap();
        let s = strehl(&q);
        assert!(
            (s - psf.strehl).abs() < 0.01,
            "{name} field {field}: direct Strehl {s} against the FFT PSF's {}",
            psf.strehl
        );
    }
    println!(
        "direct (192²) vs FFT (256/1024) MTF: worst {worst_conv:.4}; criterion grid (32²) vs \
         converged: worst {worst32:.4}"
    );
}

#[test]
fn a_perfect_focus_has_a_strehl_ratio_of_one_and_defocus_lowers_it_as_theory_says() {
    let h = 5.0;
    let q = WaveOptions::default();
    let l = oval_of(0.0, h);
    let w = wavefront(&l, &l.compile(), Field::angle(0.0), WL, &q).unwrap();
    assert!((strehl(&w) - 1.0).abs() < 1e-9);
    // Pure defocus W = a (2ρ² − 1)·√3 (Z4 of RMS a): the Strehl of a uniform pupil with a
    // quadratic phase of peak-to-valley p waves is sinc²(p) (sin(π p) / (π p))².
    let d = wavefront(
        &oval_of(0.01, h),
        &oval_of(0.01, h).compile(),
        Field::angle(0.0),
        WL,
        &q,
    )
    .unwrap();
    let z4 = d.stats(4).unwrap().zernike_standard.coefficients[3];
    let p = 2.0 * 3f64.sqrt() * z4.abs();
    let exact = ((std::f64::consts::PI * p).sin() / (std::f64::consts::PI * p)).powi(2);
    // The oval's defocus also carries a little spherical aberration (Z11): a loose bound.
    assert!(
        (strehl(&d) - exact).abs() < 0.02,
        "Strehl {} against sinc² {exact} (PV {p} waves)",
        strehl(&d)
    );
}

fn options(criterion: Criterion, compensate: bool, wavelengths_nm: Vec<f64>) -> McOptions {
    McOptions {
        spec: ToleranceSpec::default(),
        trials: 6,
        seed: 3,
        fields: [0.0, 0.7].map(Field::fraction).to_vec(),
        wavelengths_nm,
        pupil: Pupil {
            pattern: PupilPattern::Grid(16),
            scale: 1.0,
            aim: false,
        },
        compensate_focus: compensate,
        apertures: true,
        criterion,
    }
}

#[test]
fn a_trial_records_the_wave_analyses_of_its_lens() {
    let l = Lens::load("cooke-triplet").unwrap();
    let wls = vec![LAMBDA_F_NM, LAMBDA_D_NM, LAMBDA_C_NM];
    let opts = options(Criterion::RmsWavefront, false, wls.clone());
    let report = monte_carlo(&l, "cooke-triplet", &opts, None, &|| {}).unwrap();
    let spec = ToleranceSpec::default();
    let k = 4;
    let pattern = spec.sample(&l, opts.seed, k as u64).unwrap();
    let (plens, adj) = pattern.apply(&l).unwrap();
    let sys = tolray::lens::System::compile(&plens, &adj, &|_, v| v);
    for (fi, f) in opts.fields.iter().enumerate() {
        let by_hand: f64 = wls
            .iter()
            .map(|&wl| {
                wavefront(&l, &sys, *f, wl, &WaveOptions::default())
                    .unwrap()
                    .rms_to_centroid_waves()
                    .unwrap()
            })
            .sum::<f64>()
            / 3.0;
        let rec = report.trials[k].criterion.as_ref().unwrap()[fi];
        assert!(
            (rec - by_hand).abs() < 1e-12,
            "field {fi}: recorded {rec}, by hand {by_hand}"
        );
    }
    let sm = report.summary.unwrap();
    let c = sm.criterion.unwrap();
    assert!(c.mean_over_fields.yield_above.is_empty());
    assert_eq!(c.per_field.len(), 2);
    // The RMS spot is still recorded.
    assert!(report.trials.iter().all(|t| t.rms_um.len() == 2));

    // The MTF criterion: the direct MTF on the criterion's grid, mean of T and S.
    let c = Criterion::Mtf {
        freq_lpmm: 30.0,
        direction: MtfDirection::Mean,
    };
    let opts = options(c, false, vec![LAMBDA_D_NM]);
    let (v, _, _) = perturbed_criterion(&l, &opts, &pattern).unwrap();
    for (fi, f) in opts.fields.iter().enumerate() {
        let m = direct_mtf(&l, &sys, *f, LAMBDA_D_NM, &grid(MTF_GRID), &[30.0]).unwrap();
        let by_hand = 0.5 * (m.tangential[0] + m.sagittal[0]);
        assert!((v[fi] - by_hand).abs() < 1e-12, "{} vs {by_hand}", v[fi]);
    }
    let report = monte_carlo(&l, "cooke-triplet", &opts, None, &|| {}).unwrap();
    let st = &report.summary.unwrap().criterion.unwrap().mean_over_fields;
    // Higher is better: 90 % of lenses reach at least the 10th percentile.
    assert_eq!(st.yield_above[0][0], 0.9);
    assert!(st.yield_above[0][1] <= st.yield_above[3][1]);
}

#[test]
fn the_compensator_finds_the_best_focus_of_the_criterion() {
    // Scan the sensor by hand (a gap change after the last surface moves the image plane along
    // the axis, which on a centred lens is its normal) around the compensator's answer.
    let l = Lens::load("cooke-triplet").unwrap();
    let last = l.surfaces.len() - 1;
    for c in [
        Criterion::RmsWavefront,
        Criterion::Strehl,
        Criterion::Mtf {
            freq_lpmm: 40.0,
            direction: MtfDirection::Tangential,
        },
    ] {
        let on = options(c, true, vec![LAMBDA_D_NM]);
        let off = options(c, false, vec![LAMBDA_D_NM]);
        let (best, _, dz) = perturbed_criterion(&l, &on, &Perturbation::default()).unwrap();
        let dz = dz.unwrap();
        let at = |z: f64| -> f64 {
            let p = Perturbation {
                surfaces: vec![SurfacePerturbation {
                    surface: last,
                    gap_mm: z,
                    ..Default::default()
                }],
                ..Default::default()
            };
            let v = perturbed_criterion(&l, &off, &p).unwrap().0;
            v.iter().sum::<f64>() / v.len() as f64
        };
        let mean = best.iter().sum::<f64>() / best.len() as f64;
        assert!((at(dz) - mean).abs() < 1e-9, "{c:?}: {} vs {mean}", at(dz));
        let sign = if c.higher_is_better() { 1.0 } else { -1.0 };
        for k in [-20, -5, -1, 1, 5, 20] {
            let z = dz + f64::from(k) * 2e-4;
            assert!(
                sign * (mean - at(z)) >= -1e-7,
                "{c:?}: {} at {z} beats {mean} at the compensator's {dz}",
                at(z)
            );
        }
        // And the spot's best focus is not better (it is where the search starts).
        let spot = perturbed_criterion(
            &l,
            &options(Criterion::RmsSpot, true, vec![LAMBDA_D_NM]),
            &Perturbation::default(),
        )
        .unwrap()
        .2
        .unwrap();
        assert!(sign * (mean - at(spot)) >= -1e-9);
    }
}

#[test]
fn criteria_are_parsed_and_bad_ones_refused_by_name() {
    for (s, ok) in [
        ("rms-spot", true),
        ("rms-wavefront", true),
        ("strehl", true),
        ("mtf@30", true),
        ("mtf@30:s", true),
        ("mtf@30:sagittal", true),
        ("mtf@0", false),
        ("mtf@abc", false),
        ("mtf@30:x", false),
        ("spot", false),
    ] {
        let r = Criterion::parse(s);
        assert_eq!(r.is_ok(), ok, "{s}: {r:?}");
        if let Ok(c) = r {
            assert_eq!(Criterion::parse(&c.spelling()).unwrap(), c);
        } else {
            let e = r.unwrap_err();
            assert_eq!(e.kind(), ErrorKind::Argument);
            assert!(e.message().contains(s), "{}", e.message());
        }
    }
    // A frequency beyond the cutoff is refused as such, by the Monte Carlo too.
    let l = Lens::load("cooke-triplet").unwrap();
    let opts = options(
        Criterion::Mtf {
            freq_lpmm: 5000.0,
            direction: MtfDirection::Mean,
        },
        false,
        vec![LAMBDA_D_NM],
    );
    let e = monte_carlo(&l, "cooke-triplet", &opts, None, &|| {}).unwrap_err();
    assert!(e.message().contains("cutoff"), "{}", e.message());
    let (nom, rows) =
        sensitivity(&l, &options(Criterion::Strehl, false, vec![LAMBDA_D_NM])).unwrap();
    assert!(nom.criterion.is_some());
    assert!(rows
        .windows(2)
        .all(|w| w[0].worst_delta_criterion >= w[1].worst_delta_criterion));
}
