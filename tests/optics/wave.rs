//! Wave optics against closed forms: a Cartesian oval (a conic refracting surface that images
//! infinity perfectly into glass) has zero OPD, an Airy PSF, a Strehl ratio of 1 and the
//! circular pupil's MTF; the same surface defocused has the Z4 that the geometry gives; FFT
//! and Huygens PSFs of one case agree; bad input is refused by name. The cross-check against
//! optiland is in `wave_reference`.

use tolray::trace::Field;
use tolray::wave::mtf::{circular_pupil_mtf, fft_mtf};
use tolray::wave::psf::{fft_psf, huygens_psf, FftOptions, HuygensOptions};
use tolray::wave::zernike::{zernike, Ordering};
use tolray::wave::{wavefront, Sampling, WaveOptions};
use tolray::{ErrorKind, Lens};

const WL: f64 = 587.5618;
/// Index of the oval's glass, surface radius and semi-aperture (mm).
pub(crate) const N: f64 = 1.5;
const R: f64 = 20.0;
const H: f64 = 5.0;

/// A single conic surface of index N with conic -1/N²: parallel light focuses without
/// aberration at f' = N R / (N - 1) inside the glass; the sensor moved by `dz_mm` from there.
fn oval(dz_mm: f64) -> Lens {
    oval_of(dz_mm, H)
}

/// [`oval`] with semi-aperture `h` mm.
pub(crate) fn oval_of(dz_mm: f64, h: f64) -> Lens {
    let f = N * R / (N - 1.0);
    tolray::lens::json::from_str(&format!(
        r#"{{"(object)": "inf", "primary_wvln": 0.5875618, "r_sensor": 1.0,
        "surfaces": [{{"type": "Spheric", "c": {c}, "k": {k}, "r": {h}, "mat2": "{N}",
        "d_next": {d}, "is_aperture": true}}]}}"#,
        c = 1.0 / R,
        k = -1.0 / (N * N),
        d = f + dz_mm
    ))
    .unwrap()
}

/// The oval's image-space sine of the marginal ray's angle, from its geometry.
pub(crate) fn marginal_sine(h: f64) -> f64 {
    let f = N * R / (N - 1.0);
    let c = 1.0 / R;
    let k = -1.0 / (N * N);
    let z = c * h * h / (1.0 + (1.0 - (1.0 + k) * c * c * h * h).sqrt());
    h / h.hypot(f - z)
}

fn grid(n: usize) -> WaveOptions {
    WaveOptions {
        sampling: Sampling::Grid(n),
        ..WaveOptions::default()
    }
}

#[test]
fn a_perfect_focus_has_no_opd_and_a_strehl_ratio_of_one() {
    let l = oval(0.0);
    let w = wavefront(
        &l,
        &l.compile(),
        Field::angle(0.0),
        WL,
        &WaveOptions::default(),
    )
    .unwrap();
    assert_eq!(
        w.opd_waves.len(),
        16 * 48,
        "every quadrature ray gets through"
    );
    let s = w.stats(37).unwrap();
    assert!(s.rms_to_chief_waves < 1e-7, "RMS {}", s.rms_to_chief_waves);
    assert!(s.pv_to_chief_waves < 1e-6, "PV {}", s.pv_to_chief_waves);
    assert!((s.strehl_marechal - 1.0).abs() < 1e-10);
    assert!((w.image_index - N).abs() < 1e-15);
    let p = fft_psf(
        &tolray::wave::wavefront(&l, &l.compile(), Field::angle(0.0), WL, &grid(64)).unwrap(),
        &FftOptions::default(),
    )
    .unwrap();
    assert!((p.strehl - 1.0).abs() < 1e-9, "FFT Strehl {}", p.strehl);
}

