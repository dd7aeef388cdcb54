//! Modulation transfer functions: diffraction (the pupil's autocorrelation, computed as the FFT
//! of the FFT PSF) and geometric (the Fourier transform of the rays' spot, times the diffraction
//! limit as OpticStudio recommends), tangential and sagittal.
//!
//! **Tangential** is the frequency along the field's direction in the image plane (y for a y
//! field, and y on axis), **sagittal** across it; MTFs are 1 at zero frequency. The
//! **diffraction limit** is the MTF of the same pupil (same vignetting) with the OPD set to
//! zero: for a full circular pupil, `(2/π)(φ − cos φ sin φ)`, `φ = acos(ν/ν_c)`,
//! `ν_c = 1 / (λ N_w)`. A frequency at or above the cutoff of its direction (where the shifted
//! pupils no longer overlap) is refused, naming the cutoff.

use super::psf::{direction_map, pupil_transform, FftOptions};
use super::Wavefront;
use crate::error::{Error, Result};
use rustfft::num_complex::Complex;
use serde::Serialize;

/// MTF of one field and wavelength at a list of frequencies.
#[derive(Clone, Debug, Serialize)]
pub struct Mtf {
    /// Frequencies, cycles per mm.
    pub freq_lpmm: Vec<f64>,
    /// Tangential MTF at each frequency.
    pub tangential: Vec<f64>,
    /// Sagittal MTF at each frequency.
    pub sagittal: Vec<f64>,
    /// Diffraction-limited MTF of the same pupil, tangential.
    pub diffraction_limit: Vec<f64>,
    /// Diffraction-limited MTF of the same pupil, sagittal.
    pub diffraction_limit_sagittal: Vec<f64>,
    /// Cutoff frequencies (tangential, sagittal), cycles per mm.
    pub cutoff_lpmm: [f64; 2],
}

/// The unit vectors (tangential, sagittal) in the image plane for the field of `w`.
pub(crate) fn directions(w: &Wavefront) -> ([f64; 2], [f64; 2]) {
    let [x, y] = w.centre_image_mm;
    let r = x.hypot(y);
    let t = if r > 1e-9 { [x / r, y / r] } else { [0.0, 1.0] };
    (t, [t[1], -t[0]])
}

/// Diffraction MTF and cutoffs from the FFT of the FFT PSF.
struct Otf {
    otf: Vec<Complex<f64>>,
    ideal: Vec<Complex<f64>>,
    n: usize,
    /// Cells of the OTF per cycle/mm along x and y (signed).
    cells_per_lpmm: [f64; 2],
    /// Pupil-coordinate shift per cycle/mm along x and y.
    shift_per_lpmm: [f64; 2],
}

impl Otf {
    fn new(w: &Wavefront, opts: &FftOptions) -> Result<Otf> {
        opts.check()?;
        super::psf::check_sampling(w, opts.pupil_samples)?;
        let map = direction_map(w)?;
        let (ax, ay) = (map[0][1], map[1][2]);
        let n = opts.grid;
        let lambda_mm = w.wavelength_nm * 1e-6;
        let dp = 2.0 / opts.pupil_samples as f64;
        let mut planner = rustfft::FftPlanner::<f64>::new();
        let f = planner.plan_fft_forward(n);
        let transform = |aberrated: bool| {
            let (a, _) = pupil_transform(w, opts, aberrated);
            let mut i: Vec<Complex<f64>> =
                a.iter().map(|v| Complex::new(v.norm_sqr(), 0.0)).collect();
            crate::psf::transform2(&mut i, n, &f);
            let dc = i[0].re;
            for v in &mut i {
                *v /= dc;
            }
            i
        };
        // PSF index k = sign(a) x / pitch, pitch = λ / (N Δp |a|): OTF index m = sign(a) ν N
        // pitch = ν λ / (Δp a).
        Ok(Otf {
            otf: transform(true),
            ideal: transform(false),
            n,
            cells_per_lpmm: [lambda_mm / (dp * ax), lambda_mm / (dp * ay)],
            shift_per_lpmm: [lambda_mm / ax.abs(), lambda_mm / ay.abs()],
        })
    }

    /// Cutoff along the image-plane unit vector `u`, cycles/mm: the shift of a pupil diameter.
    fn cutoff(&self, u: [f64; 2]) -> f64 {
        2.0 / (u[0] * self.shift_per_lpmm[0]).hypot(u[1] * self.shift_per_lpmm[1])
    }

    /// |OTF| at frequency `nu` (cycles/mm) along `u`, bilinear in the complex OTF.
    fn at(&self, table: &[Complex<f64>], nu: f64, u: [f64; 2]) -> f64 {
        let n = self.n as isize;
        let mx = nu * u[0] * self.cells_per_lpmm[0];
        let my = nu * u[1] * self.cells_per_lpmm[1];
        let (x0, y0) = (mx.floor(), my.floor());
        let (fx, fy) = (mx - x0, my - y0);
        let g = |i: isize, j: isize| {
            let (i, j) = (i.rem_euclid(n) as usize, j.rem_euclid(n) as usize);
            table[j * self.n + i]
        };
        let (i, j) = (x0 as isize, y0 as isize);
        let v = g(i, j) * ((1.0 - fx) * (1.0 - fy))
            + g(i + 1, j) * (fx * (1.0 - fy))
            + g(i, j + 1) * ((1.0 - fx) * fy)
            + g(i + 1, j + 1) * (fx * fy);
        v.norm()
    }
}

