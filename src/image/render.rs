//! Image formation: spatially variant convolution by a PSF map, its adjoint with respect to the
//! PSF, and sensor noise.
//!
//! Convention: `y[c][r][q] = Σ_{j,i} psf[c][j][i] · x[c][r − (j − h)][q − (i − h)]`, `h = ks / 2`
//! (a point source at pixel p spreads to p + (i − h, j − h) with weight `psf[j][i]`; PSF row 0 is
//! +y on the sensor, as the image's row 0). The image is cut into `grid x grid` tiles (tile row
//! `i` spans rows `i·H/grid .. (i+1)·H/grid`); each tile is convolved with its own PSF over its
//! pixels plus a halo of `h` pixels from the whole image, reflect-padded at the border, so there
//! are no seams inside the image and PSFs change at tile edges (as DeepLens and the paper).
//! Each tile is one FFT convolution of size the smallest 2^a 3^b 5^c covering tile + halo.

use super::Image;
use crate::error::{Error, Result};
use crate::fft::{fast_size, fft2};
use rand::SeedableRng;
use rayon::prelude::*;
use rustfft::num_complex::Complex;

/// RGB PSFs on a `grid x grid` field grid: tile `t = row · grid + col` (row 0 at the top), each
/// `3 · ks · ks` values, channel-major, unit sum per channel.
#[derive(Clone, Debug, PartialEq)]
pub struct PsfMap {
    /// Fields per side.
    pub grid: usize,
    /// Kernel size, pixels (odd).
    pub ks: usize,
    /// `grid² · 3 · ks²` values.
    pub psfs: Vec<f32>,
}

impl PsfMap {
    /// A map from its values.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for an even kernel, an empty grid or a wrong length.
    pub fn new(grid: usize, ks: usize, psfs: Vec<f32>) -> Result<PsfMap> {
        if grid == 0 || ks.is_multiple_of(2) || psfs.len() != grid * grid * 3 * ks * ks {
            return Err(Error::argument(format!(
                "PSF map: {} values for a {grid}x{grid} grid of {ks}x{ks} RGB kernels (odd size)",
                psfs.len()
            )));
        }
        Ok(PsfMap { grid, ks, psfs })
    }

    /// The RGB PSF of tile `t`.
    pub fn psf(&self, t: usize) -> &[f32] {
        let n = 3 * self.ks * self.ks;
        &self.psfs[t * n..(t + 1) * n]
    }
}

/// Places a `w x h` real array at the origin of a zeroed `nx x ny` complex array.
fn embed(src: &[f32], w: usize, h: usize, nx: usize, ny: usize) -> Vec<Complex<f32>> {
    let mut a = vec![Complex::default(); nx * ny];
    for y in 0..h {
        for x in 0..w {
            a[y * nx + x] = Complex::new(src[y * w + x], 0.0);
        }
    }
    a
}

fn check_patch(xpad: &[f32], w: usize, h: usize, ks: usize) -> Result<(usize, usize)> {
    let (pw, ph) = (w + ks - 1, h + ks - 1);
    if ks.is_multiple_of(2) || w == 0 || h == 0 || xpad.len() != 3 * pw * ph {
        return Err(Error::argument(format!(
            "patch: {} values for a {pw}x{ph} RGB image with halo (output {w}x{h}, odd kernel {ks})",
            xpad.len()
        )));
    }
    Ok((pw, ph))
}

