//! The image loss of the paper, `0.1 MSE + 0.01 TV + 0.001 VGG`, with a stand-in for the VGG
//! perceptual term (no VGG weights can be shipped): the mean squared difference of image
//! gradients, which like a perceptual loss weighs edges and texture. TV is the mean squared
//! forward difference of the output (squared, so that at ~28 dB it does not outweigh the MSE as
//! an L1 total variation at 0.01 would). Every term is a mean over pixels and channels.

use serde::{Deserialize, Serialize};

/// Weights of the image-loss terms.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageLossWeights {
    /// Mean squared error against the sharp image (the paper: 0.1).
    pub mse: f64,
    /// Squared total variation of the output (the paper's TV weight: 0.01).
    pub tv: f64,
    /// Gradient-domain stand-in for the VGG term (the paper's weight: 0.001).
    pub grad: f64,
}

impl Default for ImageLossWeights {
    fn default() -> Self {
        ImageLossWeights {
            mse: 0.1,
            tv: 0.01,
            grad: 0.001,
        }
    }
}

/// The loss of the estimate `xhat` against `x` (both 3 x h x w planar) and dL/dxhat.
pub fn image_loss(
    xhat: &[f32],
    x: &[f32],
    w: usize,
    h: usize,
    wt: &ImageLossWeights,
) -> (f64, Vec<f32>) {
    let n = (3 * w * h) as f64;
    let mut g = vec![0f64; xhat.len()];
    let mut loss = 0.0;
    for (k, (a, b)) in xhat.iter().zip(x).enumerate() {
        let d = (*a - *b) as f64;
        loss += wt.mse * d * d / n;
        g[k] += wt.mse * 2.0 * d / n;
    }
    for c in 0..3 {
        let o = c * w * h;
        for r in 0..h {
            for q in 0..w {
                let i = o + r * w + q;
                for j in [(q + 1 < w).then(|| i + 1), (r + 1 < h).then(|| i + w)]
                    .into_iter()
                    .flatten()
                {
                    let dh = (xhat[j] - xhat[i]) as f64;
                    let dt = dh - (x[j] - x[i]) as f64;
                    loss += (wt.tv * dh * dh + wt.grad * dt * dt) / n;
                    let s = 2.0 * (wt.tv * dh + wt.grad * dt) / n;
                    g[j] += s;
                    g[i] -= s;
                }
            }
        }
    }
    (loss, g.into_iter().map(|v| v as f32).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_central_differences() {
        let (w, h) = (5, 4);
        let x: Vec<f32> = (0..60).map(|k| ((k * 37) % 17) as f32 / 17.0).collect();
        let xh: Vec<f32> = (0..60).map(|k| ((k * 11) % 13) as f32 / 13.0).collect();
        let wt = ImageLossWeights {
            mse: 0.1,
            tv: 0.05,
            grad: 0.02,
        };
        let (l, g) = image_loss(&xh, &x, w, h, &wt);
        assert!(l > 0.0);
        for k in [0, 7, 19, 33, 59] {
            let e = 1e-2f32;
            let (mut a, mut b) = (xh.clone(), xh.clone());
            a[k] += e;
            b[k] -= e;
            // The loss is quadratic: the central difference is exact up to rounding.
            let fd = (image_loss(&a, &x, w, h, &wt).0 - image_loss(&b, &x, w, h, &wt).0)
                / (2.0 * e as f64);
            assert!(
                (g[k] as f64 - fd).abs() < 1e-5 * fd.abs().max(1e-3),
                "{k}: {} vs {fd}",
                g[k]
            );
        }
        assert_eq!(
            image_loss(
                &x,
                &x,
                w,
                h,
                &ImageLossWeights {
                    mse: 1.0,
                    tv: 0.0,
                    grad: 1.0
                }
            )
            .0,
            0.0
        );
    }
}
