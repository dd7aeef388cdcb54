//! Diffraction PSFs: the FFT of the pupil function, and Huygens' direct sum of wavelets from
//! the reference sphere to each image point.
//!
//! Both are given relative to the peak of the unaberrated PSF of the same pupil (same
//! vignetting, zero OPD), so the peak of a PSF is its Strehl ratio; pixel (n/2, n/2) is the
//! reference sphere's centre (the chief ray's image point), row 0 the top (+y) of the image
//! plane.
//!
//! **FFT** ([`fft_psf`]): the OPD on an `S x S` grid over the entrance pupil is placed in an
//! `N x N` array (zero padded, `N >= 2S` so that the MTF computed from it does not wrap) and
//! transformed. The amplitude at image point `x` is `Σ_p exp(i 2π (W_p − L(p)·x / λ))` (a ray
//! leading the sphere by `W` is a path `W λ` short; moving `x` along a ray lengthens its path
//! by `L·x`), which the forward transform evaluates on a grid. The image-plane scale comes from the rays themselves: a least-squares affine
//! map from pupil coordinates to the rays' direction cosines (times the image-space index),
//! whose slopes `a_x`, `a_y` are the image-space numerical aperture per unit pupil coordinate;
//! the pixel is `λ / (N Δp |a|)` with `Δp = 2 / S`, i.e. `λ N_w / Q` with `Q = N / S` for a
//! pupil of working F-number `N_w`. Off axis the two slopes differ (the pupil seen from an
//! off-axis image point is narrower tangentially), so the pixels are rectangular. The FFT PSF
//! assumes, as OpticStudio's does, that the PSF is small against the exit pupil distance and
//! that the pupil's map to direction cosines is affine.
//!
//! **Huygens** ([`huygens_psf`]): `U(x) = Σ_p w_p exp(i k (n' |x − q_p| − W_p λ)) / |x − q_p|`
//! over the rays' points `q_p` on the reference sphere, for every image point `x` of an
//! `M x M` grid of any pitch on the image plane (tilted planes and wide fields included).

use super::Wavefront;
use crate::error::{Error, Result};
use crate::math::Vec3;
use crate::real::Real;
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use serde::Serialize;

/// A diffraction PSF on a grid of the image plane.
#[derive(Clone, Debug, Serialize)]
pub struct DiffractionPsf {
    /// Grid side, pixels.
    pub n: usize,
    /// Pixel pitch along x and y, µm.
    pub pitch_um: [f64; 2],
    /// Intensity relative to the unaberrated peak, row-major, row 0 at the top (+y).
    pub values: Vec<f64>,
    /// Strehl ratio: the PSF's peak (located between pixels) over the unaberrated peak.
    pub strehl: f64,
    /// Where pixel (n/2, n/2) lies in the image plane's frame (x, y), mm.
    pub centre_image_mm: [f64; 2],
}

/// Options of the FFT PSF.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct FftOptions {
    /// Pupil samples across the diameter, S.
    pub pupil_samples: usize,
    /// Side of the transformed array, N (at least 2 S).
    pub grid: usize,
}

impl Default for FftOptions {
    /// 64 pupil samples in a 256 array: pixels of λ N_w / 4.
    fn default() -> Self {
        FftOptions {
            pupil_samples: 64,
            grid: 256,
        }
    }
}

/// Largest FFT grid side (a 8192² complex array is 1 GiB).
pub const MAX_GRID: usize = 8192;

impl FftOptions {
    /// Checks the sizes.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for fewer than 4 pupil samples, a grid smaller than twice
    /// the pupil samples or larger than [`MAX_GRID`].
    pub fn check(&self) -> Result<()> {
        let (s, n) = (self.pupil_samples, self.grid);
        if s < 4 {
            return Err(Error::argument(format!(
                "{s} pupil samples: give at least 4"
            )));
        }
        if n < 2 * s {
            return Err(Error::argument(format!(
                "FFT grid {n} for {s} pupil samples: the grid must be at least twice the pupil \
                 samples ({}) so that the pupil's autocorrelation (the MTF) does not wrap",
                2 * s
            )));
        }
        if n > MAX_GRID {
            return Err(Error::argument(format!(
                "FFT grid {n}: at most {MAX_GRID} (a {MAX_GRID}² array takes 1 GiB)"
            )));
        }
        Ok(())
    }
}

/// The affine map from normalised pupil coordinates to the rays' image-space direction cosines
/// times the index: `[[L0, a_xx, a_xy], [M0, a_yx, a_yy]]`.
pub(crate) fn direction_map(w: &Wavefront) -> Result<[[f64; 3]; 2]> {
    let n = w.image_index;
    let fit = |k: usize| -> Result<[f64; 3]> {
        let v: Vec<f64> = w
            .directions
            .iter()
            .map(|d| n * if k == 0 { d.x } else { d.y })
            .collect();
        let f = super::zernike::fit(
            super::zernike::Ordering::Standard,
            3,
            &w.pupil,
            &v,
            &w.weight,
        )?;
        // Z2 = 2x, Z3 = 2y.
        Ok([
            f.coefficients[0],
            2.0 * f.coefficients[1],
            2.0 * f.coefficients[2],
        ])
    };
    let m = [fit(0)?, fit(1)?];
    if !(m[0][1].abs() > 0.0 && m[1][2].abs() > 0.0) {
        return Err(Error::numerical(
            "the rays leave the pupil with one direction: no converging beam to diffract",
        ));
    }
    Ok(m)
}

