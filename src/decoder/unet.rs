//! A small U-Net with hand-written forward and backward passes (im2col + `matrixmultiply`
//! SGEMM), in the style of llm.c: each layer a forward/backward pair, gradients accumulated with
//! `+=` into caller-zeroed buffers. Planar tensors, one sample at a time (`[channels][h][w]`);
//! samples of a batch run in parallel and their weight gradients are summed in sample order, so
//! results do not depend on the thread count.
//!
//! Architecture (`levels` = L, width c): per level two 3x3 convolutions with ReLU (c, 2c, 4c,
//! ...), 2x2 average pooling down, a bottleneck of two convolutions, then per level nearest 2x
//! upsampling, concatenation with the skip, two convolutions; a final 1x1 convolution to 3
//! channels whose weights start at zero, so the network starts as a zero residual.

use super::conv;
use crate::error::{Error, Result};
use rand::SeedableRng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// U-Net shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct UnetConfig {
    /// Input channels.
    pub in_channels: usize,
    /// Channels of the first level.
    pub width: usize,
    /// Levels (poolings); sizes must be divisible by 2^levels.
    pub levels: usize,
}

/// One convolution: `cout x cin x k x k` weights at `w`, `cout` biases at `b` in the parameters.
#[derive(Clone, Copy, Debug)]
struct Conv {
    cin: usize,
    cout: usize,
    k: usize,
    w: usize,
    b: usize,
}

/// The network: its convolutions in order and its flat parameters.
#[derive(Clone, Debug)]
pub struct Unet {
    /// Shape.
    pub cfg: UnetConfig,
    convs: Vec<Conv>,
    /// Every weight and bias (layout: the convolutions in order, weights then biases).
    pub params: Vec<f32>,
}

/// What one sample's backward pass needs: the input of every convolution and the (post-ReLU)
/// output of every ReLU convolution, in forward order.
#[derive(Clone, Debug)]
pub struct Cache {
    h: usize,
    w: usize,
    ins: Vec<Vec<f32>>,
    outs: Vec<Vec<f32>>,
}

/// Columns `p0..p1` (pixels in row-major order) of im2col for a 3x3 (zero padding 1) or 1x1
/// convolution: `(cin · k²) x (p1 - p0)` into `col`, every value written.
fn im2col_band(
    inp: &[f32],
    cin: usize,
    h: usize,
    w: usize,
    k: usize,
    (p0, p1): (usize, usize),
    col: &mut [f32],
) {
    debug_assert!(k == 1 || k == 3, "only 1x1 and 3x3 kernels");
    debug_assert_eq!(inp.len(), cin * h * w, "input is cin x h x w");
    let (hw, nb) = (h * w, p1 - p0);
    debug_assert!(p0 < p1 && p1 <= hw && col.len() == cin * k * k * nb);
    if k == 1 {
        for c in 0..cin {
            col[c * nb..(c + 1) * nb].copy_from_slice(&inp[c * hw + p0..c * hw + p1]);
        }
        return;
    }
    for c in 0..cin {
        for ky in 0..3 {
            for kx in 0..3 {
                let row = &mut col[(c * 9 + ky * 3 + kx) * nb..(c * 9 + ky * 3 + kx + 1) * nb];
                // Output pixels (y, xa..xb) of the band, row by row; the source column is
                // x + kx - 1, valid for x in lo..hi.
                let mut p = p0;
                while p < p1 {
                    let (y, xa) = (p / w, p % w);
                    let xb = (p1 - y * w).min(w);
                    let dst = &mut row[p - p0..p - p0 + xb - xa];
                    let sy = y as isize + ky as isize - 1;
                    let (lo, hi) = (xa.max(1 - kx.min(1)), xb.min(w + 1 - kx.max(1)));
                    if sy < 0 || sy >= h as isize || lo >= hi {
                        dst.fill(0.0);
                    } else {
                        let src = &inp[c * hw + sy as usize * w..c * hw + sy as usize * w + w];
                        dst[..lo - xa].fill(0.0);
                        dst[lo - xa..hi - xa].copy_from_slice(&src[lo + kx - 1..hi + kx - 1]);
                        dst[hi - xa..].fill(0.0);
                    }
                    p = y * w + xb;
                }
            }
        }
    }
}

