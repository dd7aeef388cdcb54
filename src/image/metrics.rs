//! Image-quality metrics: PSNR and SSIM, comparing sRGB-encoded images clamped to [0, 1]. The
//! statistics over units (percentiles, the yield table, bootstrap intervals) are
//! [`crate::math::stats`].

use super::Image;
use crate::error::{Error, Result};

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::stats::{paired_bootstrap, percentile, YieldTable};

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