/// Cell index of a grid point of [`super::Sampling::Grid`]`(s)`.
fn cell(x: f64, s: usize) -> usize {
    (((x + 1.0) * 0.5 * s as f64).floor() as usize).min(s - 1)
}

/// The largest OPD difference (waves) between neighbouring samples of `w` on the `s x s` pupil
/// grid: above half a wave the sampled pupil function aliases and an FFT PSF or MTF computed
/// from it is wrong.
#[must_use]
pub fn opd_step_waves(w: &Wavefront, s: usize) -> f64 {
    opd_step(&w.pupil, &w.opd_waves, s)
}

/// [`opd_step_waves`] of the OPD `opd` (waves, any number type: its values) at the grid points
/// `pupil`.
fn opd_step<S: Real>(pupil: &[[f64; 2]], opd: &[S], s: usize) -> f64 {
    let mut g = vec![f64::NAN; s * s];
    for (p, &v) in pupil.iter().zip(opd) {
        g[cell(p[1], s) * s + cell(p[0], s)] = v.value();
    }
    let mut step: f64 = 0.0;
    for j in 0..s {
        for i in 0..s {
            let v = g[j * s + i];
            for (a, b) in [(i + 1, j), (i, j + 1)] {
                if a < s && b < s {
                    let u = g[b * s + a];
                    if v.is_finite() && u.is_finite() {
                        step = step.max((u - v).abs());
                    }
                }
            }
        }
    }
    step
}

/// The error of a pupil grid of `s` samples across on which the OPD steps by `step` waves.
fn undersampled(step: f64, s: usize) -> Error {
    let need = (s as f64 * step / 0.4).ceil() as usize;
    Error::numerical(format!(
        "pupil undersampled: the OPD changes by {step:.2} waves between neighbouring samples \
         of the {s} x {s} pupil grid (at most 0.5 without aliasing); use about {need} pupil \
         samples or more"
    ))
}

/// Refuses a wavefront not traced on the `s x s` pupil grid, or too steep for it
/// ([`opd_step_waves`] above half a wave),
/// saying how many samples would do.
pub(crate) fn check_sampling(w: &Wavefront, s: usize) -> Result<()> {
    check_grid_sampled(w, s)?;
    let step = opd_step_waves(w, s);
    if step > 0.5 {
        return Err(undersampled(step, s));
    }
    Ok(())
}

/// The FFT of the pupil function of `w` (traced with [`super::Sampling::Grid`] of
/// `opts.pupil_samples`): the complex amplitude, unshifted (index 0 is the chief ray's image
/// point), and the normalisation `(Σ A)²` of the unaberrated peak. With `aberrated` false the
/// OPD is set to zero (the diffraction limit of the same pupil).
pub(crate) fn pupil_transform(
    w: &Wavefront,
    opts: &FftOptions,
    aberrated: bool,
) -> (Vec<Complex<f64>>, f64) {
    let opd = aberrated.then_some(w.opd_waves.as_slice());
    let a = transform_of(&w.pupil, opd, opts.pupil_samples, opts.grid);
    let count = w.pupil.len() as f64;
    (
        a.into_iter().map(|[re, im]| Complex::new(re, im)).collect(),
        count * count,
    )
}

/// The FFT of the pupil function `exp(i 2π W)` of the OPD `opd` (waves; zero when `None`) at
/// the points `pupil` of the `s x s` grid, placed in the centre of an `n x n` array, as
/// `[re, im]`, in any number type: the transform is linear with constant coefficients, so each
/// of the number's components ([`Real::part`]: the value and each derivative) is transformed
/// by `rustfft` on its own.
fn transform_of<S: Real>(pupil: &[[f64; 2]], opd: Option<&[S]>, s: usize, n: usize) -> Vec<[S; 2]> {
    let off = (n - s) / 2;
    let at: Vec<usize> = pupil
        .iter()
        .map(|p| (cell(p[1], s) + off) * n + cell(p[0], s) + off)
        .collect();
    let values: Vec<[S; 2]> = match opd {
        Some(o) => o
            .iter()
            .map(|&w| {
                let ph = w * S::cst(std::f64::consts::TAU);
                [ph.cos(), ph.sin()]
            })
            .collect(),
        None => vec![[S::cst(1.0), S::cst(0.0)]; pupil.len()],
    };
    let parts: Vec<Vec<Complex<f64>>> = (0..S::PARTS)
        .map(|k| {
            let mut a = vec![Complex::new(0.0, 0.0); n * n];
            for (&i, v) in at.iter().zip(&values) {
                a[i] = Complex::new(v[0].part(k), v[1].part(k));
            }
            // Only the pupil's rows are not zero.
            crate::fft::fft2_rows(&mut a, n, n, off..off + s, false);
            a
        })
        .collect();
    let (mut re, mut im) = (vec![0.0; S::PARTS], vec![0.0; S::PARTS]);
    (0..n * n)
        .map(|m| {
            for (k, a) in parts.iter().enumerate() {
                re[k] = a[m].re;
                im[k] = a[m].im;
            }
            [S::from_parts(&re), S::from_parts(&im)]
        })
        .collect()
}