#[test]
fn a_perfect_focus_has_an_airy_psf_and_the_circular_pupils_mtf() {
    // Stopped down to f/30, where sin θ is proportional to the pupil coordinate to 4e-4 (the
    // oval does not obey the sine condition: at f/6 the Airy ring moves by 0.6 %).
    let h = 1.0;
    let l = oval_of(0.0, h);
    let na = N * marginal_sine(h);
    let lambda_mm = WL * 1e-6;
    // Huygens along x through the centre: the first zero of (2 J1(v) / v)², v = 2π NA r / λ,
    // at v = 3.8317 (r = 0.60983 λ / NA), found by a parabola through the three samples around
    // the darkest one.
    let airy = 3.831_705_970_2 / std::f64::consts::TAU * lambda_mm / na;
    let w = wavefront(
        &l,
        &l.compile(),
        Field::angle(0.0),
        WL,
        &WaveOptions {
            sampling: Sampling::Quadrature {
                rings: 12,
                spokes: 48,
            },
            ..WaveOptions::default()
        },
    )
    .unwrap();
    // Samples 1/100 of the Airy radius apart (at 1/25 the parabola is 0.25 % off).
    let m = 241;
    let pitch_um = airy * 1e3 / 100.0;
    let p = huygens_psf(
        &w,
        &HuygensOptions {
            image_samples: m,
            pitch_um,
        },
    )
    .unwrap();
    let row = &p.values[(m / 2) * m..(m / 2 + 1) * m];
    assert!(
        (row[m / 2] - 1.0).abs() < 1e-6,
        "unaberrated peak {}",
        row[m / 2]
    );
    let first = (m / 2 + 1..m - 1)
        .find(|&i| row[i] < row[i - 1] && row[i] <= row[i + 1])
        .unwrap();
    let (a, b, c) = (row[first - 1], row[first], row[first + 1]);
    let frac = 0.5 * (a - c) / (a - 2.0 * b + c);
    let r_zero = ((first - m / 2) as f64 + frac) * pitch_um * 1e-3;
    assert!(
        (r_zero / airy - 1.0).abs() < 1e-3,
        "first zero at {r_zero} mm, Airy {airy} mm"
    );
    assert!(b < 1e-3, "the first zero holds {b}");
    // MTF: cutoff 2 NA / λ, and the circular pupil's curve.
    let w = wavefront(&l, &l.compile(), Field::angle(0.0), WL, &grid(128)).unwrap();
    let fft = FftOptions {
        pupil_samples: 128,
        grid: 512,
    };
    let cut = 2.0 * na / lambda_mm;
    let f: Vec<f64> = [0.1, 0.25, 0.5, 0.75, 0.9]
        .iter()
        .map(|x| x * cut)
        .collect();
    let mtf = fft_mtf(&w, &fft, &f).unwrap();
    // The pupil coordinates map to sin θ only nearly linearly, so the fitted NA differs from
    // the marginal ray's by the pupil's distortion (small at NA 0.19).
    for c in mtf.cutoff_lpmm {
        assert!((c / cut - 1.0).abs() < 2e-3, "cutoff {c} vs {cut}");
    }
    for (k, &nu) in f.iter().enumerate() {
        let want = circular_pupil_mtf(nu, cut);
        for got in [mtf.tangential[k], mtf.sagittal[k], mtf.diffraction_limit[k]] {
            assert!(
                (got - want).abs() < 5e-3,
                "MTF at {nu:.1}/mm: {got} vs {want}"
            );
        }
    }
}

#[test]
fn a_defocused_perfect_focus_has_the_z4_its_geometry_gives() {
    // Sensor 0.02 mm behind the focus: W(θ) = n' Δz (1 - cos θ) to first order in Δz, leading
    // the reference sphere (positive) at the rim.
    let dz = 0.02;
    let l = oval(dz);
    let w = wavefront(
        &l,
        &l.compile(),
        Field::angle(0.0),
        WL,
        &WaveOptions::default(),
    )
    .unwrap();
    let s = w.stats(37).unwrap();
    // The closed form projected on Z4 by an independent quadrature (ρ = h / H).
    let gl = gauss(32);
    let mut z4 = 0.0;
    let mut mean = 0.0;
    for (x, wx) in gl {
        let rho = (0.5 * (x + 1.0)).sqrt();
        let sin = marginal_sine(rho * H);
        let wv = N * dz * (1.0 - (1.0 - sin * sin).sqrt()) / (WL * 1e-6);
        z4 += 0.5 * wx * wv * zernike(Ordering::Standard, 4, rho, 0.0);
        mean += 0.5 * wx * wv;
    }
    let got = s.zernike_standard.coefficients[3];
    assert!(
        got > 0.0,
        "a sensor behind the focus gives positive defocus, got {got}"
    );
    assert!((got / z4 - 1.0).abs() < 1e-3, "Z4 {got} vs {z4} waves");
    // ... and about W020 / (2√3) with W020 = Δz NA² / (2 n') (paraxial), to the higher orders.
    let na = N * marginal_sine(H);
    let w020 = dz * na * na / (2.0 * N) / (WL * 1e-6);
    assert!((got / (w020 / (2.0 * 3f64.sqrt())) - 1.0).abs() < 0.02);
    let _ = mean;
    // Only rotationally symmetric terms.
    for j in [2, 3, 5, 6, 7, 8, 9, 10] {
        assert!(s.zernike_standard.coefficients[j - 1].abs() < 1e-9, "Z{j}");
    }
}

