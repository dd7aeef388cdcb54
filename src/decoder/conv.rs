//! Direct 3x3 convolutions for the U-Net on x86-64 with AVX2 and FMA: the forward pass and the
//! input gradient read a zero-padded copy of their input instead of im2col, and compute the same
//! sums as im2col + matrixmultiply's SGEMM term for term.
//!
//! Why by hand (ARCHITECTURE.md): at the U-Net's 8 to 64 channels the SGEMM's operands are thin,
//! and im2col (nine copies of the input), the SGEMM's packing and col2im moved more memory than
//! the products needed. Here each output is a chain of fused multiply-adds read straight from
//! the padded planes, eight 8-lane chains at a time in registers.
//!
//! **The same sums.** matrixmultiply's FMA kernels (AVX2 and AVX-512) compute each element of
//! `C = A B` as a chain `acc = fma(a_k, b_k, acc)` from zero over each block of 256 values of k
//! (its `KC`), and add each block's chain to C in order (`C = C + acc`; C is the bias in the
//! forward pass). The input gradient was `dcol = Wᵀ · dout` (a chain over the output channels)
//! added into the input gradient tap by tap in (ky, kx) order by col2im. This module forms the
//! same chains in the same order and adds them in the same order, so the values are equal; only
//! the sign of a zero can differ (the SGEMM's `fma(1, acc, 0)` turns -0 into +0, and a padded
//! tap adds a +0 where col2im skipped it), which no later operation of the network tells apart.
//! `tests` in `unet.rs` compare the two paths value for value.
//!
//! **Layout.** A channel plane is the image with a border of zeros, `(h + 2)` rows of `w + 2`
//! values (plus slack). Output position `q = y (w + 2) + x` reads tap (ky, kx) at plane index
//! `q + ky (w + 2) + kx`, so every chain runs over contiguous memory whatever the width; the two
//! positions per row with `x >= w` are computed and dropped.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// matrixmultiply's SGEMM depth block (`S_KC` in matrixmultiply 0.3): the chains restart at
/// each multiple of it.
const KC: usize = 256;
/// `f32` lanes of a 256-bit vector.
const V: usize = 8;

/// Whether the direct convolutions run: x86-64 with AVX2 and FMA, unless the baseline build is
/// forced (`TOLRAY_SIMD=baseline` or [`crate::trace::simd::set_active`]), which runs im2col +
/// SGEMM instead (the same values: see the module's documentation).
pub(crate) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        crate::trace::simd::active() != crate::trace::simd::Isa::Baseline
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The padded geometry of an `h x w` image.
#[derive(Clone, Copy, Debug)]
struct Grid {
    h: usize,
    w: usize,
    /// Padded row length, `w + 2`.
    wp: usize,
    /// Output positions computed, `h · wp` rounded up to whole vectors.
    nq: usize,
    /// Values per padded plane: every tap of every computed position inside it.
    plane: usize,
}

impl Grid {
    fn new(h: usize, w: usize) -> Grid {
        let wp = w + 2;
        let nq = (h * wp).div_ceil(V) * V;
        Grid {
            h,
            w,
            wp,
            nq,
            plane: nq + 2 * wp + 2 + V,
        }
    }

    /// Writes `c` channels of `src` (`c x h x w`) into zero-bordered planes at `dst`, the image
    /// at row 1 and column 1 of each plane (only the border and the slack are zeroed).
    fn pad(&self, src: &[f32], c: usize, dst: &mut [f32]) {
        let (h, w, wp) = (self.h, self.w, self.wp);
        debug_assert!(src.len() == c * h * w && dst.len() == c * self.plane);
        for (s, d) in src
            .chunks_exact(h * w)
            .zip(dst.chunks_exact_mut(self.plane))
        {
            d[..wp + 1].fill(0.0);
            for (y, row) in s.chunks_exact(w).enumerate() {
                let at = (y + 1) * wp + 1;
                d[at..at + w].copy_from_slice(row);
                // This row's right border and the next row's left border.
                d[at + w..at + w + 2].fill(0.0);
            }
            d[(h + 1) * wp + 1..].fill(0.0);
        }
    }

    /// The inverse of [`Grid::pad`] without its offset, for rows of `nq` positions: `c` channels of
    /// `src` (`c x nq`) into `dst` (`c x h x w`).
    fn unpad(&self, src: &[f32], c: usize, dst: &mut [f32]) {
        let (h, w, wp) = (self.h, self.w, self.wp);
        debug_assert!(src.len() == c * self.nq && dst.len() == c * h * w);
        for (s, d) in src.chunks_exact(self.nq).zip(dst.chunks_exact_mut(h * w)) {
            for (y, row) in d.chunks_exact_mut(w).enumerate() {
                row.copy_from_slice(&s[y * wp..y * wp + w]);
            }
        }
    }
}