/// Checks frequencies: finite, not negative, below the cutoff of each direction.
fn check_freqs(freqs: &[f64], cut: [f64; 2]) -> Result<()> {
    if freqs.is_empty() {
        return Err(Error::argument("no MTF frequency given"));
    }
    for &f in freqs {
        if !(f >= 0.0 && f.is_finite()) {
            return Err(Error::argument(format!(
                "MTF frequency {f} cycles/mm: give a finite frequency >= 0"
            )));
        }
        let c = cut[0].min(cut[1]);
        if f >= c {
            return Err(Error::argument(format!(
                "MTF frequency {f} cycles/mm is at or above this field's diffraction cutoff \
                 ({:.2} cycles/mm tangential, {:.2} sagittal): the MTF is 0 there",
                cut[0], cut[1]
            )));
        }
    }
    Ok(())
}

/// The diffraction MTF of `w` (traced with [`super::Sampling::Grid`]`(opts.pupil_samples)`) at
/// `freqs` (cycles/mm), tangential and sagittal, with the diffraction limit of the same pupil.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for sizes [`FftOptions::check`] refuses, no frequency, or a
/// frequency not below the cutoff; [`crate::ErrorKind::Numerical`] for a beam that does not
/// converge or a pupil grid too coarse for the wavefront (as [`super::psf::fft_psf`]).
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{mtf::fft_mtf, psf::FftOptions, wavefront, Sampling, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let opts = WaveOptions { sampling: Sampling::Grid(64), ..WaveOptions::default() };
/// let w = wavefront(&lens, &lens.compile(), Field::fraction(0.7), 587.5618, &opts)?;
/// let m = fft_mtf(&w, &FftOptions::default(), &[0.0, 20.0, 40.0])?;
/// assert!((m.tangential[0] - 1.0).abs() < 1e-12);
/// assert!(m.tangential[2] <= m.diffraction_limit[2] + 1e-9);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn fft_mtf(w: &Wavefront, opts: &FftOptions, freqs: &[f64]) -> Result<Mtf> {
    let otf = Otf::new(w, opts)?;
    let (t, s) = directions(w);
    let cut = [otf.cutoff(t), otf.cutoff(s)];
    check_freqs(freqs, cut)?;
    let along = |table: &[Complex<f64>], u: [f64; 2]| -> Vec<f64> {
        freqs.iter().map(|&f| otf.at(table, f, u)).collect()
    };
    Ok(Mtf {
        freq_lpmm: freqs.to_vec(),
        tangential: along(&otf.otf, t),
        sagittal: along(&otf.otf, s),
        diffraction_limit: along(&otf.ideal, t),
        diffraction_limit_sagittal: along(&otf.ideal, s),
        cutoff_lpmm: cut,
    })
}

/// The geometric MTF of `w`'s rays at `freqs` (cycles/mm): the modulus of the weighted sum of
/// `exp(−2πi ν·x)` over the rays' image points (the Fourier transform of the spot, exact for
/// the rays, no binning), multiplied by the diffraction limit of the same pupil (computed with
/// `opts`, as [`fft_mtf`]). `w` may be sampled either way; the diffraction limit needs the
/// grid, so it is traced on [`super::Sampling::Grid`].
///
/// # Errors
/// As [`fft_mtf`].
pub fn geometric_mtf(
    w: &Wavefront,
    limit: &Wavefront,
    opts: &FftOptions,
    freqs: &[f64],
) -> Result<Mtf> {
    // Only the unaberrated pupil of `limit` is used: its OPD is not sampled.
    let mut flat = limit.clone();
    flat.opd_waves.iter_mut().for_each(|v| *v = 0.0);
    let otf = Otf::new(&flat, opts)?;
    let (t, s) = directions(w);
    let cut = [otf.cutoff(t), otf.cutoff(s)];
    check_freqs(freqs, cut)?;
    let c = w.centre_image_mm;
    let geo = |u: [f64; 2]| -> Vec<f64> {
        freqs
            .iter()
            .map(|&f| {
                let mut sum = Complex::new(0.0, 0.0);
                for (p, &wt) in w.image_points.iter().zip(&w.weight) {
                    let x = (p[0] - c[0]) * u[0] + (p[1] - c[1]) * u[1];
                    sum += Complex::from_polar(wt, -std::f64::consts::TAU * f * x);
                }
                sum.norm()
            })
            .collect()
    };
    let dl_t: Vec<f64> = freqs.iter().map(|&f| otf.at(&otf.ideal, f, t)).collect();
    let dl_s: Vec<f64> = freqs.iter().map(|&f| otf.at(&otf.ideal, f, s)).collect();
    let times = |a: Vec<f64>, b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).collect();
    Ok(Mtf {
        freq_lpmm: freqs.to_vec(),
        tangential: times(geo(t), &dl_t),
        sagittal: times(geo(s), &dl_s),
        diffraction_limit: dl_t,
        diffraction_limit_sagittal: dl_s,
        cutoff_lpmm: cut,
    })
}

/// The diffraction-limited MTF of a full circular pupil at `nu` for cutoff `cutoff` (same
/// units): `(2/π)(φ − cos φ sin φ)`, `φ = acos(ν/ν_c)`; 0 at and beyond the cutoff.
///
/// # Examples
/// ```
/// use tolray::wave::mtf::circular_pupil_mtf;
/// assert_eq!(circular_pupil_mtf(0.0, 100.0), 1.0);
/// assert!((circular_pupil_mtf(50.0, 100.0) - 0.3910).abs() < 1e-4);
/// assert_eq!(circular_pupil_mtf(120.0, 100.0), 0.0);
/// ```
#[must_use]
pub fn circular_pupil_mtf(nu: f64, cutoff: f64) -> f64 {
    let x = (nu / cutoff).abs();
    if x >= 1.0 {
        return 0.0;
    }
    let phi = x.acos();
    (2.0 / std::f64::consts::PI) * (phi - phi.cos() * phi.sin())
}