/// A wavefront on the `s x s` pupil grid in any number type: what an FFT PSF is made of.
#[derive(Clone, Debug)]
pub(crate) struct GridWave<S> {
    /// Normalised pupil points (cell centres of the grid) of the rays that got through.
    pub pupil: Vec<[f64; 2]>,
    /// Their OPD, waves.
    pub opd_waves: Vec<S>,
    /// The slopes `a_x`, `a_y` of the image-space direction cosines times the index over the
    /// pupil ([`direction_map`]'s `[0][1]` and `[1][2]`).
    pub slopes: [S; 2],
}

/// The FFT PSF intensity of `w` on an `n x n` grid (relative to the unaberrated peak, laid out
/// as [`fft_psf`]'s values) and its pixel pitch (mm) along x and y.
fn intensity_of<S: Real>(
    w: &GridWave<S>,
    s: usize,
    n: usize,
    wavelength_nm: f64,
) -> (Vec<S>, [S; 2]) {
    let (ax, ay) = (w.slopes[0], w.slopes[1]);
    let k = S::cst(wavelength_nm * 1e-6 / (n as f64 * 2.0 / s as f64));
    let pitch = [k / ax.abs(), k / ay.abs()];
    let a = transform_of(&w.pupil, Some(&w.opd_waves), s, n);
    let count = w.pupil.len() as f64;
    let inv = S::cst(1.0 / (count * count));
    let half = (n / 2) as isize;
    let wrap = |k: isize| k.rem_euclid(n as isize) as usize;
    let (sx, sy) = (ax.value().signum() as isize, ay.value().signum() as isize);
    let mut values = Vec::with_capacity(n * n);
    for r in 0..n {
        // Image y = (n/2 - r) pitch; frequency index k_y = sign(a_y) (n/2 - r).
        let ky = wrap(sy * (half - r as isize));
        for c in 0..n {
            let kx = wrap(sx * (c as isize - half));
            let [re, im] = a[ky * n + kx];
            values.push((re * re + im * im) * inv);
        }
    }
    (values, pitch)
}

/// The FFT PSF's grid before its peak is refined: [`fft_psf`]'s values, pixel pitch (mm),
/// the slopes of the rays' direction cosines over the pupil and the unaberrated peak.
struct FftGrid {
    n: usize,
    values: Vec<f64>,
    pitch_mm: [f64; 2],
    slopes: [f64; 2],
    ideal: f64,
}

fn fft_intensity(w: &Wavefront, opts: &FftOptions) -> Result<FftGrid> {
    opts.check()?;
    check_sampling(w, opts.pupil_samples)?;
    let (s, n) = (opts.pupil_samples, opts.grid);
    let map = direction_map(w)?;
    let g = GridWave {
        pupil: w.pupil.clone(),
        opd_waves: w.opd_waves.clone(),
        slopes: [map[0][1], map[1][2]],
    };
    let (values, pitch_mm) = intensity_of(&g, s, n, w.wavelength_nm);
    let count = w.pupil.len() as f64;
    Ok(FftGrid {
        n,
        values,
        pitch_mm,
        slopes: g.slopes,
        ideal: count * count,
    })
}