thread_local! {
    /// Each thread's padded planes and output rows, kept between convolutions.
    static BUFFERS: std::cell::RefCell<(Vec<f32>, Vec<f32>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// Runs `f` on this thread's two buffers of `a` and `b` values (fresh ones if in use).
fn with_buffers<R>(a: usize, b: usize, f: impl FnOnce(&mut [f32], &mut [f32]) -> R) -> R {
    BUFFERS.with(|cell| match cell.try_borrow_mut() {
        Ok(mut v) => {
            let (x, y) = &mut *v;
            if x.len() < a {
                x.resize(a, 0.0);
            }
            if y.len() < b {
                y.resize(b, 0.0);
            }
            f(&mut x[..a], &mut y[..b])
        }
        Err(_) => f(&mut vec![0f32; a], &mut vec![0f32; b]),
    })
}

/// One sum of chains: for output row r and position q, `Σ_k w[k · ldw + r] · src[off[k] + q]`.
struct Chains<'a> {
    off: &'a [usize],
    w: &'a [f32],
    ldw: usize,
}

/// The 3x3 convolution (zero padding 1) of `inp` (`cin x h x w`) by `wt` (`cout x cin x 3 x 3`)
/// plus `bias` (`cout`): `cout x h x w`, the values of im2col + SGEMM.
///
/// # Panics
/// If [`available`] is false or the slices do not have these lengths.
pub(crate) fn forward(
    wt: &[f32],
    bias: &[f32],
    inp: &[f32],
    (cin, cout): (usize, usize),
    (h, w): (usize, usize),
) -> Vec<f32> {
    let kk = cin * 9;
    assert!(
        available() && wt.len() == cout * kk && bias.len() == cout && inp.len() == cin * h * w,
        "direct convolution: operands do not fit"
    );
    let g = Grid::new(h, w);
    let mut wtt = vec![0f32; kk * cout];
    for (co, row) in wt.chunks_exact(kk).enumerate() {
        for (k, &v) in row.iter().enumerate() {
            wtt[k * cout + co] = v;
        }
    }
    let off: Vec<usize> = (0..kk)
        .map(|k| (k / 9) * g.plane + (k % 9 / 3) * g.wp + k % 3)
        .collect();
    let chains = [Chains {
        off: &off,
        w: &wtt,
        ldw: cout,
    }];
    let mut out = vec![0f32; cout * h * w];
    with_buffers(cin * g.plane, cout * g.nq, |planes, acc| {
        g.pad(inp, cin, planes);
        for (a, &b) in acc.chunks_exact_mut(g.nq).zip(bias) {
            a.fill(b);
        }
        run(planes, &chains, true, acc, g.nq, cout);
        g.unpad(acc, cout, &mut out);
    });
    out
}

/// Adds the input gradient of [`forward`] for the output gradient `dout` (`cout x h x w`) into
/// `dinp` (`cin x h x w`): per input value, the nine taps in (ky, kx) order, each a chain over
/// the output channels, as col2im adds `Wᵀ · dout`.
///
/// # Panics
/// If [`available`] is false or the slices do not have these lengths.
pub(crate) fn input_gradient(
    wt: &[f32],
    dout: &[f32],
    (cin, cout): (usize, usize),
    (h, w): (usize, usize),
    dinp: &mut [f32],
) {
    let kk = cin * 9;
    assert!(
        available()
            && wt.len() == cout * kk
            && dout.len() == cout * h * w
            && dinp.len() == cin * h * w,
        "direct convolution gradient: operands do not fit"
    );
    let g = Grid::new(h, w);
    // Tap t = (ky, kx) of input position q reads the output gradient at (y + 1 - ky, x + 1 - kx),
    // which is padded plane index q + (2 - ky) wp + (2 - kx) with the gradient at (1, 1).
    let mut wts = vec![0f32; 9 * cout * cin];
    for (co, row) in wt.chunks_exact(kk).enumerate() {
        for (k, &v) in row.iter().enumerate() {
            wts[((k % 9) * cout + co) * cin + k / 9] = v;
        }
    }
    let offs: Vec<Vec<usize>> = (0..9)
        .map(|t| {
            let (ky, kx) = (t / 3, t % 3);
            (0..cout)
                .map(|co| co * g.plane + (2 - ky) * g.wp + (2 - kx))
                .collect()
        })
        .collect();
    let chains: Vec<Chains> = (0..9)
        .map(|t| Chains {
            off: &offs[t],
            w: &wts[t * cout * cin..(t + 1) * cout * cin],
            ldw: cin,
        })
        .collect();
    with_buffers(cout * g.plane, cin * g.nq, |planes, acc| {
        g.pad(dout, cout, planes);
        // The positions x >= w of each row are computed and dropped: left as they are.
        for (a, d) in acc.chunks_exact_mut(g.nq).zip(dinp.chunks_exact(h * w)) {
            for (y, row) in d.chunks_exact(w).enumerate() {
                a[y * g.wp..y * g.wp + w].copy_from_slice(row);
            }
        }
        run(planes, &chains, false, acc, g.nq, cin);
        g.unpad(acc, cin, dinp);
    });
}

/// Adds every sum of `chains` into `rows` rows of `acc` (`rows x nq`, position q of row r at
/// `r · nq + q`), a tile of output rows and positions at a time. With `per_block`, each block of
/// [`KC`] terms is added into `acc` as it ends (the SGEMM's `C = C + chain`); without, a sum's
/// blocks are added together first and then into `acc` (col2im adding one tap's `dcol`).
fn run(src: &[f32], chains: &[Chains], per_block: bool, acc: &mut [f32], nq: usize, rows: usize) {
    assert!(nq.is_multiple_of(V) && acc.len() == rows * nq);
    for c in chains {
        let last = c.off.iter().max().copied().unwrap_or(0);
        assert!(
            last + nq <= src.len() && c.w.len() == c.off.len() * c.ldw && c.ldw >= rows,
            "direct convolution: a chain reads outside its operands"
        );
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: AVX2 and FMA are present (`available`, asserted by the callers); every read is
    // `src[off + q .. off + q + V]` with `q + V <= nq` and `off + nq <= src.len()` (asserted
    // above), every weight `w[k · ldw + r]` with `k < off.len()` and `r < rows <= ldw`, and every
    // write `acc[r · nq + q ..][..V]` with `r < rows`, `q + V <= nq`.
    unsafe {
        let (s, a) = (src.as_ptr(), acc.as_mut_ptr());
        let mut q = 0;
        while q + 2 * V <= nq {
            rows_at::<2>(s, chains, per_block, a, (nq, rows), q);
            q += 2 * V;
        }
        while q < nq {
            rows_at::<1>(s, chains, per_block, a, (nq, rows), q);
            q += V;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!("direct convolutions run on x86-64 only");
}

/// Every row of [`run`] at positions `q0 .. q0 + Q V`, four rows a tile.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn rows_at<const Q: usize>(
    src: *const f32,
    chains: &[Chains],
    per_block: bool,
    acc: *mut f32,
    (nq, rows): (usize, usize),
    q0: usize,
) {
    let mut r = 0;
    while r + 4 <= rows {
        tile::<4, Q>(src, chains, per_block, acc, nq, (r, q0));
        r += 4;
    }
    for r in r..rows {
        tile::<1, Q>(src, chains, per_block, acc, nq, (r, q0));
    }
}

/// Rows `r0 .. r0 + R`, positions `q0 .. q0 + Q V` of [`run`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn tile<const R: usize, const Q: usize>(
    src: *const f32,
    chains: &[Chains],
    per_block: bool,
    acc: *mut f32,
    nq: usize,
    (r0, q0): (usize, usize),
) {
    let out = |r: usize, j: usize| acc.add((r0 + r) * nq + q0 + j * V);
    let add_out = |v: [[__m256; Q]; R]| {
        for (r, vr) in v.iter().enumerate() {
            for (j, vj) in vr.iter().enumerate() {
                let p = out(r, j);
                _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), *vj));
            }
        }
    };
    for c in chains {
        let blocks = c.off.len().div_ceil(KC);
        if per_block {
            for b in 0..blocks {
                add_out(chain::<R, Q>(src, c, b, (r0, q0)));
            }
        } else if blocks == 1 {
            // The SGEMM stores its chain as fma(1, chain, 0) before col2im adds it.
            let mut v = chain::<R, Q>(src, c, 0, (r0, q0));
            v.iter_mut()
                .flatten()
                .for_each(|x| *x = _mm256_add_ps(*x, _mm256_setzero_ps()));
            add_out(v);
        } else {
            let mut sum = [[_mm256_setzero_ps(); Q]; R];
            for b in 0..blocks {
                let v = chain::<R, Q>(src, c, b, (r0, q0));
                for (s, x) in sum.iter_mut().flatten().zip(v.iter().flatten()) {
                    *s = _mm256_add_ps(*s, *x);
                }
            }
            add_out(sum);
        }
    }
}