fn gauss(n: usize) -> Vec<(f64, f64)> {
    // Golub–Welsch would do; Newton on P_n is enough here.
    (1..=n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 - 0.25) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let kf = k as f64;
                    let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                x -= p1 / dp;
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

#[test]
fn fft_and_huygens_psfs_agree_on_a_well_sampled_case() {
    // The Cooke triplet off axis: coma and astigmatism (0.7 waves RMS at 14°), a PSF a few Airy
    // disks wide, no OPD step of half a wave between pupil samples.
    let l = Lens::load("cooke-triplet").unwrap();
    let sys = l.compile();
    let w = wavefront(&l, &sys, Field::fraction(0.5), WL, &grid(64)).unwrap();
    let fft = fft_psf(
        &w,
        &FftOptions {
            pupil_samples: 64,
            grid: 256,
        },
    )
    .unwrap();
    let m = 64;
    let h = huygens_psf(
        &w,
        &HuygensOptions {
            image_samples: m,
            pitch_um: fft.pitch_um[0],
        },
    )
    .unwrap();
    // Compare on the Huygens grid (the FFT's square pixels on axis... off axis the FFT's y pitch
    // differs slightly: resample the FFT bilinearly).
    let n = fft.n;
    let at = |x_um: f64, y_um: f64| -> f64 {
        let fx = x_um / fft.pitch_um[0] + (n / 2) as f64;
        let fy = (n / 2) as f64 - y_um / fft.pitch_um[1];
        let (i, j) = (fx.floor() as usize, fy.floor() as usize);
        let (a, b) = (fx - i as f64, fy - j as f64);
        let v = |i: usize, j: usize| fft.values[j * n + i];
        v(i, j) * (1.0 - a) * (1.0 - b)
            + v(i + 1, j) * a * (1.0 - b)
            + v(i, j + 1) * (1.0 - a) * b
            + v(i + 1, j + 1) * a * b
    };
    let mut worst: f64 = 0.0;
    for r in 0..m {
        for c in 0..m {
            let x = (c as f64 - (m / 2) as f64) * h.pitch_um[0];
            let y = ((m / 2) as f64 - r as f64) * h.pitch_um[1];
            worst = worst.max((h.values[r * m + c] - at(x, y)).abs());
        }
    }
    let peak = h.values.iter().copied().fold(0.0, f64::max);
    assert!(
        worst < 3e-2 * peak,
        "largest difference {worst} of peak {peak}"
    );
    assert!(
        (fft.strehl - h.strehl).abs() < 0.02,
        "Strehl {} vs {}",
        fft.strehl,
        h.strehl
    );
}

#[test]
fn quadrature_converges_where_a_square_grid_does_not() {
    // lens2 without apertures (it vignettes its rim on axis, where no quadrature is exact).
    let l = Lens::load("lens2").unwrap();
    let sys = l.compile();
    let f = Field::fraction(0.7);
    let rms = |s: Sampling| {
        let o = WaveOptions {
            sampling: s,
            trace: tolray::trace::TraceOptions { apertures: false },
            ..WaveOptions::default()
        };
        wavefront(&l, &sys, f, WL, &o)
            .unwrap()
            .stats(37)
            .unwrap()
            .rms_to_centroid_waves
    };
    let a = rms(Sampling::Quadrature {
        rings: 16,
        spokes: 48,
    });
    let b = rms(Sampling::Quadrature {
        rings: 32,
        spokes: 96,
    });
    // Measured: 20.379543742898 and 20.379543742793 (64 x 192: ...742818).
    assert!((a - b).abs() < 1e-8 * b, "{a} vs {b}");
    // The grid's staircase rim: 20.4507 on a 64² grid (0.35 % off), 20.3779 on 256² — the
    // reason the quadrature is the default.
    let g = rms(Sampling::Grid(64));
    assert!((g - b).abs() > 1e-3 * b, "grid {g} vs {b}");
}

#[test]
fn bad_input_is_refused_by_name() {
    let l = Lens::load("lens2").unwrap();
    let sys = l.compile();
    // A field beyond the lens' reach.
    let e = wavefront(&l, &sys, Field::angle(80.0), WL, &WaveOptions::default()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Numerical);
    assert!(e.message().contains("chief ray"), "{}", e.message());
    // A pupil sampling too large to allocate.
    let e = wavefront(&l, &sys, Field::angle(0.0), WL, &grid(100_000)).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Argument);
    assert!(e.message().contains("at most"), "{}", e.message());
    // A pupil grid too coarse for lens2's 20 waves of defocus (it would alias).
    let w = wavefront(&l, &sys, Field::angle(0.0), WL, &grid(64)).unwrap();
    let e = fft_mtf(&w, &FftOptions::default(), &[10.0]).unwrap_err();
    assert!(e.message().contains("undersampled"), "{}", e.message());
    // A frequency above the cutoff.
    let c = Lens::load("cooke-triplet").unwrap();
    let wc = wavefront(&c, &c.compile(), Field::angle(0.0), WL, &grid(64)).unwrap();
    let e = fft_mtf(&wc, &FftOptions::default(), &[10.0, 5000.0]).unwrap_err();
    assert!(e.message().contains("cutoff"), "{}", e.message());
    // A wavefront on the default quadrature is not the FFT's grid: the MTF refuses it as the
    // PSF does (it read the quadrature's points as grid cells and gave 0.09 for 0.82).
    let wq = wavefront(
        &c,
        &c.compile(),
        Field::angle(0.0),
        WL,
        &WaveOptions::default(),
    )
    .unwrap();
    for e in [
        fft_mtf(&wq, &FftOptions::default(), &[10.0]).unwrap_err(),
        fft_psf(&wq, &FftOptions::default()).unwrap_err(),
    ] {
        assert_eq!(e.kind(), ErrorKind::Argument);
        assert!(
            e.message().contains("64 x 64 pupil grid"),
            "{}",
            e.message()
        );
    }
    // A grid that would wrap the MTF, and one too large.
    assert!(fft_psf(
        &w,
        &FftOptions {
            pupil_samples: 64,
            grid: 100
        }
    )
    .is_err());
    assert!(fft_psf(
        &w,
        &FftOptions {
            pupil_samples: 64,
            grid: 1 << 20
        }
    )
    .is_err());
    // An FFT of a wavefront not traced on its grid.
    let q = wavefront(&l, &sys, Field::angle(0.0), WL, &WaveOptions::default()).unwrap();
    assert!(fft_psf(&q, &FftOptions::default()).is_err());
    // Every number finite.
    let s = w.stats(37).unwrap();
    assert!(s
        .zernike_standard
        .coefficients
        .iter()
        .all(|v| v.is_finite()));
}