/// The adjoint of [`im2col_band`]: adds the columns of pixels `p0..p1` back into `dinp`.
///
/// Every input value receives its terms in the order of (ky, kx), as an adjoint of the whole
/// image does, when the bands of an image are added from the last to the first: a later pixel
/// reaches an input through an earlier (ky, kx).
fn col2im_band(
    col: &[f32],
    cin: usize,
    h: usize,
    w: usize,
    k: usize,
    (p0, p1): (usize, usize),
    dinp: &mut [f32],
) {
    let (hw, nb) = (h * w, p1 - p0);
    debug_assert_eq!(col.len(), cin * k * k * nb, "columns are (cin k²) x band");
    debug_assert_eq!(dinp.len(), cin * hw, "the input gradient is cin x h x w");
    if k == 1 {
        for c in 0..cin {
            let d = &mut dinp[c * hw + p0..c * hw + p1];
            d.iter_mut()
                .zip(&col[c * nb..(c + 1) * nb])
                .for_each(|(d, s)| *d += s);
        }
        return;
    }
    for c in 0..cin {
        for ky in 0..3 {
            for kx in 0..3 {
                let row = &col[(c * 9 + ky * 3 + kx) * nb..(c * 9 + ky * 3 + kx + 1) * nb];
                let mut p = p0;
                while p < p1 {
                    let (y, xa) = (p / w, p % w);
                    let xb = (p1 - y * w).min(w);
                    let sy = y as isize + ky as isize - 1;
                    let (lo, hi) = (xa.max(1 - kx.min(1)), xb.min(w + 1 - kx.max(1)));
                    if sy >= 0 && sy < h as isize && lo < hi {
                        let dst = &mut dinp[c * hw + sy as usize * w..c * hw + sy as usize * w + w];
                        dst[lo + kx - 1..hi + kx - 1]
                            .iter_mut()
                            .zip(&row[lo - xa + p - p0..hi - xa + p - p0])
                            .for_each(|(d, s)| *d += s);
                    }
                    p = y * w + xb;
                }
            }
        }
    }
}

/// Pixels per band of a convolution with `kk` columns per pixel: a multiple of
/// matrixmultiply's SGEMM depth block (`S_KC` = 256 in matrixmultiply 0.3; another value would
/// change the weight gradient's last bits, which the test of bands would catch), so that a
/// weight gradient summed band by band adds the same blocks in the same order as one product
/// over the whole image; about 512 KB of columns up to kk = 512 (256 pixels above: 256 · kk
/// values), which stay in the L2 cache between im2col and the product.
fn band_px(kk: usize, hw: usize) -> usize {
    const KC: usize = 256;
    ((128 * 1024 / kk.max(1)) / KC)
        .max(1)
        .saturating_mul(KC)
        .min(hw)
}