/// The FFT PSF of a wavefront traced with [`super::Sampling::Grid`]`(opts.pupil_samples)`.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for sizes [`FftOptions::check`] refuses or a wavefront not
/// sampled on that grid; [`crate::ErrorKind::Numerical`] for a beam that does not converge or
/// a pupil grid too coarse for the wavefront (an OPD step over half a wave between
/// neighbouring samples, which aliases: the message says how many samples would do).
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{psf::{fft_psf, FftOptions}, wavefront, Sampling, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let o = FftOptions { pupil_samples: 32, grid: 64 };
/// let opts = WaveOptions { sampling: Sampling::Grid(32), ..WaveOptions::default() };
/// let w = wavefront(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, &opts)?;
/// let p = fft_psf(&w, &o)?;
/// assert!(p.strehl > 0.0 && p.strehl <= 1.0 + 1e-9);
/// // lens2 carries 20 waves of defocus at its sensor: 32 samples alias, and are refused.
/// let lens2 = Lens::load("lens2")?;
/// let w2 = wavefront(&lens2, &lens2.compile(), Field::fraction(0.0), 587.5618, &opts)?;
/// assert!(fft_psf(&w2, &o).unwrap_err().message().contains("undersampled"));
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn fft_psf(w: &Wavefront, opts: &FftOptions) -> Result<DiffractionPsf> {
    let g = fft_intensity(w, opts)?;
    let (n, values, pitch, ideal) = (g.n, g.values, g.pitch_mm, g.ideal);
    let (ax, ay) = (g.slopes[0], g.slopes[1]);
    let lambda_mm = w.wavelength_nm * 1e-6;
    let half = (n / 2) as isize;
    // The peak between pixels: the continuous PSF by direct summation, refined from the
    // brightest pixel.
    let amp = |x: f64, y: f64| -> f64 {
        let mut sum = Complex::new(0.0, 0.0);
        for (p, &opd) in w.pupil.iter().zip(&w.opd_waves) {
            let ph = std::f64::consts::TAU * (opd - (ax * p[0] * x + ay * p[1] * y) / lambda_mm);
            sum += Complex::from_polar(1.0, ph);
        }
        sum.norm_sqr() / ideal
    };
    let (kmax, _) =
        values.iter().enumerate().fold(
            (0, f64::NEG_INFINITY),
            |b, (k, &v)| if v > b.1 { (k, v) } else { b },
        );
    let x0 = ((kmax % n) as f64 - half as f64) * pitch[0];
    let y0 = (half as f64 - (kmax / n) as f64) * pitch[1];
    let strehl = refine_peak(&amp, x0, y0, pitch).min(1.0);
    Ok(DiffractionPsf {
        n,
        pitch_um: [pitch[0] * 1e3, pitch[1] * 1e3],
        values,
        strehl,
        centre_image_mm: w.centre_image_mm,
    })
}

/// The Strehl ratio of `w` by direct summation over its rays, any sampling: the peak over image
/// points `x` (near the chief ray's image point) of `|Σ_p w_p exp(i 2π (W_p − n d_p·x / λ))|²`,
/// `w_p` the sampling's weights normalised over the rays that got through (so the same pupil
/// without aberration gives 1), `d_p` each ray's direction. The peak is searched on a 5 x 5
/// grid around the spot's centroid, then refined by Newton steps on the analytic gradient and
/// Hessian. With the default quadrature it is the accurate, cheap Strehl the tolerance
/// criterion uses; [`fft_psf`]'s Strehl is the same peak found from the FFT's brightest pixel.
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{psf::strehl, wavefront, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let w = wavefront(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, &WaveOptions::default())?;
/// let s = strehl(&w);
/// assert!(s > 0.0 && s <= 1.0);
/// // Maréchal's estimate is close for a good wavefront.
/// let m = w.stats(3)?.strehl_marechal;
/// assert!((s - m).abs() < 0.05);
/// # Ok::<(), tolray::Error>(())
/// ```
#[must_use]
pub fn strehl(w: &Wavefront) -> f64 {
    let k = std::f64::consts::TAU / (w.wavelength_nm * 1e-6);
    let n = w.image_index;
    // |A|², its gradient and Hessian at image point (x, y) relative to the sphere's centre.
    let eval = |x: f64, y: f64| -> (f64, [f64; 2], [[f64; 2]; 2]) {
        let mut a = Complex::new(0.0, 0.0);
        let mut da = [Complex::new(0.0, 0.0); 2];
        let mut dda = [[Complex::new(0.0, 0.0); 2]; 2];
        for ((d, &opd), &wt) in w.directions.iter().zip(&w.opd_waves).zip(&w.weight) {
            let (lx, ly) = (n * d.x * k, n * d.y * k);
            let e = Complex::from_polar(wt, std::f64::consts::TAU * opd - lx * x - ly * y);
            let l = [lx, ly];
            a += e;
            for i in 0..2 {
                da[i] += e * Complex::new(0.0, -l[i]);
                for j in 0..2 {
                    dda[i][j] -= e * (l[i] * l[j]);
                }
            }
        }
        let g = [2.0 * (a.conj() * da[0]).re, 2.0 * (a.conj() * da[1]).re];
        let mut h = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                h[i][j] = 2.0 * (da[i].conj() * da[j] + a.conj() * dda[i][j]).re;
            }
        }
        (a.norm_sqr(), g, h)
    };
    // The scale of the PSF: λ over the spread of the rays' direction cosines.
    let (mut mx, mut my, mut m2) = (0.0, 0.0, 0.0);
    for (d, &wt) in w.directions.iter().zip(&w.weight) {
        mx += wt * d.x;
        my += wt * d.y;
        m2 += wt * (d.x * d.x + d.y * d.y);
    }
    let spread = n * (m2 - mx * mx - my * my).max(1e-18).sqrt();
    let h = (0.25 * std::f64::consts::TAU / (k * spread)).min(1e3);
    let c = w.centre_image_mm;
    let (cx, cy) = w
        .image_points
        .iter()
        .zip(&w.weight)
        .fold((0.0, 0.0), |(sx, sy), (p, &wt)| {
            (sx + wt * (p[0] - c[0]), sy + wt * (p[1] - c[1]))
        });
    let (mut x, mut y, mut best) = (0.0, 0.0, eval(0.0, 0.0).0);
    for j in -2..=2 {
        for i in -2..=2 {
            let (px, py) = (cx + f64::from(i) * h, cy + f64::from(j) * h);
            let v = eval(px, py).0;
            if v > best {
                (x, y, best) = (px, py, v);
            }
        }
    }
    let mut step = h;
    for _ in 0..12 {
        let (v, g, hm) = eval(x, y);
        best = best.max(v);
        let det = hm[0][0] * hm[1][1] - hm[0][1] * hm[1][0];
        // Newton on a concave patch, else a gradient step of length `step`.
        let (mut dx, mut dy) = if hm[0][0] < 0.0 && det > 0.0 {
            (
                -(hm[1][1] * g[0] - hm[0][1] * g[1]) / det,
                -(hm[0][0] * g[1] - hm[1][0] * g[0]) / det,
            )
        } else {
            let gn = g[0].hypot(g[1]).max(1e-300);
            (step * g[0] / gn, step * g[1] / gn)
        };
        let len = dx.hypot(dy);
        if len > step {
            (dx, dy) = (dx * step / len, dy * step / len);
        }
        let v2 = eval(x + dx, y + dy).0;
        if v2 >= v {
            (x, y) = (x + dx, y + dy);
            best = best.max(v2);
            if dx.hypot(dy) < 1e-7 * h {
                break;
            }
        } else {
            step *= 0.5;
        }
    }
    best.min(1.0)
}