/// The blur of one patch by one RGB PSF: `xpad` is a 3-plane image of `(w + ks − 1) x
/// (h + ks − 1)` pixels (the patch and its halo), the result the `3 · w · h` pixels of the
/// patch ('valid' convolution, by FFT).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for sizes that do not match.
pub fn blur_patch(xpad: &[f32], w: usize, h: usize, psf: &[f32], ks: usize) -> Result<Vec<f32>> {
    let (pw, ph) = check_patch(xpad, w, h, ks)?;
    if psf.len() != 3 * ks * ks {
        return Err(Error::argument(format!(
            "PSF: {} values for 3 x {ks}x{ks}",
            psf.len()
        )));
    }
    let (nx, ny) = (fast_size(pw), fast_size(ph));
    let scale = 1.0 / (nx * ny) as f32;
    let mut out = vec![0f32; 3 * w * h];
    for c in 0..3 {
        let mut a = embed(&xpad[c * pw * ph..(c + 1) * pw * ph], pw, ph, nx, ny);
        let mut k = embed(&psf[c * ks * ks..(c + 1) * ks * ks], ks, ks, nx, ny);
        fft2(&mut a, nx, ny, false);
        fft2(&mut k, nx, ny, false);
        for (u, v) in a.iter_mut().zip(&k) {
            *u *= v;
        }
        fft2(&mut a, nx, ny, true);
        // y[r][q] = full[r + ks - 1][q + ks - 1].
        let o = &mut out[c * w * h..(c + 1) * w * h];
        for r in 0..h {
            for q in 0..w {
                o[r * w + q] = a[(r + ks - 1) * nx + q + ks - 1].re * scale;
            }
        }
    }
    Ok(out)
}

/// The adjoint of [`blur_patch`] with respect to the PSF: dL/dpsf (`3 · ks²`) from dL/dy
/// (`3 · w · h`), i.e. `dpsf[c][j][i] = Σ_{r,q} dy[c][r][q] · xpad[c][r + ks − 1 − j][q + ks − 1 − i]`.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for sizes that do not match.
pub fn blur_patch_psf_adjoint(
    xpad: &[f32],
    w: usize,
    h: usize,
    ks: usize,
    dy: &[f32],
) -> Result<Vec<f32>> {
    let (pw, ph) = check_patch(xpad, w, h, ks)?;
    if dy.len() != 3 * w * h {
        return Err(Error::argument(format!(
            "dL/dy: {} values for 3 x {w}x{h}",
            dy.len()
        )));
    }
    let (nx, ny) = (fast_size(pw), fast_size(ph));
    let scale = 1.0 / (nx * ny) as f32;
    let mut out = vec![0f32; 3 * ks * ks];
    for c in 0..3 {
        let mut a = embed(&xpad[c * pw * ph..(c + 1) * pw * ph], pw, ph, nx, ny);
        // dy placed at offset (ks - 1, ks - 1); then a circular correlation with xpad.
        let mut d = vec![Complex::default(); nx * ny];
        for r in 0..h {
            for q in 0..w {
                d[(r + ks - 1) * nx + q + ks - 1] = Complex::new(dy[c * w * h + r * w + q], 0.0);
            }
        }
        fft2(&mut a, nx, ny, false);
        fft2(&mut d, nx, ny, false);
        for (u, v) in d.iter_mut().zip(&a) {
            *u *= v.conj();
        }
        fft2(&mut d, nx, ny, true);
        let o = &mut out[c * ks * ks..(c + 1) * ks * ks];
        for j in 0..ks {
            for i in 0..ks {
                o[j * ks + i] = d[j * nx + i].re * scale;
            }
        }
    }
    Ok(out)
}

/// `img` padded by `p` pixels on every side by reflection about the edge pixels (numpy's
/// 'reflect': the edge is not repeated).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] when `p` is not smaller than the image.
pub fn pad_reflect(img: &Image, p: usize) -> Result<Image> {
    let (w, h) = (img.width, img.height);
    if p >= w || p >= h {
        return Err(Error::argument(format!(
            "reflect padding of {p} px needs an image larger than that, not {w}x{h}"
        )));
    }
    let idx = |i: isize, n: usize| -> usize {
        let n = n as isize;
        let i = if i < 0 { -i } else { i };
        (if i >= n { 2 * (n - 1) - i } else { i }) as usize
    };
    let (pw, ph) = (w + 2 * p, h + 2 * p);
    let mut out = Image::new(pw, ph)?;
    for c in 0..3 {
        let src = img.plane(c);
        let dst = out.plane_mut(c);
        for y in 0..ph {
            let sy = idx(y as isize - p as isize, h);
            for x in 0..pw {
                dst[y * pw + x] = src[sy * w + idx(x as isize - p as isize, w)];
            }
        }
    }
    Ok(out)
}

