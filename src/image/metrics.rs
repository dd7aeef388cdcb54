//! Image-quality metrics and yield statistics: PSNR, SSIM, percentiles, the manufacturing-yield
//! table and a paired bootstrap. Metrics compare sRGB-encoded images clamped to [0, 1].

use super::Image;
use crate::error::{Error, Result};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

fn same_size(a: &Image, b: &Image) -> Result<()> {
    if a.width != b.width || a.height != b.height {
        return Err(Error::argument(format!(
            "images of different sizes: {}x{} and {}x{}",
            a.width, a.height, b.width, b.height
        )));
    }
    Ok(())
}

/// Peak signal-to-noise ratio in dB for data range 1, both images clamped to [0, 1] first;
/// capped at 100 dB for identical images.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for images of different sizes.
pub fn psnr(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    let se: f64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| {
            let d = x.clamp(0.0, 1.0) as f64 - y.clamp(0.0, 1.0) as f64;
            d * d
        })
        .sum();
    let mse = se / a.data.len() as f64;
    Ok((-10.0 * mse.log10()).min(100.0))
}

/// The 11-tap Gaussian window of σ = 1.5, normalized (skimage's truncate = 3.5).
fn window() -> [f64; 11] {
    let mut w = [0.0; 11];
    for (k, v) in w.iter_mut().enumerate() {
        let x = k as f64 - 5.0;
        *v = (-x * x / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f64 = w.iter().sum();
    w.map(|v| v / s)
}

/// Gaussian-weighted local means of `v` (w x h) at every pixel at least 5 from the border
/// (separable, valid region): ((w - 10) x (h - 10)) values.
fn local_mean(v: &[f64], w: usize, h: usize, k: &[f64; 11]) -> Vec<f64> {
    let (ow, oh) = (w - 10, h - 10);
    let mut rows = vec![0.0; ow * h];
    for y in 0..h {
        for x in 0..ow {
            rows[y * ow + x] = (0..11).map(|t| k[t] * v[y * w + x + t]).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|t| k[t] * rows[(y + t) * ow + x]).sum();
        }
    }
    out
}

/// Structural similarity (Wang et al. 2004) with an 11 x 11 Gaussian window of σ = 1.5,
/// K1 = 0.01, K2 = 0.03, data range 1, population covariances, averaged over channels and the
/// pixels at least 5 from the border: the definition of scikit-image's
/// `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
/// data_range=1, channel_axis=-1)`. Both images are clamped to [0, 1].
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for images of different sizes or smaller than 11 x 11.
pub fn ssim(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    let (w, h) = (a.width, a.height);
    if w < 11 || h < 11 {
        return Err(Error::argument(format!(
            "SSIM needs at least 11x11 pixels, not {w}x{h}"
        )));
    }
    let k = window();
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    for c in 0..3 {
        let x: Vec<f64> = a
            .plane(c)
            .iter()
            .map(|v| v.clamp(0.0, 1.0) as f64)
            .collect();
        let y: Vec<f64> = b
            .plane(c)
            .iter()
            .map(|v| v.clamp(0.0, 1.0) as f64)
            .collect();
        let prod = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(u, v)| u * v).collect::<Vec<_>>();
        let (mx, my) = (local_mean(&x, w, h, &k), local_mean(&y, w, h, &k));
        let (mxx, myy, mxy) = (
            local_mean(&prod(&x, &x), w, h, &k),
            local_mean(&prod(&y, &y), w, h, &k),
            local_mean(&prod(&x, &y), w, h, &k),
        );
        let mut s = 0.0;
        for i in 0..mx.len() {
            let (vx, vy, cxy) = (
                mxx[i] - mx[i] * mx[i],
                myy[i] - my[i] * my[i],
                mxy[i] - mx[i] * my[i],
            );
            s += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
        }
        total += s / mx.len() as f64;
    }
    Ok(total / 3.0)
}

/// Percentile `p` (0 to 100) of `values` by linear interpolation between order statistics
/// (numpy's default); NaN for no values.
pub fn percentile(values: &[f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let pos = (p / 100.0).clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos - pos.floor());
    if i + 1 < v.len() {
        v[i] + f * (v[i + 1] - v[i])
    } else {
        v[i]
    }
}

/// The manufacturing-yield table: the value that 90/70/50/10 % of units exceed (the 10th,
/// 30th, 50th and 90th percentiles).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct YieldTable {
    /// Exceeded by 90 % of units.
    #[serde(rename = "90")]
    pub y90: f64,
    /// Exceeded by 70 %.
    #[serde(rename = "70")]
    pub y70: f64,
    /// Exceeded by 50 % (the median).
    #[serde(rename = "50")]
    pub y50: f64,
    /// Exceeded by 10 %.
    #[serde(rename = "10")]
    pub y10: f64,
}

impl YieldTable {
    /// The table of `values`.
    pub fn from(values: &[f64]) -> YieldTable {
        YieldTable {
            y90: percentile(values, 10.0),
            y70: percentile(values, 30.0),
            y50: percentile(values, 50.0),
            y10: percentile(values, 90.0),
        }
    }
}