/// The maximum of `f` near (x0, y0) by coordinate-wise parabolic steps on a shrinking scale.
fn refine_peak(f: &dyn Fn(f64, f64) -> f64, x0: f64, y0: f64, pitch: [f64; 2]) -> f64 {
    let (mut x, mut y) = (x0, y0);
    let mut best = f(x, y);
    let mut h = [pitch[0], pitch[1]];
    for _ in 0..30 {
        for axis in 0..2 {
            let at = |t: f64| if axis == 0 { f(x + t, y) } else { f(x, y + t) };
            let (fm, fp) = (at(-h[axis]), at(h[axis]));
            let curv = fm - 2.0 * best + fp;
            let mut t = if curv < 0.0 {
                0.5 * h[axis] * (fm - fp) / curv
            } else if fp > fm {
                h[axis]
            } else {
                -h[axis]
            };
            t = t.clamp(-h[axis], h[axis]);
            let v = at(t);
            if v > best {
                best = v;
                if axis == 0 {
                    x += t;
                } else {
                    y += t;
                }
            }
        }
        h = [h[0] * 0.5, h[1] * 0.5];
    }
    best
}

/// Checks that `w` was traced on [`super::Sampling::Grid`]`(s)`: every pupil point is a cell
/// centre of that grid.
fn check_grid_sampled(w: &Wavefront, s: usize) -> Result<()> {
    let ok = w.pupil.iter().all(|p| {
        p.iter().all(|&x| {
            let c = cell(x, s) as f64;
            ((2.0 * c + 1.0) / s as f64 - 1.0 - x).abs() < 1e-9
        })
    });
    if ok {
        Ok(())
    } else {
        Err(Error::argument(format!(
            "an FFT PSF or MTF needs a wavefront traced on the {s} x {s} pupil grid \
             (Sampling::Grid({s})), the FFT's own sampling"
        )))
    }
}

/// Options of the Huygens PSF.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HuygensOptions {
    /// Image points per side, M.
    pub image_samples: usize,
    /// Pixel pitch, µm.
    pub pitch_um: f64,
}

/// Most image points per side of a Huygens PSF.
pub const MAX_HUYGENS_SIDE: usize = 2048;

/// The Huygens PSF of `w` on an `M x M` grid of the image plane centred on the reference
/// sphere's centre. Cost: rays x M² complex exponentials, in parallel over rows.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for no image point, more than [`MAX_HUYGENS_SIDE`] per side,
/// or a pitch that is not positive and finite.
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{psf::{huygens_psf, HuygensOptions}, wavefront, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("lens2")?;
/// let w = wavefront(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, &WaveOptions::default())?;
/// let p = huygens_psf(&w, &HuygensOptions { image_samples: 16, pitch_um: 1.0 })?;
/// assert_eq!(p.values.len(), 256);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn huygens_psf(w: &Wavefront, opts: &HuygensOptions) -> Result<DiffractionPsf> {
    huygens_on_grid(&[(w, 1.0)], opts, w.centre_image_mm)
}

/// The polychromatic Huygens PSF of one field: the weighted sum of the wavelengths' PSFs
/// (`waves` are `(wavefront, weight)` pairs of one lens, field and image plane; the weights
/// are normalised to sum 1), each relative to its own unaberrated peak, on one `M x M` grid
/// centred on the first wavefront's reference point (the primary wavelength's chief ray, when
/// it comes first), so that lateral colour spreads it. Its Strehl ratio is its peak: 1 for a
/// lens free of every aberration and of colour.
///
/// # Errors
/// As [`huygens_psf`]; [`crate::ErrorKind::Argument`] for no wavelength, or a weight that is
/// negative, not finite, or all zero.
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{psf::{huygens_psf, polychromatic_huygens_psf, HuygensOptions}, wavefront, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let (sys, f, o) = (lens.compile(), Field::fraction(0.0), WaveOptions::default());
/// let d = wavefront(&lens, &sys, f, 587.5618, &o)?;
/// let c = wavefront(&lens, &sys, f, 656.2725, &o)?;
/// let h = HuygensOptions { image_samples: 32, pitch_um: 1.0 };
/// let poly = polychromatic_huygens_psf(&[(&d, 1.0), (&c, 1.0)], &h)?;
/// // On axis both grids are centred on the axis: the mean of the two PSFs.
/// let (pd, pc) = (huygens_psf(&d, &h)?, huygens_psf(&c, &h)?);
/// for k in [0, 100, 16 * 32 + 16] {
///     assert!((poly.values[k] - 0.5 * (pd.values[k] + pc.values[k])).abs() < 1e-12);
/// }
/// assert!(poly.strehl > 0.0 && poly.strehl <= 0.5 * (pd.strehl + pc.strehl) + 1e-12);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn polychromatic_huygens_psf(
    waves: &[(&Wavefront, f64)],
    opts: &HuygensOptions,
) -> Result<DiffractionPsf> {
    let Some((first, _)) = waves.first() else {
        return Err(Error::argument(
            "a polychromatic PSF needs at least one wavelength",
        ));
    };
    huygens_on_grid(waves, opts, first.centre_image_mm)
}