/// Block `b` of a sum of [`Chains`] for rows `r0 .. r0 + R` and positions `q0 .. q0 + Q V`:
/// `R x Q` vectors of chains `fma(w, x, acc)` from zero.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn chain<const R: usize, const Q: usize>(
    src: *const f32,
    c: &Chains,
    b: usize,
    (r0, q0): (usize, usize),
) -> [[__m256; Q]; R] {
    let mut ch = [[_mm256_setzero_ps(); Q]; R];
    let offs = &c.off[b * KC..c.off.len().min((b + 1) * KC)];
    let mut wk = c.w.as_ptr().add(b * KC * c.ldw + r0);
    for &o in offs {
        let s = src.add(o + q0);
        let x: [__m256; Q] = std::array::from_fn(|j| _mm256_loadu_ps(s.add(j * V)));
        for (r, chr) in ch.iter_mut().enumerate() {
            let wv = _mm256_broadcast_ss(&*wk.add(r));
            for (cj, xj) in chr.iter_mut().zip(&x) {
                *cj = _mm256_fmadd_ps(wv, *xj, *cj);
            }
        }
        wk = wk.add(c.ldw);
    }
    ch
}

/// Adds the weight gradient of [`forward`] into `dw` (`cout x cin x 3 x 3`): `dW[co][k] +=
/// Σ_p dout[co][p] · col[k][p]`, each a chain over 256 pixels at a time in image order (the
/// SGEMM's depth blocks, bands of whole blocks), added into `dw` block by block.
///
/// # Panics
/// If [`available`] is false or the slices do not have these lengths.
pub(crate) fn weight_gradient(
    inp: &[f32],
    dout: &[f32],
    (cin, cout): (usize, usize),
    (h, w): (usize, usize),
    dw: &mut [f32],
) {
    let (kk, hw) = (cin * 9, h * w);
    assert!(
        available() && inp.len() == cin * hw && dout.len() == cout * hw && dw.len() == cout * kk,
        "direct weight gradient: operands do not fit"
    );
    let g = Grid::new(h, w);
    // The output gradient pixel-major, output channels padded to whole vectors.
    let cp = cout.div_ceil(V) * V;
    with_buffers(cin * g.plane, hw * cp, |planes, dt| {
        g.pad(inp, cin, planes);
        if cp != cout {
            dt.fill(0.0);
        }
        for (p, row) in dt.chunks_exact_mut(cp).enumerate() {
            for (co, v) in row[..cout].iter_mut().enumerate() {
                *v = dout[co * hw + p];
            }
        }
        let mut base = Vec::with_capacity(KC);
        let mut part = [[0f32; V]; 9];
        for p0 in (0..hw).step_by(KC) {
            let p1 = (p0 + KC).min(hw);
            base.clear();
            base.extend((p0..p1).map(|p| (p / w) * g.wp + p % w));
            assert!(base.iter().all(|&b| b + 2 * g.wp + 2 < g.plane));
            for cv in 0..cp / V {
                for ci in 0..cin {
                    let plane = &planes[ci * g.plane..(ci + 1) * g.plane];
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 and FMA are present (asserted above); the reads are
                    // `plane[b + ky wp + kx]` for b in `base` (bounded by the assertion) and
                    // `dt[p cp + cv V ..][..V]` with p < hw and (cv + 1) V <= cp.
                    unsafe {
                        taps9(
                            plane.as_ptr(),
                            g.wp,
                            &base,
                            dt.as_ptr().add(p0 * cp + cv * V),
                            cp,
                            &mut part,
                        );
                    }
                    for (t, lanes) in part.iter().enumerate() {
                        for (l, &v) in lanes.iter().enumerate().take(cout - cv * V) {
                            let k = ci * 9 + t;
                            dw[(cv * V + l) * kk + k] += v;
                        }
                    }
                }
            }
        }
    });
}

/// The nine chains of one input channel for eight output channels: `part[t][l] = Σ_i d[i][l] ·
/// plane[base[i] + ky wp + kx]` (t = 3 ky + kx), fused multiply-adds from zero in pixel order;
/// `d[i]` is the `V` values at `dt + i · cp`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn taps9(
    plane: *const f32,
    wp: usize,
    base: &[usize],
    dt: *const f32,
    cp: usize,
    part: &mut [[f32; V]; 9],
) {
    let mut acc = [_mm256_setzero_ps(); 9];
    for (i, &b) in base.iter().enumerate() {
        let d = _mm256_loadu_ps(dt.add(i * cp));
        let rows = [plane.add(b), plane.add(b + wp), plane.add(b + 2 * wp)];
        for (ky, row) in rows.iter().enumerate() {
            for kx in 0..3 {
                let x = _mm256_broadcast_ss(&*row.add(kx));
                acc[ky * 3 + kx] = _mm256_fmadd_ps(d, x, acc[ky * 3 + kx]);
            }
        }
    }
    for (a, p) in acc.iter().zip(part.iter_mut()) {
        _mm256_storeu_ps(p.as_mut_ptr(), *a);
    }
}