/// The image blurred by the PSF map, tile by tile (see the module documentation), in parallel
/// over tiles.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for an image smaller than the grid or than the kernel's halo.
pub fn render_map(img: &Image, map: &PsfMap) -> Result<Image> {
    let (w, h, g, ks) = (img.width, img.height, map.grid, map.ks);
    if w < g || h < g {
        return Err(Error::argument(format!(
            "a {w}x{h} image cannot be cut into {g}x{g} tiles"
        )));
    }
    let half = ks / 2;
    let padded = pad_reflect(img, half)?;
    let tiles: Vec<(usize, usize, usize, usize, Vec<f32>)> = (0..g * g)
        .into_par_iter()
        .map(|t| -> Result<_> {
            let (row, col) = (t / g, t % g);
            let (y0, y1) = (row * h / g, (row + 1) * h / g);
            let (x0, x1) = (col * w / g, (col + 1) * w / g);
            let (tw, th) = (x1 - x0, y1 - y0);
            let xpad = padded.crop(x0, y0, tw + ks - 1, th + ks - 1)?;
            Ok((
                x0,
                y0,
                tw,
                th,
                blur_patch(&xpad.data, tw, th, map.psf(t), ks)?,
            ))
        })
        .collect::<Result<_>>()?;
    let mut out = Image::new(w, h)?;
    for (x0, y0, tw, th, v) in tiles {
        for c in 0..3 {
            for r in 0..th {
                let d = c * w * h + (y0 + r) * w + x0;
                out.data[d..d + tw]
                    .copy_from_slice(&v[c * tw * th + r * tw..c * tw * th + (r + 1) * tw]);
            }
        }
    }
    Ok(out)
}

/// How the PSFs of a map meet between fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Blend {
    /// Each tile is blurred by its own PSF ([`render_map`]; DeepLens and the paper).
    #[default]
    Tiles,
    /// Bilinear: each pixel is the blend of the images blurred by the four PSFs whose field
    /// centres surround it ([`render_map_bilinear`]); no steps at tile edges.
    Bilinear,
}

/// The bilinear weights of the field columns (or rows) `0..g` along an axis of `n` pixels:
/// for pixel `x`, `u = (x + 0.5) g / n − 0.5` clamped to `[0, g − 1]`, and field `j` weighs
/// `max(0, 1 − |u − j|)`. Returns per field its first pixel and the weights of its support.
fn tent_weights(n: usize, g: usize) -> Vec<(usize, Vec<f32>)> {
    (0..g)
        .map(|j| {
            let w = |x: usize| -> f64 {
                let u = ((x as f64 + 0.5) * g as f64 / n as f64 - 0.5).clamp(0.0, (g - 1) as f64);
                (1.0 - (u - j as f64).abs()).max(0.0)
            };
            let first = (0..n).find(|&x| w(x) > 0.0).unwrap_or(0);
            let last = (first..n).rev().find(|&x| w(x) > 0.0).unwrap_or(first);
            (first, (first..=last).map(|x| w(x) as f32).collect())
        })
        .collect()
}