/// The weighted sum of the Huygens PSFs of `waves` on the grid of `opts` centred on `c` (the
/// image plane's frame, mm), each relative to its own unaberrated peak.
fn huygens_on_grid(
    waves: &[(&Wavefront, f64)],
    opts: &HuygensOptions,
    c: [f64; 2],
) -> Result<DiffractionPsf> {
    let m = opts.image_samples;
    if m == 0 || m > MAX_HUYGENS_SIDE {
        return Err(Error::argument(format!(
            "{m} Huygens image points per side: give 1 to {MAX_HUYGENS_SIDE}"
        )));
    }
    if !(opts.pitch_um > 0.0 && opts.pitch_um.is_finite()) {
        return Err(Error::argument(format!(
            "Huygens pixel pitch {} µm: give a positive number",
            opts.pitch_um
        )));
    }
    if let Some(b) = waves.iter().find(|(_, v)| !(*v >= 0.0 && v.is_finite())) {
        return Err(Error::argument(format!(
            "wavelength weight {}: weights must be zero or positive, and finite",
            b.1
        )));
    }
    let total: f64 = waves.iter().map(|(_, v)| v).sum();
    if !(total > 0.0) {
        return Err(Error::argument(
            "every wavelength weight is zero: give at least one positive weight",
        ));
    }
    let image = waves[0].0.image;
    // One wavelength's field at a point, and its unaberrated peak.
    let field = |w: &Wavefront, x: Vec3<f64>, aberrated: bool| -> Complex<f64> {
        let k = std::f64::consts::TAU / (w.wavelength_nm * 1e-6);
        let mut sum = Complex::new(0.0, 0.0);
        for ((q, &opd), &wt) in w.sphere_points.iter().zip(&w.opd_waves).zip(&w.weight) {
            let d = (x - *q).norm();
            let lag = if aberrated {
                opd * std::f64::consts::TAU
            } else {
                0.0
            };
            sum += Complex::from_polar(wt / d, k * w.image_index * d - lag);
        }
        sum
    };
    // Each wavelength's unaberrated peak and share.
    let parts: Vec<(&Wavefront, f64, f64)> = waves
        .iter()
        .filter(|(_, v)| *v > 0.0)
        .map(|&(w, v)| {
            let centre = Vec3::cst(w.centre_mm[0], w.centre_mm[1], w.centre_mm[2]);
            (w, field(w, centre, false).norm_sqr(), v / total)
        })
        .collect();
    let intensity = |x: Vec3<f64>| -> f64 {
        parts
            .iter()
            .map(|&(w, ideal, share)| field(w, x, true).norm_sqr() / ideal * share)
            .sum()
    };
    let pitch = opts.pitch_um * 1e-3;
    let half = (m / 2) as f64;
    let local = |x: f64, y: f64| image.point_to_global(Vec3::cst(c[0] + x, c[1] + y, 0.0));
    let values: Vec<f64> = (0..m)
        .into_par_iter()
        .flat_map_iter(|r| (0..m).map(move |col| (r, col)))
        .map(|(r, col)| {
            intensity(local(
                (col as f64 - half) * pitch,
                (half - r as f64) * pitch,
            ))
        })
        .collect();
    let (kmax, _) =
        values.iter().enumerate().fold(
            (0, f64::NEG_INFINITY),
            |b, (i, &v)| if v > b.1 { (i, v) } else { b },
        );
    let f = |x: f64, y: f64| intensity(local(x, y));
    let x0 = ((kmax % m) as f64 - half) * pitch;
    let y0 = (half - (kmax / m) as f64) * pitch;
    let strehl = refine_peak(&f, x0, y0, [pitch, pitch]).min(1.0);
    Ok(DiffractionPsf {
        n: m,
        pitch_um: [opts.pitch_um; 2],
        values,
        strehl,
        centre_image_mm: c,
    })
}

/// The diffraction PSF of `w` (traced on the [`super::Sampling::Grid`]`(opts.pupil_samples)`
/// pupil grid) laid out as [`crate::psf`] lays out a geometric PSF, for image simulation: `ks x
/// ks` sensor pixels of `pitch_mm`, row 0 at the top, the reference sphere's centre (the chief
/// ray's image point for [`super::Reference::Chief`]) in pixel `(ks/2, ks/2)`, each FFT sample
/// deposited bilinearly on the pixel centres as a geometric PSF deposits a ray, unit sum over
/// what lands in the window. The FFT's pixels should be finer than the sensor's (a grid of
/// more than twice the pupil samples makes them so) and its image should cover the window.
///
/// # Errors
/// As [`fft_psf`]; [`crate::ErrorKind::Argument`] for an even `ks` or one below 3, or a pitch
/// that is not positive and finite; [`crate::ErrorKind::Numerical`] when no energy lands in
/// the window.
///
/// # Examples
/// ```
/// use tolray::trace::Field;
/// use tolray::wave::{psf::{pixel_psf, FftOptions}, wavefront, Sampling, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let o = WaveOptions { sampling: Sampling::Grid(64), ..WaveOptions::default() };
/// let w = wavefront(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, &o)?;
/// let p = pixel_psf(&w, &FftOptions { pupil_samples: 64, grid: 128 }, 21, 0.004)?;
/// assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
/// // On axis the PSF (a ring here: the triplet is far from diffraction-limited at its
/// // paraxial focus) is centred: its mirror images match pixel for pixel.
/// for i in 0..21 * 21 {
///     let (r, c) = (i / 21, i % 21);
///     assert!((p[i] - p[r * 21 + 20 - c]).abs() < 1e-9);
///     assert!((p[i] - p[(20 - r) * 21 + c]).abs() < 1e-9);
/// }
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn pixel_psf(w: &Wavefront, opts: &FftOptions, ks: usize, pitch_mm: f64) -> Result<Vec<f64>> {
    check_window(ks, pitch_mm)?;
    let g = fft_intensity(w, opts)?;
    deposit(&g, ks, pitch_mm).ok_or_else(|| {
        Error::numerical(format!(
            "the diffraction PSF at {} nm puts no energy in its {ks} x {ks} window",
            w.wavelength_nm
        ))
    })
}