/// The polychromatic Huygens PSF: the oval's glass has one index at every wavelength, so the
/// oval is perfect in any light (Strehl 1, the Airy pattern of each wavelength summed); moving
/// its sensor adds defocus in each colour alike and lowers it below 1; weights are checked.
#[test]
fn a_polychromatic_huygens_psf_of_a_lens_without_colour() {
    use tolray::wave::psf::polychromatic_huygens_psf;
    let waves = |l: &Lens| -> Vec<tolray::wave::Wavefront> {
        [WL, 486.1327, 656.2725]
            .iter()
            .map(|&wl| wavefront(l, &l.compile(), Field::angle(0.0), wl, &grid(48)).unwrap())
            .collect()
    };
    let h = HuygensOptions {
        image_samples: 15,
        pitch_um: 1.0,
    };
    let sharp = waves(&oval(0.0));
    let refs: Vec<(&tolray::wave::Wavefront, f64)> = sharp.iter().zip([1.0, 2.0, 0.5]).collect();
    let p = polychromatic_huygens_psf(&refs, &h).unwrap();
    assert!((p.strehl - 1.0).abs() < 1e-6, "Strehl {}", p.strehl);
    // The weighted mean of the monochromatic PSFs, pixel for pixel (one centre: the axis).
    let mono: Vec<_> = sharp.iter().map(|w| huygens_psf(w, &h).unwrap()).collect();
    for k in 0..p.values.len() {
        let mean = (mono[0].values[k] + 2.0 * mono[1].values[k] + 0.5 * mono[2].values[k]) / 3.5;
        assert!((p.values[k] - mean).abs() < 1e-12, "pixel {k}");
    }
    let soft = waves(&oval(0.05));
    let refs: Vec<(&tolray::wave::Wavefront, f64)> = soft.iter().map(|w| (w, 1.0)).collect();
    let q = polychromatic_huygens_psf(&refs, &h).unwrap();
    assert!(
        q.strehl < 0.9 && q.strehl > 0.1,
        "defocused Strehl {}",
        q.strehl
    );
    // Weights: one zero is allowed, a negative or all-zero set is refused by name.
    let one = polychromatic_huygens_psf(&[(&soft[0], 1.0), (&soft[1], 0.0)], &h).unwrap();
    assert_eq!(one.values, huygens_psf(&soft[0], &h).unwrap().values);
    for bad in [-1.0, f64::NAN] {
        let e = polychromatic_huygens_psf(&[(&soft[0], bad)], &h).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Argument);
        assert!(e.message().contains("weight"), "{}", e.message());
    }
    let e = polychromatic_huygens_psf(&[(&soft[0], 0.0)], &h).unwrap_err();
    assert!(e.message().contains("every wavelength weight is zero"));
    assert!(polychromatic_huygens_psf(&[], &h).is_err());
}