/// The image blurred by the PSF map with bilinear blending between fields:
/// `y(p) = Σ_k w_k(p) · (psf_k ∗ x)(p)`, the weights `w_k` the bilinear interpolation weights of
/// the field centres (tile centres; constant beyond the outer centres), summing to 1 at every
/// pixel. Each PSF blurs only the pixels its weight reaches (about 2 x 2 tiles, with the halo from
/// the reflect-padded image as in [`render_map`]), so it costs about four times as much.
/// Deterministic and independent of the thread count (fixed summation order).
///
/// ```
/// use tolray::image::{render::{render_map, render_map_bilinear, PsfMap}, Image};
/// let mut img = Image::new(32, 32)?;
/// img.data.iter_mut().enumerate().for_each(|(i, v)| *v = (i % 7) as f32 / 7.0);
/// let mut psf = vec![0f32; 3 * 9];
/// for c in 0..3 { psf[c * 9 + 4] = 1.0; } // 3x3 identity kernels
/// let map = PsfMap::new(2, 3, psf.repeat(4))?;
/// // One PSF everywhere: blending changes nothing.
/// assert_eq!(render_map_bilinear(&img, &map)?.data.len(), render_map(&img, &map)?.data.len());
/// # Ok::<(), tolray::Error>(())
/// ```
///
/// # Errors
/// As [`render_map`].
pub fn render_map_bilinear(img: &Image, map: &PsfMap) -> Result<Image> {
    let (w, h, g, ks) = (img.width, img.height, map.grid, map.ks);
    if w < g || h < g {
        return Err(Error::argument(format!(
            "a {w}x{h} image cannot be cut into {g}x{g} tiles"
        )));
    }
    let padded = pad_reflect(img, ks / 2)?;
    let (wx, wy) = (tent_weights(w, g), tent_weights(h, g));
    let parts: Vec<Vec<f32>> = (0..g * g)
        .into_par_iter()
        .map(|t| -> Result<Vec<f32>> {
            let ((y0, ay), (x0, ax)) = (&wy[t / g], &wx[t % g]);
            let (tw, th) = (ax.len(), ay.len());
            let xpad = padded.crop(*x0, *y0, tw + ks - 1, th + ks - 1)?;
            let mut v = blur_patch(&xpad.data, tw, th, map.psf(t), ks)?;
            for c in 0..3 {
                for (r, fy) in ay.iter().enumerate() {
                    let row = &mut v[c * tw * th + r * tw..c * tw * th + (r + 1) * tw];
                    for (p, fx) in row.iter_mut().zip(ax) {
                        *p *= fy * fx;
                    }
                }
            }
            Ok(v)
        })
        .collect::<Result<_>>()?;
    let mut out = Image::new(w, h)?;
    for (t, v) in parts.iter().enumerate() {
        let ((y0, ay), (x0, ax)) = (&wy[t / g], &wx[t % g]);
        let (tw, th) = (ax.len(), ay.len());
        for c in 0..3 {
            for r in 0..th {
                let d = c * w * h + (y0 + r) * w + x0;
                let src = &v[c * tw * th + r * tw..c * tw * th + (r + 1) * tw];
                for (o, s) in out.data[d..d + tw].iter_mut().zip(src) {
                    *o += s;
                }
            }
        }
    }
    Ok(out)
}

/// [`render_map`] or [`render_map_bilinear`].
///
/// # Errors
/// As [`render_map`].
pub fn render(img: &Image, map: &PsfMap, blend: Blend) -> Result<Image> {
    match blend {
        Blend::Tiles => render_map(img, map),
        Blend::Bilinear => render_map_bilinear(img, map),
    }
}

/// `n` standard normal samples by Box–Muller from ChaCha8 (`seed`, `stream`): the samples of
/// [`add_gaussian_noise`] and [`SensorNoise::add`].
pub fn standard_normals(n: usize, seed: u64, stream: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    let mut out = Vec::with_capacity(n + 1);
    while out.len() < n {
        let (z0, z1) = crate::math::normal::pair(&mut rng);
        out.push(z0 as f32);
        out.push(z1 as f32);
    }
    out.truncate(n);
    out
}

/// Adds white Gaussian noise of standard deviation `sigma` (linear [0, 1] units; the paper's
/// 1 % is 0.01), deterministic per (`seed`, `stream`). No clipping.
pub fn add_gaussian_noise(data: &mut [f32], sigma: f32, seed: u64, stream: u64) {
    SensorNoise::gaussian(sigma as f64).add(data, seed, stream);
}