/// Checks a sensor window: `ks` odd, 3 to 255 pixels (as a geometric PSF's), of a positive,
/// finite pitch up to 10 mm.
pub(crate) fn check_window(ks: usize, pitch_mm: f64) -> Result<()> {
    if ks < 3 || ks.is_multiple_of(2) || ks > 255 {
        return Err(Error::argument(format!(
            "PSF window of {ks} pixels: give an odd number from 3 to 255"
        )));
    }
    if !(pitch_mm > 0.0 && pitch_mm <= 10.0) {
        return Err(Error::argument(format!(
            "pixel pitch {pitch_mm} mm: give a positive pitch up to 10 mm"
        )));
    }
    Ok(())
}

/// The FFT grid `g` deposited bilinearly on a `ks x ks` window of `pitch_mm` pixels centred on
/// the grid's centre, unit sum; `None` when nothing lands.
fn deposit(g: &FftGrid, ks: usize, pitch_mm: f64) -> Option<Vec<f64>> {
    deposit_of(&g.values, g.n, g.pitch_mm, ks, pitch_mm)
}

/// [`deposit`] of the `n x n` intensities `values` of pixel pitch `grid_pitch_mm`, in any number
/// type: which pixels a sample lands between is decided on the values, its bilinear weights
/// and the unit sum move with the pitch and the intensities.
fn deposit_of<S: Real>(
    values: &[S],
    n: usize,
    grid_pitch_mm: [S; 2],
    ks: usize,
    pitch_mm: f64,
) -> Option<Vec<S>> {
    let (half_g, half_k) = ((n / 2) as f64, (ks / 2) as f64);
    let last = (ks - 1) as f64;
    let scale = [
        grid_pitch_mm[0] * S::cst(1.0 / pitch_mm),
        grid_pitch_mm[1] * S::cst(1.0 / pitch_mm),
    ];
    // Each column's pixel and weight toward the next.
    let cols: Vec<Option<(usize, S)>> = (0..n)
        .map(|c| {
            let u = S::cst(c as f64 - half_g) * scale[0] + S::cst(half_k);
            let uv = u.value();
            (uv >= 0.0 && uv < last).then(|| (uv.floor() as usize, u - S::cst(uv.floor())))
        })
        .collect();
    let mut img = vec![S::cst(0.0); ks * ks];
    let mut total = S::cst(0.0);
    let one = S::cst(1.0);
    for r in 0..n {
        let v = S::cst(half_k) - S::cst(half_g - r as f64) * scale[1];
        let vv = v.value();
        if !(vv >= 0.0 && vv < last) {
            continue;
        }
        let (j, fy) = (vv.floor() as usize, v - S::cst(vv.floor()));
        for (c, col) in cols.iter().enumerate() {
            let e = values[r * n + c];
            let Some((i, fx)) = *col else { continue };
            if e.value() == 0.0 {
                continue;
            }
            let (ey, ey1) = (e * (one - fy), e * fy);
            img[j * ks + i] += ey * (one - fx);
            img[j * ks + i + 1] += ey * fx;
            img[(j + 1) * ks + i] += ey1 * (one - fx);
            img[(j + 1) * ks + i + 1] += ey1 * fx;
            total += e;
        }
    }
    if !(total.value() > 0.0) {
        return None;
    }
    let inv = one / total;
    for x in &mut img {
        *x *= inv;
    }
    Some(img)
}

/// The pupil samples [`diffraction_psf_map`] starts from, and the most it takes.
const MAP_SAMPLES: (usize, usize) = (64, 1024);

/// A diffraction PSF map in the layout of [`crate::psf::psf_map`] (the `grid x grid` fields of
/// [`crate::psf::grid_fields`], each a [`pixel_psf`] of `ks x ks` pixels of `pitch_mm`) for
/// `sys` (a compiled, possibly perturbed form of `lens`) at `wavelength_nm`. Each field's pupil
/// grid starts at 64 samples across and doubles (up to 1024) until the FFT's image extent, λ N
/// times the samples, covers 1.2 times the window and the wavefront is not undersampled; the
/// FFT grid is twice the pupil samples, or more until its pixels are at most half the sensor's.
///
/// # Errors
/// As [`diffraction_psf_tiles`], the first failing field's.
///
/// # Examples
/// ```
/// use tolray::wave::psf::diffraction_psf_map;
/// use tolray::Lens;
/// let lens = Lens::load("lens1")?;
/// let map = diffraction_psf_map(&lens, &lens.compile(), 2, 587.5618, 15, 0.0036)?;
/// assert_eq!(map.len(), 4);
/// assert!(map.iter().all(|p| p.len() == 225 && (p.iter().sum::<f64>() - 1.0).abs() < 1e-9));
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn diffraction_psf_map(
    lens: &crate::lens::Lens,
    sys: &crate::lens::System<f64>,
    grid: usize,
    wavelength_nm: f64,
    ks: usize,
    pitch_mm: f64,
) -> Result<Vec<Vec<f64>>> {
    diffraction_psf_tiles(lens, sys, grid, wavelength_nm, ks, pitch_mm)?
        .into_iter()
        .collect()
}