/// `stat(a) - stat(b)` and its 95 % bootstrap percentile interval over `resamples` paired
/// resamples (the same resampled unit indices for `a` and `b`), seeded.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for samples of different or zero length or no resamples.
pub fn paired_bootstrap(
    a: &[f64],
    b: &[f64],
    stat: impl Fn(&[f64]) -> f64,
    resamples: usize,
    seed: u64,
) -> Result<(f64, [f64; 2])> {
    if a.len() != b.len() || a.is_empty() || resamples == 0 {
        return Err(Error::argument(format!(
            "paired bootstrap of {} and {} values with {resamples} resamples",
            a.len(),
            b.len()
        )));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = a.len();
    let (mut ra, mut rb) = (vec![0.0; n], vec![0.0; n]);
    let diffs: Vec<f64> = (0..resamples)
        .map(|_| {
            for k in 0..n {
                let i = rng.random_range(0..n);
                ra[k] = a[i];
                rb[k] = b[i];
            }
            stat(&ra) - stat(&rb)
        })
        .collect();
    Ok((
        stat(a) - stat(b),
        [percentile(&diffs, 2.5), percentile(&diffs, 97.5)],
    ))
}

/// Pooled over independent repetitions (training seeds) evaluated on the same units: the mean
/// over groups of `stat(a_g) - stat(b_g)` and its 95 % bootstrap percentile interval. Each of
/// the `resamples` draws both groups (with replacement: the spread between training seeds) and
/// unit indices (with replacement, the same indices in every group and for `a` and `b`: the
/// units are shared and paired), so the interval carries both sources of variation.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for no group, groups or samples of different or zero length,
/// or no resamples.
///
/// # Examples
/// ```
/// use tolray::image::metrics::pooled_paired_bootstrap;
/// let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
/// // Two seeds whose designs differ by exactly 0.5 and 0.3 dB on every unit.
/// let g1 = (vec![20.5, 21.5, 19.5], vec![20.0, 21.0, 19.0]);
/// let g2 = (vec![20.3, 21.3, 19.3], vec![20.0, 21.0, 19.0]);
/// let (d, ci) = pooled_paired_bootstrap(&[g1, g2], mean, 1000, 7)?;
/// assert!((d - 0.4).abs() < 1e-12 && ci[0] >= 0.3 - 1e-12 && ci[1] <= 0.5 + 1e-12);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn pooled_paired_bootstrap(
    groups: &[(Vec<f64>, Vec<f64>)],
    stat: impl Fn(&[f64]) -> f64,
    resamples: usize,
    seed: u64,
) -> Result<(f64, [f64; 2])> {
    let n = groups.first().map_or(0, |g| g.0.len());
    if groups.is_empty()
        || n == 0
        || resamples == 0
        || groups.iter().any(|g| g.0.len() != n || g.1.len() != n)
    {
        return Err(Error::argument(format!(
            "pooled bootstrap of {} groups (every group needs the same, nonzero number of paired \
             values) with {resamples} resamples",
            groups.len()
        )));
    }
    let m = groups.len();
    let diff = |g: &(Vec<f64>, Vec<f64>)| stat(&g.0) - stat(&g.1);
    let estimate = groups.iter().map(diff).sum::<f64>() / m as f64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut ra, mut rb) = (vec![0.0; n], vec![0.0; n]);
    let mut units = vec![0usize; n];
    let diffs: Vec<f64> = (0..resamples)
        .map(|_| {
            for u in units.iter_mut() {
                *u = rng.random_range(0..n);
            }
            let mut sum = 0.0;
            for _ in 0..m {
                let g = &groups[rng.random_range(0..m)];
                for (k, &i) in units.iter().enumerate() {
                    ra[k] = g.0[i];
                    rb[k] = g.1[i];
                }
                sum += stat(&ra) - stat(&rb);
            }
            sum / m as f64
        })
        .collect();
    Ok((
        estimate,
        [percentile(&diffs, 2.5), percentile(&diffs, 97.5)],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_ssim_percentiles() {
        let mut a = Image::new(32, 24).unwrap();
        for (i, v) in a.data.iter_mut().enumerate() {
            *v = ((i * 7919) % 101) as f32 / 100.0;
        }
        let mut b = a.clone();
        for v in b.data.iter_mut() {
            *v = (*v + 0.01).min(1.0);
        }
        // Every value moves by 0.01 except those clipped at 1.
        let clipped = a.data.iter().filter(|&&v| v > 0.99).count() as f64;
        let mse = 1e-4 * (a.data.len() as f64 - clipped) / a.data.len() as f64;
        assert!((psnr(&a, &b).unwrap() - (-10.0 * mse.log10())).abs() < 1e-4);
        assert_eq!(psnr(&a, &a).unwrap(), 100.0);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        let s = ssim(&a, &b).unwrap();
        assert!(s < 1.0 && s > 0.9, "{s}");
        // numpy.percentile([3, 1, 4, 1, 5], [10, 50, 97.5]) = 1.0, 3.0, 4.9
        let v = [3.0, 1.0, 4.0, 1.0, 5.0];
        assert_eq!(percentile(&v, 10.0), 1.0);
        assert_eq!(percentile(&v, 50.0), 3.0);
        assert!((percentile(&v, 97.5) - 4.9).abs() < 1e-12);
        let y = YieldTable::from(&v);
        assert!((y.y10 - 4.6).abs() < 1e-12 && y.y90 == 1.0);
        // A constant shift gives a degenerate interval at the shift; resampling is seeded.
        let b: Vec<f64> = v.iter().map(|x| x - 0.5).collect();
        let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len() as f64;
        let (d, ci) = paired_bootstrap(&v, &b, mean, 500, 1).unwrap();
        assert!(
            (d - 0.5).abs() < 1e-12 && (ci[0] - 0.5).abs() < 1e-12 && (ci[1] - 0.5).abs() < 1e-12
        );
        let c: Vec<f64> = v.iter().map(|x| x * x).collect();
        assert_eq!(
            paired_bootstrap(&v, &c, mean, 200, 9).unwrap(),
            paired_bootstrap(&v, &c, mean, 200, 9).unwrap()
        );
    }
}