/// A sensor's noise in linear [0, 1] units (1 = a full well): white Gaussian noise of standard
/// deviation `sigma` (read noise and everything else that does not depend on the signal; the
/// paper's 1 % is 0.01) and, with a full well, photon shot noise. A pixel of noise-free value
/// `b` reads `b + s(b) z`, `z` standard normal, `s(b) = sqrt(max(b, 0) / full_well + sigma²)`:
/// the Poisson–Gaussian model of raw sensor data in its heteroscedastic Gaussian form (Foi et
/// al., IEEE TIP 2008), whose shot-noise variance is the Poisson variance of `b · full_well`
/// electrons divided by `full_well²`. The Gaussian form rather than Poisson sampling is used
/// everywhere (rendering, training, evaluation) because training differentiates the capture
/// with respect to the PSF through the noise (`dy/db = 1 + z s'(b)`, [`SensorNoise::slope`])
/// and evaluation must see the noise training saw; it departs from Poisson counts only below
/// about ten electrons a pixel. Read noise in electrons `e` is `sigma = e / full_well`.
///
/// ```
/// use tolray::image::render::SensorNoise;
/// let n = SensorNoise { sigma: 0.002, full_well_electrons: Some(10_000.0) };
/// n.validate().unwrap();
/// // At half a full well, shot noise (5000 electrons: ±71) dominates 20 electrons of read noise.
/// assert!((n.std(0.5) - (0.5f64 / 1e4 + 0.002f64.powi(2)).sqrt()).abs() < 1e-12);
/// let mut y = vec![0.5f32; 4];
/// n.add(&mut y, 7, 0);
/// assert!(y.iter().all(|v| (v - 0.5).abs() < 0.1));
/// assert_eq!(SensorNoise::gaussian(0.01).full_well_electrons, None);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SensorNoise {
    /// Standard deviation of the signal-independent Gaussian noise, linear [0, 1] units.
    pub sigma: f64,
    /// Electrons of a full well (signal 1), for shot noise; `None`: no shot noise.
    pub full_well_electrons: Option<f64>,
}

impl SensorNoise {
    /// White Gaussian noise of standard deviation `sigma` alone (the paper's model).
    pub fn gaussian(sigma: f64) -> SensorNoise {
        SensorNoise {
            sigma,
            full_well_electrons: None,
        }
    }

    /// Checks the settings.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for a negative or non-finite `sigma`, or a full well that
    /// is not a finite number of at least one electron.
    pub fn validate(&self) -> Result<()> {
        if !(self.sigma >= 0.0 && self.sigma.is_finite()) {
            return Err(Error::argument(format!(
                "noise sigma {}: must be zero or positive",
                self.sigma
            )));
        }
        if let Some(f) = self.full_well_electrons {
            if !(f >= 1.0 && f.is_finite()) {
                return Err(Error::argument(format!(
                    "full well {f} electrons: must be a finite number of at least 1"
                )));
            }
        }
        Ok(())
    }

    /// The noise's standard deviation at noise-free signal `b`, linear units.
    pub fn std(&self, b: f64) -> f64 {
        match self.full_well_electrons {
            None => self.sigma,
            Some(f) => (b.max(0.0) / f + self.sigma * self.sigma).sqrt(),
        }
    }

    /// A standard deviation representative of the noise for setting a decoder's regularization:
    /// [`SensorNoise::std`] at 0.18 (photographic mid-grey in linear light).
    pub fn typical_std(&self) -> f64 {
        self.std(0.18)
    }

    /// Adds the noise to the noise-free capture `data`, from standard normal samples that are
    /// deterministic per (`seed`, `stream`) ([`standard_normals`]). No clipping.
    pub fn add(&self, data: &mut [f32], seed: u64, stream: u64) {
        if self.sigma == 0.0 && self.full_well_electrons.is_none() {
            return;
        }
        self.apply(data, &standard_normals(data.len(), seed, stream));
    }

