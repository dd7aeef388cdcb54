//! Modulation transfer functions: diffraction (the pupil's autocorrelation, computed as the FFT
//! of the FFT PSF, or directly from exactly traced sheared pupils) and geometric (the Fourier transform of the rays' spot, times the diffraction
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
        let transform = |aberrated: bool| {
            let (a, _) = pupil_transform(w, opts, aberrated);
            let mut i: Vec<Complex<f64>> =
                a.iter().map(|v| Complex::new(v.norm_sqr(), 0.0)).collect();
            crate::fft::fft2(&mut i, n, n, false);
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

/// Cutoff of `w`'s pupil along the image-plane unit vector `u`, cycles/mm (the shift of a pupil
/// diameter), from its [`direction_map`] `map`.
pub(crate) fn cutoff_along(w: &Wavefront, map: &[[f64; 3]; 2], u: [f64; 2]) -> f64 {
    let lambda_mm = w.wavelength_nm * 1e-6;
    2.0 / (u[0] * lambda_mm / map[0][1]).hypot(u[1] * lambda_mm / map[1][2])
}

/// Checks frequencies: finite, not negative, below the cutoff of each direction.
pub(crate) fn check_freqs(freqs: &[f64], cut: [f64; 2]) -> Result<()> {
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

/// The diffraction OTF modulus of the pupil of `base` (traced by [`super::wavefront`] through
/// `lens`/`sys`) at `nu` cycles/mm along the image-plane unit vector `u`, and the same for the
/// unaberrated pupil: see [`direct_mtf`]. `map` is `base`'s [`direction_map`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn direct_otf(
    lens: &crate::lens::Lens,
    sys: &crate::lens::System<f64>,
    base: &Wavefront,
    map: &[[f64; 3]; 2],
    opts: &super::WaveOptions,
    nu: f64,
    u: [f64; 2],
) -> Result<(f64, f64)> {
    direct_otf_complex(lens, sys, base, map, opts, nu, u).map(|(o, l)| (o.norm(), l))
}

/// [`direct_otf`] with the OTF's phase: `Σ_p w_p P(p) P*(p − δ)`. A PSF displaced by `Δ` in the
/// image plane multiplies it by `exp(i 2π ν u·Δ)`: the displacement is a wavefront tilt
/// `W_p = a p·Δ / λ` (the amplitude at x is `Σ exp(i 2π (W_p − a p·x / λ))`), and
/// `P(p) P*(p − δ)` then gains `exp(i 2π a δ·Δ / λ) = exp(i 2π ν u·Δ)`. `base` must be referred
/// to the chief ray: the sheared rays are.
#[allow(clippy::too_many_arguments)]
pub(crate) fn direct_otf_complex(
    lens: &crate::lens::Lens,
    sys: &crate::lens::System<f64>,
    base: &Wavefront,
    map: &[[f64; 3]; 2],
    opts: &super::WaveOptions,
    nu: f64,
    u: [f64; 2],
) -> Result<(Complex<f64>, f64)> {
    if nu == 0.0 {
        return Ok((Complex::new(1.0, 0.0), 1.0));
    }
    let lambda_mm = base.wavelength_nm * 1e-6;
    let shift = [
        nu * u[0] * lambda_mm / map[0][1],
        nu * u[1] * lambda_mm / map[1][2],
    ];
    // The sheared points inside the unit disk, and which base ray each belongs to.
    let mut pts = Vec::with_capacity(base.pupil.len());
    let mut owner = Vec::with_capacity(base.pupil.len());
    for (i, p) in base.pupil.iter().enumerate() {
        let q = [p[0] - shift[0], p[1] - shift[1]];
        if q[0] * q[0] + q[1] * q[1] <= 1.0 {
            pts.push(q);
            owner.push(i);
        }
    }
    if pts.is_empty() {
        return Ok((Complex::new(0.0, 0.0), 0.0));
    }
    let ones = vec![1.0; pts.len()];
    // The sheared rays are referred to the chief ray, as `base` is (a centroid reference would
    // be the sheared set's own centroid, another sphere).
    let chief = super::WaveOptions {
        reference: super::Reference::Chief,
        ..*opts
    };
    let sheared = super::trace_wavefront(
        lens,
        sys,
        base.field,
        base.wavelength_nm,
        &pts,
        &ones,
        &chief,
        0,
    )?;
    let (mut otf, mut overlap) = (Complex::new(0.0, 0.0), 0.0);
    for (&k, &opd) in sheared.ray_index.iter().zip(&sheared.opd_waves) {
        let i = owner[k];
        let wt = base.weight[i];
        otf += Complex::from_polar(wt, std::f64::consts::TAU * (base.opd_waves[i] - opd));
        overlap += wt;
    }
    Ok((otf, overlap))
}

/// The diffraction MTF at `freqs` (cycles/mm) by the pupil's autocorrelation evaluated
/// directly, tangential and sagittal, with the diffraction limit of the same pupil. For a
/// frequency `ν` along `u` the OTF is `Σ_p w_p P(p) P*(p − δ)` over the pupil points `p` of
/// `opts.sampling` (weights normalised over the rays that get through), `δ = λ ν u / a` (`a`
/// the slopes of the rays' direction cosines over the pupil, as [`fft_mtf`] scales its
/// pixels), and `P(p − δ)` comes from a ray traced exactly through the shifted point (0 outside
/// the pupil or where that ray is vignetted); the diffraction limit is the weight of the
/// overlap. No pupil grid is binned and nothing aliases, at the cost of one trace of the pupil
/// per frequency and direction: the method of choice for a few frequencies (the tolerance
/// criterion), where [`fft_mtf`] gives a whole curve at once. The wavefront is referred to the
/// chief ray whatever `opts.reference` says (the MTF does not depend on it).
///
/// # Errors
/// As [`super::wavefront`]; [`crate::ErrorKind::Argument`] for no frequency or one not below
/// the cutoff.
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{mtf::direct_mtf, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let m = direct_mtf(&lens, &lens.compile(), Field::fraction(0.7), 587.5618,
///                    &WaveOptions::default(), &[0.0, 40.0])?;
/// assert_eq!(m.tangential[0], 1.0);
/// assert!(m.tangential[1] > 0.0 && m.tangential[1] <= m.diffraction_limit[1] + 1e-9);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn direct_mtf(
    lens: &crate::lens::Lens,
    sys: &crate::lens::System<f64>,
    field: crate::trace::Field,
    wavelength_nm: f64,
    opts: &super::WaveOptions,
    freqs: &[f64],
) -> Result<Mtf> {
    let opts = &super::WaveOptions {
        reference: super::Reference::Chief,
        ..*opts
    };
    let base = super::wavefront(lens, sys, field, wavelength_nm, opts)?;
    let map = direction_map(&base)?;
    let (t, s) = directions(&base);
    let cut = [cutoff_along(&base, &map, t), cutoff_along(&base, &map, s)];
    check_freqs(freqs, cut)?;
    let mut m = Mtf {
        freq_lpmm: freqs.to_vec(),
        tangential: Vec::with_capacity(freqs.len()),
        sagittal: Vec::with_capacity(freqs.len()),
        diffraction_limit: Vec::with_capacity(freqs.len()),
        diffraction_limit_sagittal: Vec::with_capacity(freqs.len()),
        cutoff_lpmm: cut,
    };
    for &f in freqs {
        let (a, b) = direct_otf(lens, sys, &base, &map, opts, f, t)?;
        m.tangential.push(a);
        m.diffraction_limit.push(b);
        let (a, b) = direct_otf(lens, sys, &base, &map, opts, f, s)?;
        m.sagittal.push(a);
        m.diffraction_limit_sagittal.push(b);
    }
    Ok(m)
}

/// The polychromatic diffraction MTF of one field at `freqs` (cycles/mm): the modulus of the
/// weighted sum of the wavelengths' OTFs ([`direct_mtf`]'s, over `opts.sampling`), each
/// shifted from its own chief ray's image point to the lens' primary wavelength's, so that
/// lateral colour lowers it as it blurs the polychromatic PSF; `wavelengths` are
/// `(nm, weight)` pairs, the weights normalised to sum 1. Tangential and sagittal are the
/// primary wavelength's directions; the diffraction limit is the weighted sum of the
/// wavelengths' own limits. A frequency beyond one wavelength's cutoff (but below the
/// shortest's) takes nothing from it.
///
/// # Errors
/// As [`direct_mtf`]; [`crate::ErrorKind::Argument`] for no wavelength, or a weight that is
/// negative, not finite, or all zero.
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{mtf::{direct_mtf, polychromatic_mtf}, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let (sys, f, o) = (lens.compile(), Field::fraction(0.7), WaveOptions::default());
/// let poly = polychromatic_mtf(&lens, &sys, f, &[(486.1327, 1.0), (587.5618, 1.0), (656.2725, 1.0)], &o, &[30.0])?;
/// let d = direct_mtf(&lens, &sys, f, 587.5618, &o, &[30.0])?;
/// assert!(poly.tangential[0] > 0.0 && poly.tangential[0] < 1.0);
/// # let _ = d;
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn polychromatic_mtf(
    lens: &crate::lens::Lens,
    sys: &crate::lens::System<f64>,
    field: crate::trace::Field,
    wavelengths: &[(f64, f64)],
    opts: &super::WaveOptions,
    freqs: &[f64],
) -> Result<Mtf> {
    if wavelengths.is_empty() {
        return Err(Error::argument(
            "a polychromatic MTF needs at least one wavelength",
        ));
    }
    if let Some((wl, w)) = wavelengths
        .iter()
        .find(|(_, w)| !(*w >= 0.0 && w.is_finite()))
    {
        return Err(Error::argument(format!(
            "wavelength {wl} nm: weight {w} must be finite and not negative"
        )));
    }
    let total: f64 = wavelengths.iter().map(|p| p.1).sum();
    if !(total > 0.0) {
        return Err(Error::argument("the wavelength weights are all zero"));
    }
    let opts = &super::WaveOptions {
        reference: super::Reference::Chief,
        ..*opts
    };
    let reference = super::wavefront(lens, sys, field, lens.primary_wavelength_nm, opts)?;
    let (t, s) = directions(&reference);
    let c0 = reference.centre_image_mm;
    let parts = wavelengths
        .iter()
        .map(|&(wl, w)| -> Result<_> {
            let base = super::wavefront(lens, sys, field, wl, opts)?;
            let map = direction_map(&base)?;
            Ok((w / total, base, map))
        })
        .collect::<Result<Vec<_>>>()?;
    // Refused only beyond the shortest wavelength's cutoff (the largest).
    let mut cut = [0.0f64; 2];
    for (_, b, map) in &parts {
        cut = [
            cut[0].max(cutoff_along(b, map, t)),
            cut[1].max(cutoff_along(b, map, s)),
        ];
    }
    check_freqs(freqs, cut)?;
    let mut m = Mtf {
        freq_lpmm: freqs.to_vec(),
        tangential: Vec::with_capacity(freqs.len()),
        sagittal: Vec::with_capacity(freqs.len()),
        diffraction_limit: Vec::with_capacity(freqs.len()),
        diffraction_limit_sagittal: Vec::with_capacity(freqs.len()),
        cutoff_lpmm: cut,
    };
    for &f in freqs {
        for (u, mtf, limit) in [
            (t, &mut m.tangential, &mut m.diffraction_limit),
            (s, &mut m.sagittal, &mut m.diffraction_limit_sagittal),
        ] {
            let (mut sum, mut lim) = (Complex::new(0.0, 0.0), 0.0);
            for (w, b, map) in &parts {
                let (o, l) = direct_otf_complex(lens, sys, b, map, opts, f, u)?;
                let d = [b.centre_image_mm[0] - c0[0], b.centre_image_mm[1] - c0[1]];
                let phase = std::f64::consts::TAU * f * (u[0] * d[0] + u[1] * d[1]);
                sum += o * Complex::from_polar(*w, phase);
                lim += w * l;
            }
            mtf.push(sum.norm());
            limit.push(lim);
        }
    }
    Ok(m)
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