/// The diffraction PSF on sensor pixels (image simulation's, issue 40): the oval's Airy pattern
/// deposited on pixels of a quarter of its first dark ring's radius holds 83.8 % of its energy
/// inside that ring (to 0.03: the window's cut and the pixels' tent widen it), symmetrically
/// about the centre pixel; a diffraction PSF map of one cell is the same PSF.
#[test]
fn a_perfect_focus_on_sensor_pixels_holds_the_airy_energy() {
    use tolray::wave::psf::{diffraction_psf_map, pixel_psf};
    let h = 1.0;
    let l = oval_of(0.0, h);
    let na = N * marginal_sine(h);
    let r0 = 3.831_705_970_2 / std::f64::consts::TAU * WL * 1e-6 / na;
    let (ks, pitch) = (81, r0 / 4.0);
    let w = wavefront(&l, &l.compile(), Field::angle(0.0), WL, &grid(64)).unwrap();
    let fft = FftOptions {
        pupil_samples: 64,
        grid: 512,
    };
    let p = pixel_psf(&w, &fft, ks, pitch).unwrap();
    assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    let c = (ks / 2) as f64;
    let ee: f64 = (0..ks * ks)
        .filter(|k| ((k % ks) as f64 - c).hypot((k / ks) as f64 - c) * pitch <= r0)
        .map(|k| p[k])
        .sum();
    assert!((ee - 0.8378).abs() < 0.03, "EE {ee}");
    let mid = (ks / 2) * ks + ks / 2;
    assert!(
        (p[mid - 3] - p[mid + 3]).abs() < 1e-9 && (p[mid - 3 * ks] - p[mid + 3 * ks]).abs() < 1e-9
    );
    assert!(p[mid] == p.iter().copied().fold(0.0, f64::max));
    // A 1 x 1 map of the oval's sensor is the on-axis PSF, sampled as the map samples it.
    let map = diffraction_psf_map(&l, &l.compile(), 1, WL, ks, pitch).unwrap();
    assert_eq!(map.len(), 1);
    let e: f64 = (0..ks * ks)
        .filter(|k| ((k % ks) as f64 - c).hypot((k / ks) as f64 - c) * pitch <= r0)
        .map(|k| map[0][k])
        .sum();
    assert!((e - 0.8378).abs() < 0.03, "map EE {e}");
}