thread_local! {
    /// Each thread's column buffer for one band (kept between convolutions: the whole-image
    /// im2col of a 256² crop was 19 MB allocated, faulted in and freed per convolution).
    static COLUMNS: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` on this thread's column buffer of `len` values (a fresh one if it is in use).
fn with_columns<R>(len: usize, f: impl FnOnce(&mut [f32]) -> R) -> R {
    COLUMNS.with(|b| match b.try_borrow_mut() {
        Ok(mut v) => {
            if v.len() < len {
                v.resize(len, 0.0);
            }
            f(&mut v[..len])
        }
        Err(_) => f(&mut vec![0f32; len]),
    })
}

/// `n` zeros in pages already written. A large `vec![0.0; n]` is fresh memory the kernel maps
/// to its shared zero page when first read; a gradient buffer's first `+=` reads it and then
/// faults again to write, and that second fault flushes the TLB of every core running the
/// process (16 % of a paper-batch training iteration on 2 cores, measured with perf).
pub(crate) fn written_zeros(n: usize) -> Vec<f32> {
    let mut v = vec![0f32; n];
    std::hint::black_box(v.as_mut_slice()).fill(0.0);
    v
}

/// `c (m x n, row stride rsc) = beta · c + a (m x k) · b (k x n)` with strides (row, column)
/// for a and b.
#[allow(clippy::too_many_arguments)]
fn gemm(
    (m, k, n): (usize, usize, usize),
    a: &[f32],
    (rsa, csa): (isize, isize),
    b: &[f32],
    (rsb, csb): (isize, isize),
    beta: f32,
    c: &mut [f32],
    rsc: usize,
) {
    let extent = |rs: isize, cs: isize, r: usize, cc: usize| {
        (r.saturating_sub(1)) as isize * rs + (cc.saturating_sub(1)) as isize * cs + 1
    };
    assert!(
        extent(rsa, csa, m, k) <= a.len() as isize
            && extent(rsb, csb, k, n) <= b.len() as isize
            && (m == 0 || n == 0 || (m - 1) * rsc + n <= c.len())
            && rsc >= n,
        "gemm operands smaller than their shapes"
    );
    // SAFETY: the assertion above: a, b and c hold their strided extents (all strides are
    // non-negative), and c's rows do not overlap.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            rsa,
            csa,
            b.as_ptr(),
            rsb,
            csb,
            beta,
            c.as_mut_ptr(),
            rsc as isize,
            1,
        );
    }
}

/// Convolution forward: `out[co] = b[co] + Σ W[co] · im2col(inp)`, `cout x (h · w)`, a band of
/// pixels at a time.
fn conv_forward(p: &[f32], cv: &Conv, inp: &[f32], h: usize, w: usize) -> Vec<f32> {
    if cv.k == 3 && conv::available() {
        let kk = cv.cin * 9;
        let (wt, b) = (&p[cv.w..cv.w + cv.cout * kk], &p[cv.b..cv.b + cv.cout]);
        return conv::forward(wt, b, inp, (cv.cin, cv.cout), (h, w));
    }
    let nb = band_px(cv.cin * cv.k * cv.k, h * w);
    conv_forward_bands(p, cv, inp, (h, w), nb)
}

/// [`conv_forward`] in bands of `nb` pixels.
fn conv_forward_bands(
    p: &[f32],
    cv: &Conv,
    inp: &[f32],
    (h, w): (usize, usize),
    nb: usize,
) -> Vec<f32> {
    let hw = h * w;
    let kk = cv.cin * cv.k * cv.k;
    debug_assert!(cv.w + cv.cout * kk <= p.len() && cv.b + cv.cout <= p.len());
    let mut out = vec![0f32; cv.cout * hw];
    for (co, o) in out.chunks_mut(hw).enumerate() {
        o.fill(p[cv.b + co]);
    }
    let wt = &p[cv.w..cv.w + cv.cout * kk];
    with_columns(kk * nb, |col| {
        for p0 in (0..hw).step_by(nb) {
            let p1 = (p0 + nb).min(hw);
            let col = &mut col[..kk * (p1 - p0)];
            im2col_band(inp, cv.cin, h, w, cv.k, (p0, p1), col);
            gemm(
                (cv.cout, kk, p1 - p0),
                wt,
                (kk as isize, 1),
                col,
                ((p1 - p0) as isize, 1),
                1.0,
                &mut out[p0..],
                hw,
            );
        }
    });
    out
}

/// Convolution backward: adds dW, db into `dp` and dL/dinput into `dinp`, a band of pixels at a
/// time (the weight gradient from the first band to the last, the input gradient from the last
/// to the first: both add their terms in the order of the whole-image products).
#[allow(clippy::too_many_arguments)]
fn conv_backward(
    p: &[f32],
    cv: &Conv,
    inp: &[f32],
    h: usize,
    w: usize,
    dout: &[f32],
    dp: &mut [f32],
    dinp: &mut [f32],
) {
    let nb = band_px(cv.cin * cv.k * cv.k, h * w);
    if cv.k == 3 && conv::available() {
        let dw = &mut dp[cv.w..cv.w + cv.cout * cv.cin * 9];
        conv::weight_gradient(inp, dout, (cv.cin, cv.cout), (h, w), dw);
        bias_gradient(dout, h * w, &mut dp[cv.b..cv.b + cv.cout]);
        let wt = &p[cv.w..cv.w + cv.cout * cv.cin * 9];
        conv::input_gradient(wt, dout, (cv.cin, cv.cout), (h, w), dinp);
    } else {
        conv_backward_bands(p, cv, inp, (h, w), dout, dp, dinp, nb);
    }
}

/// [`conv_backward`] in bands of `nb` pixels (a multiple of 256 for the same weight gradient).
#[allow(clippy::too_many_arguments)]
fn conv_backward_bands(
    p: &[f32],
    cv: &Conv,
    inp: &[f32],
    (h, w): (usize, usize),
    dout: &[f32],
    dp: &mut [f32],
    dinp: &mut [f32],
    nb: usize,
) {
    weight_gradient_bands(cv, inp, (h, w), dout, dp, nb);
    input_gradient_bands(p, cv, (h, w), dout, dinp, nb);
}

/// Adds dW and db of a convolution into `dp`, im2col in bands of `nb` pixels: dW (cout x kk) +=
/// dout (cout x hw) · colᵀ (hw x kk), the bands from the first to the last.
fn weight_gradient_bands(
    cv: &Conv,
    inp: &[f32],
    (h, w): (usize, usize),
    dout: &[f32],
    dp: &mut [f32],
    nb: usize,
) {
    let hw = h * w;
    let kk = cv.cin * cv.k * cv.k;
    debug_assert_eq!(
        dout.len(),
        cv.cout * hw,
        "the output gradient is cout x h x w"
    );
    with_columns(kk * nb, |col| {
        for p0 in (0..hw).step_by(nb) {
            let p1 = (p0 + nb).min(hw);
            let col = &mut col[..kk * (p1 - p0)];
            im2col_band(inp, cv.cin, h, w, cv.k, (p0, p1), col);
            gemm(
                (cv.cout, p1 - p0, kk),
                &dout[p0..],
                (hw as isize, 1),
                col,
                (1, (p1 - p0) as isize),
                1.0,
                &mut dp[cv.w..cv.w + cv.cout * kk],
                kk,
            );
        }
    });
    bias_gradient(dout, hw, &mut dp[cv.b..cv.b + cv.cout]);
}

/// Adds each channel's sum of `dout` (`db.len() x hw`) into `db`: in pixel order, as a
/// sequential sum adds them, the channels' chains interleaved so that they overlap.
fn bias_gradient(dout: &[f32], hw: usize, db: &mut [f32]) {
    debug_assert_eq!(
        dout.len(),
        db.len() * hw,
        "the output gradient is cout x h x w"
    );
    let mut s = vec![-0.0f32; db.len()];
    for p in 0..hw {
        for (co, v) in s.iter_mut().enumerate() {
            *v += dout[co * hw + p];
        }
    }
    db.iter_mut().zip(&s).for_each(|(d, v)| *d += v);
}

/// Adds dL/dinput of a convolution into `dinp`: dcol (kk x band) = Wᵀ (kk x cout) · dout (cout x
/// band), added back by col2im, the bands from the last to the first.
fn input_gradient_bands(
    p: &[f32],
    cv: &Conv,
    (h, w): (usize, usize),
    dout: &[f32],
    dinp: &mut [f32],
    nb: usize,
) {
    let hw = h * w;
    let kk = cv.cin * cv.k * cv.k;
    let wt = &p[cv.w..cv.w + cv.cout * kk];
    with_columns(kk * nb, |col| {
        for p0 in (0..hw).step_by(nb).rev() {
            let p1 = (p0 + nb).min(hw);
            let dcol = &mut col[..kk * (p1 - p0)];
            gemm(
                (kk, cv.cout, p1 - p0),
                wt,
                (1, kk as isize),
                &dout[p0..],
                (hw as isize, 1),
                0.0,
                dcol,
                p1 - p0,
            );
            col2im_band(dcol, cv.cin, h, w, cv.k, (p0, p1), dinp);
        }
    });
}

fn relu(v: &mut [f32]) {
    v.iter_mut().for_each(|x| *x = x.max(0.0));
}

/// dL/dpre-activation of a ReLU from dL/dout and its output.
fn relu_backward(dout: &mut [f32], out: &[f32]) {
    for (d, o) in dout.iter_mut().zip(out) {
        if *o <= 0.0 {
            *d = 0.0;
        }
    }
}

/// 2x2 average pooling of `c x h x w`.
fn pool(inp: &[f32], c: usize, h: usize, w: usize) -> Vec<f32> {
    let (h2, w2) = (h / 2, w / 2);
    let mut out = vec![0f32; c * h2 * w2];
    for ch in 0..c {
        for y in 0..h2 {
            for x in 0..w2 {
                let i = ch * h * w + 2 * y * w + 2 * x;
                out[ch * h2 * w2 + y * w2 + x] =
                    0.25 * (inp[i] + inp[i + 1] + inp[i + w] + inp[i + w + 1]);
            }
        }
    }
    out
}

/// Adjoint of [`pool`]: adds into `dinp`.
fn pool_backward(dout: &[f32], c: usize, h: usize, w: usize, dinp: &mut [f32]) {
    let (h2, w2) = (h / 2, w / 2);
    for ch in 0..c {
        for y in 0..h2 {
            for x in 0..w2 {
                let g = 0.25 * dout[ch * h2 * w2 + y * w2 + x];
                let i = ch * h * w + 2 * y * w + 2 * x;
                for j in [i, i + 1, i + w, i + w + 1] {
                    dinp[j] += g;
                }
            }
        }
    }
}

/// Nearest 2x upsampling of `c x h x w`.
fn up(inp: &[f32], c: usize, h: usize, w: usize) -> Vec<f32> {
    let (h2, w2) = (2 * h, 2 * w);
    let mut out = vec![0f32; c * h2 * w2];
    for ch in 0..c {
        for y in 0..h2 {
            for x in 0..w2 {
                out[ch * h2 * w2 + y * w2 + x] = inp[ch * h * w + (y / 2) * w + x / 2];
            }
        }
    }
    out
}

/// Adjoint of [`up`] (from the upsampled size `2h x 2w`): adds into `dinp`.
fn up_backward(dout: &[f32], c: usize, h: usize, w: usize, dinp: &mut [f32]) {
    let (h2, w2) = (2 * h, 2 * w);
    for ch in 0..c {
        for y in 0..h2 {
            for x in 0..w2 {
                dinp[ch * h * w + (y / 2) * w + x / 2] += dout[ch * h2 * w2 + y * w2 + x];
            }
        }
    }
}

/// Widest U-Net accepted (first-level channels): width 256 at 3 levels is ~250 M parameters.
pub const MAX_WIDTH: usize = 256;

/// The convolutions of a U-Net of shape `cfg`, in parameter order: (inputs, outputs, kernel
/// side).
fn layers(cfg: UnetConfig) -> Vec<(usize, usize, usize)> {
    let ch = |l: usize| cfg.width << l;
    let mut out = Vec::new();
    let mut cin = cfg.in_channels;
    for l in 0..=cfg.levels {
        out.push((cin, ch(l), 3));
        out.push((ch(l), ch(l), 3));
        cin = ch(l);
    }
    for l in (0..cfg.levels).rev() {
        out.push((ch(l + 1) + ch(l), ch(l), 3));
        out.push((ch(l), ch(l), 3));
    }
    out.push((cfg.width, 3, 1));
    out
}

/// Number of parameters of a U-Net of shape `cfg`, without building it; `None` for a shape
/// [`Unet::new`] refuses.
pub fn param_count(cfg: UnetConfig) -> Option<usize> {
    check_config(cfg).ok()?;
    Some(layers(cfg).iter().map(|&(i, o, k)| o * i * k * k + o).sum())
}

fn check_config(cfg: UnetConfig) -> Result<()> {
    if cfg.width == 0
        || cfg.width > MAX_WIDTH
        || cfg.in_channels == 0
        || cfg.in_channels > 64
        || cfg.levels > 6
    {
        return Err(Error::argument(format!(
            "U-Net {cfg:?}: width must be 1 to {MAX_WIDTH}, inputs 1 to 64, at most 6 levels"
        )));
    }
    Ok(())
}

impl Unet {
    /// A network of shape `cfg` with He-initialised weights from `seed`, zero biases and a zero
    /// output layer.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for a width outside 1 to [`MAX_WIDTH`], inputs outside 1 to
    /// 64, or more than 6 levels.
    pub fn new(cfg: UnetConfig, seed: u64) -> Result<Unet> {
        check_config(cfg)?;
        let mut convs = Vec::new();
        let mut n = 0;
        for (cin, cout, k) in layers(cfg) {
            let c = Conv {
                cin,
                cout,
                k,
                w: n,
                b: n + cout * cin * k * k,
            };
            n = c.b + cout;
            convs.push(c);
        }
        let mut params = vec![0f32; n];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let last = convs.len() - 1;
        for (i, c) in convs.iter().enumerate() {
            if i == last {
                continue;
            }
            let std = (2.0 / (c.cin * c.k * c.k) as f32).sqrt();
            for v in &mut params[c.w..c.b] {
                *v = crate::math::normal::scaled_f32(&mut rng, std);
            }
        }
        Ok(Unet { cfg, convs, params })
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.params.len()
    }

    /// Checks that `len` values are `n` images of the input channels x `h` x `w` that pass
    /// through the levels ([`Unet::check_size`]).
    pub(crate) fn check(&self, len: usize, n: usize, h: usize, w: usize) -> Result<()> {
        self.check_size(h, w)?;
        if len != n * self.cfg.in_channels * h * w {
            return Err(Error::argument(format!(
                "U-Net: {len} values for {n} x {} x {h}x{w}",
                self.cfg.in_channels
            )));
        }
        Ok(())
    }

    /// Checks that an image of `w` x `h` px passes through the U-Net's levels: both sizes
    /// positive multiples of 2^levels.
    pub(crate) fn check_size(&self, h: usize, w: usize) -> Result<()> {
        let m = 1 << self.cfg.levels;
        if h == 0 || w == 0 || !h.is_multiple_of(m) || !w.is_multiple_of(m) {
            return Err(Error::argument(format!(
                "U-Net: an image of {w}x{h} px; its width and height must be multiples of {m} \
                 (2 to the power of its {} levels)",
                self.cfg.levels
            )));
        }
        Ok(())
    }

    /// One sample forward; with `keep`, the cache its backward pass needs (without, the cache
    /// is empty and no activation outlives its use).
    pub(crate) fn forward_one(
        &self,
        x: &[f32],
        h: usize,
        w: usize,
        keep: bool,
    ) -> (Vec<f32>, Cache) {
        let p = &self.params;
        let (mut ins, mut outs) = (Vec::new(), Vec::new());
        let mut ci = 0;
        let mut conv_relu =
            |x: Vec<f32>, h: usize, w: usize, ins: &mut Vec<Vec<f32>>, outs: &mut Vec<Vec<f32>>| {
                let mut o = conv_forward(p, &self.convs[ci], &x, h, w);
                relu(&mut o);
                if keep {
                    ins.push(x);
                    outs.push(o.clone());
                }
                ci += 1;
                o
            };
        let ch = |l: usize| self.cfg.width << l;
        let (mut x, mut hh, mut ww) = (x.to_vec(), h, w);
        let mut skips = Vec::new();
        for l in 0..=self.cfg.levels {
            let a = conv_relu(x, hh, ww, &mut ins, &mut outs);
            let b = conv_relu(a, hh, ww, &mut ins, &mut outs);
            if l < self.cfg.levels {
                skips.push(b.clone());
                x = pool(&b, ch(l), hh, ww);
                hh /= 2;
                ww /= 2;
            } else {
                x = b;
            }
        }
        for l in (0..self.cfg.levels).rev() {
            let mut u = up(&x, ch(l + 1), hh, ww);
            hh *= 2;
            ww *= 2;
            u.extend_from_slice(&skips[l]);
            let a = conv_relu(u, hh, ww, &mut ins, &mut outs);
            x = conv_relu(a, hh, ww, &mut ins, &mut outs);
        }
        let out = conv_forward(p, &self.convs[self.convs.len() - 1], &x, h, w);
        if keep {
            ins.push(x);
        }
        (out, Cache { h, w, ins, outs })
    }

    /// One sample backward from the cache of [`Unet::forward_one`] with `keep`: adds dL/dparams
    /// into `dp` and returns dL/dinput.
    pub(crate) fn backward_one(&self, cache: &Cache, dout: &[f32], dp: &mut [f32]) -> Vec<f32> {
        let p = &self.params;
        let (h, w, l_n) = (cache.h, cache.w, self.cfg.levels);
        let ch = |l: usize| self.cfg.width << l;
        let nc = self.convs.len();
        // Output layer.
        let mut dx = written_zeros(cache.ins[nc - 1].len());
        conv_backward(
            p,
            &self.convs[nc - 1],
            &cache.ins[nc - 1],
            h,
            w,
            dout,
            dp,
            &mut dx,
        );
        // A ReLU convolution backward: from dL/dout to dL/dinput.
        let back = |i: usize, mut d: Vec<f32>, hh: usize, ww: usize, dp: &mut [f32]| {
            relu_backward(&mut d, &cache.outs[i]);
            let mut di = written_zeros(cache.ins[i].len());
            conv_backward(p, &self.convs[i], &cache.ins[i], hh, ww, &d, dp, &mut di);
            di
        };
        let mut dskips: Vec<Vec<f32>> = (0..l_n).map(|_| Vec::new()).collect();
        let (mut hh, mut ww) = (h, w);
        let mut i = nc - 1;
        for l in 0..l_n {
            i -= 2;
            let da = back(i + 1, dx, hh, ww, dp);
            let dcat = back(i, da, hh, ww, dp);
            let nu = ch(l + 1) * hh * ww;
            dskips[l] = dcat[nu..].to_vec();
            let mut dprev = written_zeros(ch(l + 1) * (hh / 2) * (ww / 2));
            up_backward(&dcat[..nu], ch(l + 1), hh / 2, ww / 2, &mut dprev);
            dx = dprev;
            hh /= 2;
            ww /= 2;
        }
        for l in (0..=l_n).rev() {
            if l < l_n {
                // dx is dL/d(pooled b); add the skip's gradient to dL/db.
                let mut db = dskips[l].clone();
                pool_backward(&dx, ch(l), hh * 2, ww * 2, &mut db);
                dx = db;
                hh *= 2;
                ww *= 2;
            }
            i -= 2;
            let da = back(i + 1, dx, hh, ww, dp);
            dx = back(i, da, hh, ww, dp);
        }
        dx
    }

    /// Forward pass over a batch `input` of `n` samples of `in_channels x h x w`; returns the
    /// `n x 3 x h x w` output and the caches.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for sizes that do not fit.
    pub fn forward(
        &self,
        input: &[f32],
        n: usize,
        h: usize,
        w: usize,
    ) -> Result<(Vec<f32>, Vec<Cache>)> {
        self.check(input.len(), n, h, w)?;
        let k = self.cfg.in_channels * h * w;
        let per: Vec<(Vec<f32>, Cache)> = (0..n)
            .into_par_iter()
            .map(|j| self.forward_one(&input[j * k..(j + 1) * k], h, w, true))
            .collect();
        let mut out = Vec::with_capacity(n * 3 * h * w);
        let mut caches = Vec::with_capacity(n);
        for (o, c) in per {
            out.extend(o);
            caches.push(c);
        }
        Ok((out, caches))
    }

    /// Forward pass without caches: the `n x 3 x h x w` output of [`Unet::forward`], each
    /// sample's activations freed as it goes.
    ///
    /// ```
    /// use tolray::decoder::unet::{Unet, UnetConfig};
    /// let mut u = Unet::new(UnetConfig { in_channels: 3, width: 2, levels: 1 }, 0)?;
    /// u.params.iter_mut().for_each(|p| *p += 0.05); // a new U-Net's output layer is zero
    /// let x: Vec<f32> = (0..2 * 3 * 4 * 4).map(|i| (i % 7) as f32 / 7.0).collect();
    /// let (out, _caches) = u.forward(&x, 2, 4, 4)?;
    /// assert!(out.iter().any(|&v| v != 0.0));
    /// assert_eq!(u.infer(&x, 2, 4, 4)?, out);
    /// # Ok::<(), tolray::Error>(())
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for sizes that do not fit.
    pub fn infer(&self, input: &[f32], n: usize, h: usize, w: usize) -> Result<Vec<f32>> {
        self.check(input.len(), n, h, w)?;
        let k = self.cfg.in_channels * h * w;
        let per: Vec<Vec<f32>> = (0..n)
            .into_par_iter()
            .map(|j| self.forward_one(&input[j * k..(j + 1) * k], h, w, false).0)
            .collect();
        Ok(per.concat())
    }

    /// Backward pass: adds dL/dparams into `dparams` (summed over samples in sample order) and
    /// writes dL/dinput (`n x in_channels x h x w`) into `dinput`.
    pub fn backward(
        &self,
        caches: &[Cache],
        dout: &[f32],
        dparams: &mut [f32],
        dinput: &mut [f32],
    ) {
        let n = caches.len();
        if n == 0 {
            return;
        }
        let m = 3 * caches[0].h * caches[0].w;
        let per: Vec<(Vec<f32>, Vec<f32>)> = caches
            .par_iter()
            .enumerate()
            .map(|(j, c)| {
                let mut dp = vec![0f32; self.params.len()];
                let dx = self.backward_one(c, &dout[j * m..(j + 1) * m], &mut dp);
                (dp, dx)
            })
            .collect();
        let k = dinput.len() / n;
        for (j, (dp, dx)) in per.into_iter().enumerate() {
            for (a, b) in dparams.iter_mut().zip(&dp) {
                *a += b;
            }
            dinput[j * k..(j + 1) * k].copy_from_slice(&dx);
        }
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
                (s >> 8) as f32 / (1 << 24) as f32 - 0.5
            })
            .collect()
    }

    /// L = Σ out · g in f64.
    fn loss(u: &Unet, x: &[f32], n: usize, h: usize, w: usize, g: &[f32]) -> f64 {
        let (o, _) = u.forward(x, n, h, w).unwrap();
        o.iter().zip(g).map(|(a, b)| *a as f64 * *b as f64).sum()
    }

    #[test]
    fn gradients_match_central_differences_and_layers_are_adjoint() {
        let cfg = UnetConfig {
            in_channels: 3,
            width: 2,
            levels: 2,
        };
        let mut u = Unet::new(cfg, 5).unwrap();
        // A nonzero output layer and biases, so that every path carries gradient.
        let n_p = u.params.len();
        for (k, v) in u.params.iter_mut().enumerate() {
            if *v == 0.0 {
                *v = 0.05 * (((k * 7919) % 13) as f32 / 13.0 - 0.4);
            }
        }
        let (n, h, w) = (2, 8, 8);
        let x = lcg(n * 3 * h * w, 1);
        let g = lcg(n * 3 * h * w, 2);
        let (_, caches) = u.forward(&x, n, h, w).unwrap();
        let mut dp = vec![0f32; n_p];
        let mut dx = vec![0f32; x.len()];
        u.backward(&caches, &g, &mut dp, &mut dx);
        let check = |fd: f64, an: f32, what: String| {
            assert!(
                (fd - an as f64).abs() < 2e-2 * fd.abs().max(0.05),
                "{what}: FD {fd} vs {an}"
            );
        };
        for k in (0..x.len()).step_by(37) {
            let e = 1e-2;
            let (mut a, mut b) = (x.clone(), x.clone());
            a[k] += e;
            b[k] -= e;
            check(
                (loss(&u, &a, n, h, w, &g) - loss(&u, &b, n, h, w, &g)) / (2.0 * e as f64),
                dx[k],
                format!("input {k}"),
            );
        }
        for c in &u.convs {
            for k in [c.w, c.w + (c.b - c.w) / 2, c.b] {
                // A bias moves every pre-activation of its channel: steps of 1e-2 carry some across
                // a ReLU kink, steps below 1e-3 drown in f32 rounding (measured on this net).
                let e = 1e-3;
                let (mut a, mut b) = (u.clone(), u.clone());
                a.params[k] += e;
                b.params[k] -= e;
                check(
                    (loss(&a, &x, n, h, w, &g) - loss(&b, &x, n, h, w, &g)) / (2.0 * e as f64),
                    dp[k],
                    format!("param {k}"),
                );
            }
        }
        // Pooling and upsampling are each other's adjoint up to a factor 4: <up x, y> = 4 <x, pool y>.
        let (a, b) = (lcg(2 * 4 * 4, 3), lcg(2 * 8 * 8, 4));
        let lhs: f32 = up(&a, 2, 4, 4).iter().zip(&b).map(|(p, q)| p * q).sum();
        let rhs: f32 = a.iter().zip(pool(&b, 2, 8, 8)).map(|(p, q)| p * q).sum();
        assert!((lhs - 4.0 * rhs).abs() < 1e-4);
    }

    /// Convolutions band by band give the bits of one band over the whole image (the weight
    /// gradient in bands of 256 pixels, the input gradient added from the last band to the
    /// first), and agree with a direct convolution in f64; bands end inside image rows.
    #[test]
    fn convolutions_in_bands_equal_one_band_and_the_direct_sum() {
        for (cin, cout, k, h, w) in [(5, 8, 3, 40, 48), (3, 4, 3, 17, 31), (8, 3, 1, 20, 30)] {
            let cv = Conv {
                cin,
                cout,
                k,
                w: 0,
                b: cout * cin * k * k,
            };
            let p = lcg(cv.b + cout, 21);
            let hw = h * w;
            let inp = lcg(cin * hw, 22);
            let dout = lcg(cout * hw, 23);
            let run = |nb: usize| {
                let out = conv_forward_bands(&p, &cv, &inp, (h, w), nb);
                let (mut dp, mut dinp) = (vec![0f32; p.len()], vec![0f32; inp.len()]);
                conv_backward_bands(&p, &cv, &inp, (h, w), &dout, &mut dp, &mut dinp, nb);
                (out, dp, dinp)
            };
            let whole = run(hw);
            assert!(hw > 2 * 256 && hw % 256 != 0 && 256 % w != 0);
            assert_eq!(run(256), whole, "{cin}x{cout} k{k} {h}x{w}");
            // Forward and input gradient in any band width.
            let odd = run(100);
            assert_eq!((&odd.0, &odd.2), (&whole.0, &whole.2));
            // The direct sums, in f64.
            let r = (k / 2) as isize;
            let at = |c: usize, y: isize, x: isize| {
                if y < 0 || x < 0 || y >= h as isize || x >= w as isize {
                    0.0
                } else {
                    inp[c * hw + y as usize * w + x as usize] as f64
                }
            };
            let wgt = |co: usize, c: usize, ky: usize, kx: usize| {
                p[((co * cin + c) * k + ky) * k + kx] as f64
            };
            for (q, &o) in whole.0.iter().enumerate().step_by(7) {
                let (co, y, x) = (q / hw, ((q % hw) / w) as isize, (q % w) as isize);
                let mut s = p[cv.b + co] as f64;
                for c in 0..cin {
                    for ky in 0..k {
                        for kx in 0..k {
                            s += wgt(co, c, ky, kx)
                                * at(c, y + ky as isize - r, x + kx as isize - r);
                        }
                    }
                }
                assert!((s - o as f64).abs() < 1e-5, "out {q}: {s} vs {o}");
            }
            for (q, &d) in whole.2.iter().enumerate().step_by(5) {
                let (c, y, x) = (q / hw, (q % hw) / w, q % w);
                let mut s = 0.0;
                for co in 0..cout {
                    for ky in 0..k {
                        for kx in 0..k {
                            let (oy, ox) =
                                (y as isize - ky as isize + r, x as isize - kx as isize + r);
                            if oy >= 0 && ox >= 0 && oy < h as isize && ox < w as isize {
                                let g = dout[co * hw + oy as usize * w + ox as usize] as f64;
                                s += wgt(co, c, ky, kx) * g;
                            }
                        }
                    }
                }
                assert!((s - d as f64).abs() < 1e-5, "dinput {q}: {s} vs {d}");
            }
        }
    }

    /// The direct 3x3 convolutions (AVX2 + FMA) give the values of im2col + SGEMM: the forward
    /// pass and the input gradient, with chains longer than the SGEMM's 256-deep blocks (cin · 9
    /// > 256 forward, cout > 256 backward), widths from 1 to above a vector, and odd sizes.
    #[test]
    fn direct_convolutions_equal_im2col_and_sgemm() {
        if !conv::available() {
            eprintln!("no AVX2 + FMA: the direct convolutions do not run here");
            return;
        }
        let shapes = [
            (8, 8, 32, 32),
            (24, 8, 16, 16),
            (5, 7, 9, 13),
            (30, 5, 6, 7),
            (3, 260, 4, 5),
            (64, 32, 8, 8),
            (1, 1, 1, 1),
            (2, 3, 3, 1),
            (4, 9, 23, 29),
        ];
        for (cin, cout, h, w) in shapes {
            let cv = Conv {
                cin,
                cout,
                k: 3,
                w: 0,
                b: cout * cin * 9,
            };
            let p = lcg(cv.b + cout, 31);
            let inp = lcg(cin * h * w, 32);
            let dout = lcg(cout * h * w, 33);
            let nb = band_px(cin * 9, h * w);
            let gemm_out = conv_forward_bands(&p, &cv, &inp, (h, w), nb);
            let direct_out = conv_forward(&p, &cv, &inp, h, w);
            assert!(gemm_out.iter().any(|&v| v != 0.0));
            assert_eq!(direct_out, gemm_out, "forward {cin}x{cout} {h}x{w}");
            let mut gemm_d = lcg(cin * h * w, 34);
            let mut direct_d = gemm_d.clone();
            input_gradient_bands(&p, &cv, (h, w), &dout, &mut gemm_d, nb);
            conv::input_gradient(&p[..cv.b], &dout, (cin, cout), (h, w), &mut direct_d);
            assert_eq!(direct_d, gemm_d, "input gradient {cin}x{cout} {h}x{w}");
            let mut gemm_dp = lcg(p.len(), 35);
            let mut direct_dp = gemm_dp.clone();
            weight_gradient_bands(&cv, &inp, (h, w), &dout, &mut gemm_dp, nb);
            conv::weight_gradient(&inp, &dout, (cin, cout), (h, w), &mut direct_dp[..cv.b]);
            // (The biases here by a plain sequential sum, there by `bias_gradient`.)
            for (co, d) in dout.chunks(h * w).enumerate() {
                direct_dp[cv.b + co] += d.iter().sum::<f32>();
            }
            assert_eq!(direct_dp, gemm_dp, "weight gradient {cin}x{cout} {h}x{w}");
        }
    }

    #[test]
    fn starts_as_zero_and_is_thread_count_free() {
        let u = Unet::new(
            UnetConfig {
                in_channels: 8,
                width: 4,
                levels: 3,
            },
            1,
        )
        .unwrap();
        let x = lcg(3 * 8 * 16 * 16, 9);
        let (o, _) = u.forward(&x, 3, 16, 16).unwrap();
        assert!(o.iter().all(|&v| v == 0.0));
        assert!(u.forward(&x, 3, 12, 16).is_err());
        let mut v = u.clone();
        v.params.iter_mut().for_each(|p| *p += 0.01);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let (o, c) = v.forward(&x, 3, 16, 16).unwrap();
                let mut dp = vec![0f32; v.params.len()];
                let mut dx = vec![0f32; x.len()];
                v.backward(&c, &o, &mut dp, &mut dx);
                (o, dp, dx)
            })
        };
        assert_eq!(run(1), run(2));
    }
}