/// [`diffraction_psf_map`] field by field: each field's PSF or why it has none (its chief ray
/// lost, fewer than three rays through, a wavefront still undersampled or an FFT image smaller
/// than the window at 1024 pupil samples), so that a caller can stand in for one field.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for a window [`pixel_psf`] refuses.
pub fn diffraction_psf_tiles(
    lens: &crate::lens::Lens,
    sys: &crate::lens::System<f64>,
    grid: usize,
    wavelength_nm: f64,
    ks: usize,
    pitch_mm: f64,
) -> Result<Vec<Result<Vec<f64>>>> {
    check_window(ks, pitch_mm)?;
    Ok(crate::psf::grid_fields(lens, grid)
        .par_iter()
        .map(|&field| {
            let mut wave_at = |s: usize| -> Result<GridWave<f64>> {
                let o = super::WaveOptions {
                    sampling: super::Sampling::Grid(s),
                    ..super::WaveOptions::default()
                };
                let w = super::wavefront(lens, sys, field, wavelength_nm, &o)?;
                check_grid_sampled(&w, s)?;
                let map = direction_map(&w)?;
                Ok(GridWave {
                    pupil: w.pupil,
                    opd_waves: w.opd_waves,
                    slopes: [map[0][1], map[1][2]],
                })
            };
            sampled_pixel_psf(&mut wave_at, wavelength_nm, ks, pitch_mm).map_err(|e| {
                e.context(format!(
                    "diffraction PSF of field {} at {wavelength_nm} nm",
                    field.label()
                ))
            })
        })
        .collect())
}

/// The pixel PSF of [`diffraction_psf_map`]'s sampling rule, in any number type, from the
/// wavefront `wave_at(s)` traced on an `s x s` pupil grid: `s` starts at 64 and doubles (up to
/// 1024) until the wavefront is not undersampled and the FFT's image (`λ / (Δp |a|)` across)
/// covers 1.2 times the window; the FFT grid is `2 s`, doubled until its pixels are at most
/// half the sensor's (or [`MAX_GRID`]); then [`deposit_of`]. Every choice is made on values, so
/// that dual numbers follow the value's path and carry its exact derivative.
///
/// # Errors
/// `wave_at`'s; [`crate::ErrorKind::Numerical`] for a wavefront still undersampled or an FFT
/// image smaller than the window at 1024 samples, or no energy in the window.
pub(crate) fn sampled_pixel_psf<S: Real>(
    wave_at: &mut dyn FnMut(usize) -> Result<GridWave<S>>,
    wavelength_nm: f64,
    ks: usize,
    pitch_mm: f64,
) -> Result<Vec<S>> {
    check_window(ks, pitch_mm)?;
    let window = ks as f64 * pitch_mm;
    let mut s = MAP_SAMPLES.0;
    loop {
        let w = wave_at(s)?;
        let more = s < MAP_SAMPLES.1;
        let step = opd_step(&w.pupil, &w.opd_waves, s);
        if step > 0.5 {
            if more {
                s *= 2;
                continue;
            }
            return Err(undersampled(step, s));
        }
        let [ax, ay] = w.slopes.map(|a| a.value().abs());
        if !(ax > 0.0 && ay > 0.0) {
            return Err(Error::numerical(
                "the rays leave the pupil with one direction: no converging beam to diffract",
            ));
        }
        // The FFT image spans n pitch = λ / (Δp |a|), whatever the grid n.
        let span = |a: f64| wavelength_nm * 1e-6 * s as f64 / (2.0 * a);
        let extent = span(ax).min(span(ay));
        if extent < 1.2 * window {
            if more {
                s *= 2;
                continue;
            }
            return Err(Error::numerical(format!(
                "the FFT image of {s} pupil samples spans {extent:.3} mm, less than the \
                 {window:.3} mm window"
            )));
        }
        // Finer FFT pixels (a larger grid, the same pupil) until they are at most half the
        // sensor's.
        let mut n = 2 * s;
        while span(ax.min(ay)) / n as f64 > 0.5 * pitch_mm && n * 2 <= MAX_GRID {
            n *= 2;
        }
        let (values, grid_pitch) = intensity_of(&w, s, n, wavelength_nm);
        return deposit_of(&values, n, grid_pitch, ks, pitch_mm)
            .ok_or_else(|| Error::numerical(format!("no energy lands in the {ks} x {ks} window")));
    }
}

/// The fraction of a PSF's energy on its grid within each radius (µm) of pixel (n/2, n/2)
/// (the chief ray's image point): encircled energy, pixels counted by their centres.
#[must_use]
pub fn encircled_energy(psf: &DiffractionPsf, radii_um: &[f64]) -> Vec<f64> {
    let n = psf.n;
    let half = (n / 2) as f64;
    let total: f64 = psf.values.iter().sum();
    radii_um
        .iter()
        .map(|&r| {
            let mut s = 0.0;
            for j in 0..n {
                for i in 0..n {
                    let x = (i as f64 - half) * psf.pitch_um[0];
                    let y = (half - j as f64) * psf.pitch_um[1];
                    if x.hypot(y) <= r {
                        s += psf.values[j * n + i];
                    }
                }
            }
            if total > 0.0 {
                s / total
            } else {
                0.0
            }
        })
        .collect()
}