    /// Adds the noise of the standard normal samples `z` to the noise-free capture `b`:
    /// `b += s(b) z`. With Gaussian noise alone this is `b += sigma · z` in f32, as
    /// [`add_gaussian_noise`] computes it.
    pub fn apply(&self, b: &mut [f32], z: &[f32]) {
        for (v, z) in b.iter_mut().zip(z) {
            *v += self.std(*v as f64) as f32 * z;
        }
    }

    /// The derivative of the noisy capture with respect to the noise-free one, pixel by pixel,
    /// for the samples `z`: `1 + z s'(b)`, `s'(b) = 1 / (2 full_well s(b))` for `b > 0` and 0
    /// below (the variance stops at zero signal; at exactly `b = 0` with `sigma = 0` the
    /// derivative from above is infinite, and 0 is used); `None` when it is 1 everywhere (no shot
    /// noise).
    pub fn slope(&self, b: &[f32], z: &[f32]) -> Option<Vec<f32>> {
        let f = self.full_well_electrons?;
        Some(
            b.iter()
                .zip(z)
                .map(|(&b, &z)| {
                    let s = self.std(b as f64);
                    if b > 0.0 && s > 0.0 {
                        (1.0 + z as f64 / (2.0 * f * s)) as f32
                    } else {
                        1.0
                    }
                })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 8) as f32 / (1 << 24) as f32
            })
            .collect()
    }

    /// The convention written out as loops.
    fn direct(xpad: &[f32], w: usize, h: usize, psf: &[f32], ks: usize) -> Vec<f32> {
        let (pw, ph) = (w + ks - 1, h + ks - 1);
        let mut y = vec![0f32; 3 * w * h];
        for c in 0..3 {
            for r in 0..h {
                for q in 0..w {
                    let mut s = 0.0;
                    for j in 0..ks {
                        for i in 0..ks {
                            s += psf[c * ks * ks + j * ks + i]
                                * xpad[c * pw * ph + (r + ks - 1 - j) * pw + q + ks - 1 - i];
                        }
                    }
                    y[c * w * h + r * w + q] = s;
                }
            }
        }
        y
    }

    #[test]
    fn sensor_noise_has_the_poisson_gaussian_moments_and_its_slope() {
        // 2000 electrons a full well, 6 electrons of read noise.
        let (f, sigma) = (2000.0, 0.003);
        let n = SensorNoise {
            sigma,
            full_well_electrons: Some(f),
        };
        n.validate().unwrap();
        let m = 200_000;
        for (k, x) in [0.0f32, 0.01, 0.3, 1.0].into_iter().enumerate() {
            let mut y = vec![x; m];
            n.add(&mut y, 11, k as u64);
            let d: Vec<f64> = y.iter().map(|&v| (v - x) as f64).collect();
            let mean = d.iter().sum::<f64>() / m as f64;
            let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
            // The Poisson variance of x·f electrons, in full wells, plus the read noise.
            let want = x as f64 / f + sigma * sigma;
            let se = (want / m as f64).sqrt();
            assert!(
                mean.abs() < 5.0 * se,
                "signal {x}: mean {mean:e} (se {se:e})"
            );
            let rel = var / want - 1.0;
            assert!(
                rel.abs() < 5.0 * (2.0 / m as f64).sqrt(),
                "signal {x}: variance {var:e} against {want:e}"
            );
        }
        // Deterministic per (seed, stream); another stream is other noise.
        let (mut a, mut b, mut c) = (vec![0.2f32; 64], vec![0.2f32; 64], vec![0.2f32; 64]);
        n.add(&mut a, 3, 1);
        n.add(&mut b, 3, 1);
        n.add(&mut c, 3, 2);
        assert_eq!(a, b);
        assert_ne!(a, c);
        // Gaussian noise alone is the paper's σ z, bit for bit, with or without the type.
        let mut g = vec![0.25f32; 999];
        let mut h = g.clone();
        add_gaussian_noise(&mut g, 0.01, 5, 2);
        let z = standard_normals(999, 5, 2);
        for (v, z) in h.iter_mut().zip(&z) {
            *v += 0.01f32 * z;
        }
        assert_eq!(g, h);
        assert_eq!(SensorNoise::gaussian(0.01).slope(&h, &z), None);
        // dy/db = 1 + z s'(b) against central differences of b + s(b) z in f64.
        let b = [1e-4f32, 0.02, 0.3, 0.9, -0.1];
        let z = [1.3f32, -0.7, 2.1, -1.9, 0.8];
        let slope = n.slope(&b, &z).unwrap();
        for ((&b, &z), &s) in b.iter().zip(&z).zip(&slope) {
            let y = |b: f64| b + n.std(b) * z as f64;
            let h = 1e-6 * (b as f64).abs().max(1e-3);
            let fd = (y(b as f64 + h) - y(b as f64 - h)) / (2.0 * h);
            assert!(
                (s as f64 - fd).abs() < 1e-5 * fd.abs(),
                "b {b}: {s} vs {fd}"
            );
        }
        // The shot-noise term matters at a small full well, so the check above is not vacuous.
        assert!((slope[0] - 1.0).abs() > 0.05);
        for bad in [
            SensorNoise {
                sigma: -0.1,
                full_well_electrons: None,
            },
            SensorNoise {
                sigma: f64::NAN,
                full_well_electrons: None,
            },
            SensorNoise {
                sigma: 0.01,
                full_well_electrons: Some(0.5),
            },
            SensorNoise {
                sigma: 0.01,
                full_well_electrons: Some(f64::INFINITY),
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn blur_matches_direct_convolution_and_its_adjoint() {
        let (w, h, ks) = (13, 9, 5);
        let xpad = lcg(3 * (w + ks - 1) * (h + ks - 1), 1);
        let psf = lcg(3 * ks * ks, 2);
        let y = blur_patch(&xpad, w, h, &psf, ks).unwrap();
        let d = direct(&xpad, w, h, &psf, ks);
        for (a, b) in y.iter().zip(&d) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        // <blur(x, k), g> = <k, adjoint(x, g)>
        let g = lcg(3 * w * h, 3);
        let lhs: f64 = y.iter().zip(&g).map(|(a, b)| (a * b) as f64).sum();
        let adj = blur_patch_psf_adjoint(&xpad, w, h, ks, &g).unwrap();
        let rhs: f64 = psf.iter().zip(&adj).map(|(a, b)| (a * b) as f64).sum();
        assert!((lhs - rhs).abs() < 1e-4 * lhs.abs(), "{lhs} vs {rhs}");
        assert!(blur_patch(&xpad, w + 1, h, &psf, ks).is_err());
    }

    #[test]
    fn map_of_one_psf_is_one_convolution_and_a_delta_is_the_identity() {
        let mut img = Image::new(40, 30).unwrap();
        img.data = lcg(3 * 40 * 30, 4);
        let ks = 7;
        let psf = lcg(3 * ks * ks, 5);
        let map = PsfMap::new(4, ks, psf.repeat(16)).unwrap();
        let y = render_map(&img, &map).unwrap();
        let whole = blur_patch(&pad_reflect(&img, 3).unwrap().data, 40, 30, &psf, ks).unwrap();
        for (a, b) in y.data.iter().zip(&whole) {
            assert!((a - b).abs() < 1e-5);
        }
        let mut delta = vec![0f32; 3 * ks * ks];
        for c in 0..3 {
            delta[c * ks * ks + ks * ks / 2] = 1.0;
        }
        let id = render_map(&img, &PsfMap::new(3, ks, delta.repeat(9)).unwrap()).unwrap();
        for (a, b) in id.data.iter().zip(&img.data) {
            assert!((a - b).abs() < 1e-5);
        }
        // A point source spreads as the PSF says: one pixel right of centre lands right.
        let mut shift = vec![0f32; 3 * ks * ks];
        for c in 0..3 {
            shift[c * ks * ks + (ks / 2) * ks + ks / 2 + 1] = 1.0;
        }
        let mut dot = Image::new(20, 20).unwrap();
        dot.data[10 * 20 + 10] = 1.0;
        let s = render_map(&dot, &PsfMap::new(1, ks, shift).unwrap()).unwrap();
        assert!((s.data[10 * 20 + 11] - 1.0).abs() < 1e-5);
    }

    /// Bilinear blending against its definition summed directly, pixel by pixel; one PSF
    /// everywhere is one convolution; at a field centre only that field's PSF counts.
    #[test]
    fn bilinear_blending_is_its_definition() {
        let (w, h, g, ks) = (45, 30, 3, 5);
        let mut img = Image::new(w, h).unwrap();
        img.data = lcg(3 * w * h, 11);
        let map = PsfMap::new(g, ks, lcg(g * g * 3 * ks * ks, 12)).unwrap();
        let y = render_map_bilinear(&img, &map).unwrap();
        let xp = pad_reflect(&img, ks / 2).unwrap();
        let pw = w + ks - 1;
        let tent = |x: usize, n: usize, j: usize| -> f64 {
            let u = ((x as f64 + 0.5) * g as f64 / n as f64 - 0.5).clamp(0.0, (g - 1) as f64);
            (1.0 - (u - j as f64).abs()).max(0.0)
        };
        let mut worst = 0f64;
        for c in 0..3 {
            for r in 0..h {
                for q in 0..w {
                    let mut s = 0f64;
                    for t in 0..g * g {
                        let wt = tent(r, h, t / g) * tent(q, w, t % g);
                        let psf = map.psf(t);
                        for j in 0..ks {
                            for i in 0..ks {
                                s += wt
                                    * psf[c * ks * ks + j * ks + i] as f64
                                    * xp.data[c * pw * (h + ks - 1)
                                        + (r + ks - 1 - j) * pw
                                        + q
                                        + ks
                                        - 1
                                        - i] as f64;
                            }
                        }
                    }
                    worst = worst.max((s - y.data[c * w * h + r * w + q] as f64).abs());
                }
            }
        }
        assert!(worst < 1e-4, "{worst}");
        // Field centres (tiles of 15 x 10 px: column 7 + 15 j is a centre; rows have none on a
        // pixel) take only their column's PSFs.
        let tiles = render_map(&img, &map).unwrap();
        let (r, q) = (0, 7 + 15);
        for c in 0..3 {
            let i = c * w * h + r * w + q;
            assert!((tiles.data[i] - y.data[i]).abs() < 1e-5);
        }
        assert!(tiles != y, "blending changed nothing");
        let one = PsfMap::new(g, ks, map.psf(4).repeat(g * g)).unwrap();
        let a = render_map_bilinear(&img, &one).unwrap();
        let b = render_map(&img, &one).unwrap();
        for (a, b) in a.data.iter().zip(&b.data) {
            assert!((a - b).abs() < 1e-5);
        }
    }

    #[test]
    fn noise_is_seeded_and_thread_count_free() {
        let mut a = vec![0.5f32; 1001];
        let mut b = a.clone();
        add_gaussian_noise(&mut a, 0.01, 7, 3);
        add_gaussian_noise(&mut b, 0.01, 7, 3);
        assert_eq!(a, b);
        let m = a.iter().map(|v| (*v - 0.5) as f64).sum::<f64>() / 1001.0;
        let s = (a.iter().map(|v| ((*v - 0.5) as f64).powi(2)).sum::<f64>() / 1001.0).sqrt();
        assert!(m.abs() < 0.002 && (s - 0.01).abs() < 0.001, "{m} {s}");
        let mut img = Image::new(64, 48).unwrap();
        img.data = lcg(3 * 64 * 48, 6);
        let map = PsfMap::new(4, 5, lcg(16 * 75, 8)).unwrap();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        for blend in [Blend::Tiles, Blend::Bilinear] {
            let y1 = one.install(|| render(&img, &map, blend).unwrap());
            let y2 = two.install(|| render(&img, &map, blend).unwrap());
            assert_eq!(y1, y2);
        }
    }
}
