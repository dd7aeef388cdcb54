//! The tracing kernel, written once for every number type.
//!
//! Per surface: move the ray into the surface frame (translation, then the inverse rotation when
//! the surface is rotated), intersect (plane, cancellation-free quadric, or Newton for an even
//! asphere started from the quadric root; odd aspheres, toroids, ideal thin lenses and gratings
//! take a separate scalar loop, [`shaped`]), clip at the clear aperture, refract by the vector
//! form of Snell's law (a grating: the grating equation on the tangential part), and move back.
//! Conditions are evaluated on values and applied as
//! selects; a dead ray keeps its last state and its status.
//!
//! The lane loops are written for LLVM's loop vectorizer (8 `f32` or 4 `f64` lanes with AVX2, 16
//! or 8 with AVX-512), and compiled once per instruction set ([`super::simd`]).
//! What it takes, found from the vectorizer's remarks and the generated code:
//! - No branches in the loop body: conditions are combined with `&`/`|` (not `&&`/`||`),
//!   statuses are chosen with `select_u32`, and `commit` writes field by field. A branch
//!   around stores (which a status chain of `if`/`else if` became) is if-converted into masked
//!   stores, or makes the cost model give up.
//! - Each pass reads one buffer and writes the other (the group of blocks and a scratch copy, in
//!   turn), so a lane that keeps its state is a select stored to another address. A select stored
//!   back to the address its old value was loaded from is turned into a masked store
//!   (`vmaskmovps`) by LLVM's x86 backend; these are slow on AMD Zen and took more than half of
//!   the time.
//! - The surface row is copied to the stack before the loop. Reached through the `System`'s
//!   `Vec`, it may alias the blocks as far as LLVM can tell, which then needs run-time alias
//!   checks for it (in the original kernel, too many: the loops stayed scalar).
//!
//! Each surface is applied to a group of blocks before the next surface, which amortizes the
//! per-surface setup (about 7% faster than block by block).

use super::gradient;
use super::{Block, CODE_BACKWARD, CODE_INVALID, CODE_MISSED, CODE_TIR, CODE_VIGNETTED, LANES};
use crate::lens::{Shape, SurfaceKind, SurfaceRow, System};
use crate::math::Vec3;
use crate::real::{Dual, Real};
use crate::trace::simd::{with_avx2, with_avx512, ISA_BASELINE};

const PLANE: u8 = 0;
const QUADRIC: u8 = 1;
const ASPHERE: u8 = 2;
/// Odd aspheres, toroids, ideal thin lenses and surfaces that start a gradient-index medium:
/// one out-of-line loop per number type (see [`shaped`]; the medium itself is
/// [`super::gradient`]'s pass).
pub(super) const SHAPED: u8 = 3;

/// A number type the tracer can run on. `f32`, `f64` and the dual numbers of widths 1 and
/// [`crate::real::GRAD_WIDTH`] override [`Traceable::trace_blocks`] with builds for several
/// instruction sets chosen at run time ([`super::simd`]); other types use the generic build.
pub trait Traceable: Real {
    /// Traces `blocks` through `sys` with refractive indices `n` (as [`System::indices`] gives
    /// them) at `wavelength_nm` (which gratings need).
    fn trace_blocks(
        sys: &System<Self>,
        n: &[Self],
        wavelength_nm: f64,
        clip: bool,
        blocks: &mut [Block<Self>],
    ) {
        trace_blocks_generic::<Self, ISA_BASELINE>(sys, n, wavelength_nm, clip, blocks);
    }
}

// Each build of the kernel sits in a module of its own. rustc starts with a codegen unit per
// module and the optimiser then works on units in parallel: with every build in this module,
// one unit held most of the library's optimisation and the second core idled.
use builds::{trace_blocks_dual1, trace_blocks_dual_grad, trace_blocks_f32, trace_blocks_f64};

mod builds {
    pub(super) use build_dual1::trace_blocks_dual1;
    pub(super) use build_dual_grad::trace_blocks_dual_grad;
    pub(super) use build_f32::trace_blocks_f32;
    pub(super) use build_f64::trace_blocks_f64;

    mod build_f32 {
        use super::super::{trace_blocks_generic, Block, System};
        crate::trace::simd::isa_dispatch! {
            pub(in super::super) fn trace_blocks_f32(
                sys: &System<f32>,
                n: &[f32],
                wavelength_nm: f64,
                clip: bool,
                blocks: &mut [Block<f32>],
            ) {
                trace_blocks_generic::<_, ISA>(sys, n, wavelength_nm, clip, blocks)
            }
        }
    }

    mod build_f64 {
        use super::super::{trace_blocks_generic, Block, System};
        crate::trace::simd::isa_dispatch! {
            pub(in super::super) fn trace_blocks_f64(
                sys: &System<f64>,
                n: &[f64],
                wavelength_nm: f64,
                clip: bool,
                blocks: &mut [Block<f64>],
            ) {
                trace_blocks_generic::<_, ISA>(sys, n, wavelength_nm, clip, blocks)
            }
        }
    }

    mod build_dual_grad {
        use super::super::{trace_blocks_generic, Block, Dual, System};
        use crate::real::GRAD_WIDTH;
        crate::trace::simd::isa_dispatch! {
            pub(in super::super) fn trace_blocks_dual_grad(
                sys: &System<Dual<f64, GRAD_WIDTH>>,
                n: &[Dual<f64, GRAD_WIDTH>],
                wavelength_nm: f64,
                clip: bool,
                blocks: &mut [Block<Dual<f64, GRAD_WIDTH>>],
            ) {
                trace_blocks_generic::<_, ISA>(sys, n, wavelength_nm, clip, blocks)
            }
        }
    }

    mod build_dual1 {
        use super::super::{trace_blocks_generic, Block, Dual, System};
        crate::trace::simd::isa_dispatch! {
            pub(in super::super) fn trace_blocks_dual1(
                sys: &System<Dual<f64, 1>>,
                n: &[Dual<f64, 1>],
                wavelength_nm: f64,
                clip: bool,
                blocks: &mut [Block<Dual<f64, 1>>],
            ) {
                trace_blocks_generic::<_, ISA>(sys, n, wavelength_nm, clip, blocks)
            }
        }
    }
}

impl Traceable for f32 {
    fn trace_blocks(
        sys: &System<f32>,
        n: &[f32],
        wavelength_nm: f64,
        clip: bool,
        blocks: &mut [Block<f32>],
    ) {
        trace_blocks_f32(sys, n, wavelength_nm, clip, blocks);
    }
}

impl Traceable for f64 {
    fn trace_blocks(
        sys: &System<f64>,
        n: &[f64],
        wavelength_nm: f64,
        clip: bool,
        blocks: &mut [Block<f64>],
    ) {
        trace_blocks_f64(sys, n, wavelength_nm, clip, blocks);
    }
}

/// Dual numbers trace with the generic build, except the widths the library differentiates with
/// (1 and [`crate::real::GRAD_WIDTH`]): they call builds compiled once per instruction set, in
/// this crate, so a crate that takes gradients (the tests, a user's program) links them instead
/// of compiling the kernel again for its width (minutes of optimization each).
impl<const N: usize> Traceable for Dual<f64, N> {
    fn trace_blocks(
        sys: &System<Self>,
        n: &[Self],
        wavelength_nm: f64,
        clip: bool,
        blocks: &mut [Block<Self>],
    ) {
        const W: usize = crate::real::GRAD_WIDTH;
        // `if const`: the other branches of each width are not compiled.
        if const { N == W } {
            let (sys, n, blocks) = same_width::<N, W>(sys, n, blocks);
            trace_blocks_dual_grad(sys, n, wavelength_nm, clip, blocks);
        } else if const { N == 1 } {
            let (sys, n, blocks) = same_width::<N, 1>(sys, n, blocks);
            trace_blocks_dual1(sys, n, wavelength_nm, clip, blocks);
        } else {
            trace_blocks_generic::<Self, ISA_BASELINE>(sys, n, wavelength_nm, clip, blocks);
        }
    }
}

/// The arguments of a trace: system, indices, blocks.
type TraceArgs<'a, S> = (&'a System<S>, &'a [S], &'a mut [Block<S>]);

/// The arguments of a dual-number trace of width `A` as width `B`, which must be the same.
fn same_width<'a, const A: usize, const B: usize>(
    sys: &'a System<Dual<f64, A>>,
    n: &'a [Dual<f64, A>],
    blocks: &'a mut [Block<Dual<f64, A>>],
) -> TraceArgs<'a, Dual<f64, B>> {
    assert_eq!(A, B);
    let (len_n, len_b) = (n.len(), blocks.len());
    // SAFETY: A == B (asserted), so `Dual<f64, A>` and `Dual<f64, B>` are one type and each cast
    // is from a type to itself: same layout, same lifetimes, the same exclusive borrow of
    // `blocks` passed on.
    unsafe {
        (
            &*(sys as *const System<Dual<f64, A>>).cast::<System<Dual<f64, B>>>(),
            std::slice::from_raw_parts(n.as_ptr().cast::<Dual<f64, B>>(), len_n),
            std::slice::from_raw_parts_mut(
                blocks.as_mut_ptr().cast::<Block<Dual<f64, B>>>(),
                len_b,
            ),
        )
    }
}

/// Blocks per group: a group and its scratch copy stay in the L1 cache.
const GROUP: usize = 8;

/// The generic block loop: groups of blocks outside, then passes (the surfaces, then the image
/// plane), then blocks and lanes; `ISA` is the build it is compiled into (see [`lanes_in`]).
#[inline(always)]
pub(crate) fn trace_blocks_generic<S: Real, const ISA: u8>(
    sys: &System<S>,
    n: &[S],
    wavelength_nm: f64,
    clip: bool,
    blocks: &mut [Block<S>],
) {
    debug_assert_eq!(
        n.len(),
        sys.rows.len() + 1,
        "an index in front of each surface and one after the last"
    );
    // Refraction needs a finite positive index in every medium: at a wavelength where one has
    // none (a model glass of absurd dispersion, a raw ray's wavelength far outside every
    // formula), no ray has a defined path, so none is traced as if it had.
    if !n.iter().all(|v| v.value().is_finite() && v.value() > 0.0) {
        for b in blocks.iter_mut() {
            for s in b.status.iter_mut() {
                if *s == 0 {
                    *s = CODE_INVALID;
                }
            }
        }
        return;
    }
    let mut scratch = vec![Block::dead(); GROUP.min(blocks.len())];
    let n_last = n.last().copied().unwrap_or(S::cst(1.0));
    let n_rows = sys.rows.len();
    for group in blocks.chunks_mut(GROUP) {
        let scratch = &mut scratch[..group.len()];
        // Pass i reads the group and writes the scratch copy when i is even, the other way round
        // when i is odd. Two call sites rather than swapped references: with the references
        // swapped, most f64 loops stayed scalar.
        for (i, row) in sys.rows.iter().enumerate() {
            let n1 = n[i];
            let eta = n1 / n[i + 1];
            // A grating's m λ T over the index in front of it; a diffractive phase's λ / 2π
            // (mm) over it (0 without either).
            let ruling = match (row.grating, &row.phase) {
                (Some(g), _) => S::cst(g.deflection(wavelength_nm)) / n1,
                (None, Some(_)) => S::cst(wavelength_nm * 1e-6 / std::f64::consts::TAU) / n1,
                (None, None) => S::cst(0.0),
            };
            let code = i as u32;
            // A surface that ends a gradient-index medium: the pass through the medium to it.
            if let Some((entry, g)) = sys.gradient_before(i) {
                let n2 = n[i + 1];
                if i % 2 == 0 {
                    gradient::exit_pass(entry, g, row, n2, code, clip, group, scratch);
                } else {
                    gradient::exit_pass(entry, g, row, n2, code, clip, scratch, group);
                }
            } else if i % 2 == 0 {
                surface::<S, ISA>(row, n1, eta, ruling, code, clip, group, scratch);
            } else {
                surface::<S, ISA>(row, n1, eta, ruling, code, clip, scratch, group);
            }
        }
        if n_rows.is_multiple_of(2) {
            image(sys, n_last, n_rows as u32, group, scratch);
            group.copy_from_slice(scratch);
        } else {
            image(sys, n_last, n_rows as u32, scratch, group);
        }
    }
}

/// One surface pass: the lane loop compiled for the surface's kind, rotation and clipping.
/// `ruling` is a grating's m λ T / n1, a diffractive phase's λ / (2π n1) (0 without either).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn surface<S: Real, const ISA: u8>(
    row: &SurfaceRow<S>,
    n1: S,
    eta: S,
    ruling: S,
    code: u32,
    clip: bool,
    src: &[Block<S>],
    dst: &mut [Block<S>],
) {
    if row.shape != Shape::Even
        || row.grating.is_some()
        || row.phase.is_some()
        || row.grin.is_some()
    {
        return shaped(row, n1, eta, ruling, code, clip, src, dst);
    }
    macro_rules! go {
        ($kind:expr, $rot:expr, $clip:expr) => {
            lanes_in::<S, ISA, { $kind }, { $rot }, { $clip }>(row, n1, eta, ruling, code, src, dst)
        };
    }
    match (row.kind, row.rotated, clip) {
        (SurfaceKind::Plane, false, false) => go!(PLANE, false, false),
        (SurfaceKind::Plane, false, true) => go!(PLANE, false, true),
        (SurfaceKind::Plane, true, false) => go!(PLANE, true, false),
        (SurfaceKind::Plane, true, true) => go!(PLANE, true, true),
        (SurfaceKind::Quadric, false, false) => go!(QUADRIC, false, false),
        (SurfaceKind::Quadric, false, true) => go!(QUADRIC, false, true),
        (SurfaceKind::Quadric, true, false) => go!(QUADRIC, true, false),
        (SurfaceKind::Quadric, true, true) => go!(QUADRIC, true, true),
        (SurfaceKind::Asphere, false, false) => go!(ASPHERE, false, false),
        (SurfaceKind::Asphere, false, true) => go!(ASPHERE, false, true),
        (SurfaceKind::Asphere, true, false) => go!(ASPHERE, true, false),
        (SurfaceKind::Asphere, true, true) => go!(ASPHERE, true, true),
    }
}

/// The lane loop `lanes::<S, KIND, ROT, CLIP>` as a surface pass of the build `ISA` runs it:
/// inlined for plain floats, and for numbers with derivative parts called out of line, compiled
/// with the same build's target features.
///
/// Each arithmetic operation on a dual number is a small loop over its parts until LLVM unrolls
/// it, so a dual-number kernel with every lane loop inlined was one function with over 6,000
/// loops, and LLVM's loop passes (LoopRotate above all) cost time in proportion to the size of
/// the function a loop sits in: the three builds of the gradient kernel took about half of the
/// library's optimisation time (`-Z llvm-time-trace`). Out of line, each of the twelve lane loops
/// is a function of its own: the library builds 8x faster, the same bits, and the `Dual<f64, 8>`
/// trace runs 5-12 % slower (docs/decisions.md).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn lanes_in<S: Real, const ISA: u8, const KIND: u8, const ROT: bool, const CLIP: bool>(
    row: &SurfaceRow<S>,
    n1: S,
    eta: S,
    ruling: S,
    code: u32,
    src: &[Block<S>],
    dst: &mut [Block<S>],
) {
    if const { S::PARTS == 1 } {
        return lanes::<S, KIND, ROT, CLIP>(row, n1, eta, ruling, code, src, dst);
    }
    // One function per build, compiled with the build's target features (`$with`).
    macro_rules! outlined {
        ($with:ident, $name:ident) => {
            $with! {
                #[inline(never)]
                #[allow(clippy::too_many_arguments)]
                fn $name<S: Real, const KIND: u8, const ROT: bool, const CLIP: bool>(
                    row: &SurfaceRow<S>,
                    n1: S,
                    eta: S,
                    ruling: S,
                    code: u32,
                    src: &[Block<S>],
                    dst: &mut [Block<S>],
                ) {
                    lanes::<S, KIND, ROT, CLIP>(row, n1, eta, ruling, code, src, dst)
                }
            }
        };
    }
    macro_rules! baseline_features {
        ($item:item) => {
            $item
        };
    }
    outlined!(with_avx512, avx512);
    outlined!(with_avx2, avx2);
    outlined!(baseline_features, baseline);
    match ISA {
        // SAFETY: `ISA` is the build this code is compiled into (`simd::isa_dispatch`), which
        // runs only on a CPU with its features.
        #[cfg(target_arch = "x86_64")]
        crate::trace::simd::ISA_AVX512 => unsafe {
            avx512::<S, KIND, ROT, CLIP>(row, n1, eta, ruling, code, src, dst)
        },
        #[cfg(target_arch = "x86_64")]
        crate::trace::simd::ISA_AVX2 => unsafe {
            avx2::<S, KIND, ROT, CLIP>(row, n1, eta, ruling, code, src, dst)
        },
        _ => baseline::<S, KIND, ROT, CLIP>(row, n1, eta, ruling, code, src, dst),
    }
}

/// A surface pass for the shapes other than the even asphere (odd asphere, toroid, ideal thin
/// lens) and for gratings. Out of line and not inlined: these loops stay scalar (a per-lane
/// Newton with an early
/// exit), are rare, and inlined into every instantiation of the vectorized loops they made the
/// cold build of every number type several times slower without making anything faster.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn shaped<S: Real>(
    row: &SurfaceRow<S>,
    n1: S,
    eta: S,
    ruling: S,
    code: u32,
    clip: bool,
    src: &[Block<S>],
    dst: &mut [Block<S>],
) {
    let r = ruling;
    match (row.rotated, clip) {
        (false, false) => lanes::<S, SHAPED, false, false>(row, n1, eta, r, code, src, dst),
        (false, true) => lanes::<S, SHAPED, false, true>(row, n1, eta, r, code, src, dst),
        (true, false) => lanes::<S, SHAPED, true, false>(row, n1, eta, r, code, src, dst),
        (true, true) => lanes::<S, SHAPED, true, true>(row, n1, eta, r, code, src, dst),
    }
}

/// The image-plane pass.
#[inline(always)]
fn image<S: Real>(sys: &System<S>, n_last: S, code: u32, src: &[Block<S>], dst: &mut [Block<S>]) {
    match (sys.image_rotated, !sys.image_c.is_zero()) {
        (true, false) => image_lanes::<S, true, false>(sys, n_last, code, src, dst),
        (false, false) => image_lanes::<S, false, false>(sys, n_last, code, src, dst),
        (true, true) => image_lanes::<S, true, true>(sys, n_last, code, src, dst),
        (false, true) => image_lanes::<S, false, true>(sys, n_last, code, src, dst),
    }
}

#[inline(always)]
pub(super) fn load<S: Real>(b: &Block<S>, l: usize) -> (Vec3<S>, Vec3<S>) {
    (
        Vec3::new(b.o[0][l], b.o[1][l], b.o[2][l]),
        Vec3::new(b.d[0][l], b.d[1][l], b.d[2][l]),
    )
}

/// `a` if `c`, else `b`, with bit operations: a branch-free select for statuses.
#[inline(always)]
pub(super) fn select_u32(c: bool, a: u32, b: u32) -> u32 {
    b ^ ((a ^ b) & (c as u32).wrapping_neg())
}

/// Writes lane `l` of `dst` from lane `l` of `src`: a ray that was alive and does not fail here
/// (`why == 0`) takes the new state; one that fails keeps its state and takes the status `why`; a
/// dead ray keeps its state and status.
#[inline(always)]
pub(super) fn commit<S: Real>(
    src: &Block<S>,
    dst: &mut Block<S>,
    l: usize,
    why: u32,
    o: Vec3<S>,
    d: Vec3<S>,
    dopl: S,
) {
    let old = src.status[l];
    let alive = old == 0;
    let keep = alive & (why == 0);
    dst.status[l] = select_u32(alive, why, old);
    // Field by field: written as loops over the components, the selects became a branch.
    let s = |new: S, old: S| S::pick(keep, new, old);
    dst.o[0][l] = s(o.x, src.o[0][l]);
    dst.o[1][l] = s(o.y, src.o[1][l]);
    dst.o[2][l] = s(o.z, src.o[2][l]);
    dst.d[0][l] = s(d.x, src.d[0][l]);
    dst.d[1][l] = s(d.y, src.d[1][l]);
    dst.d[2][l] = s(d.z, src.d[2][l]);
    dst.opl[l] = s(src.opl[l] + dopl, src.opl[l]);
}

/// True when the intersection at parameter `t` lies behind a ray at `p` (surface frame) by more
/// than rounding: a ray starting on the surface (t = 0 up to rounding) is not behind it.
#[inline(always)]
pub(crate) fn behind<S: Real>(t: S, p: Vec3<S>) -> bool {
    let tol = S::cst(64.0 * S::EPSILON) * (S::cst(1.0) + p.x.abs() + p.y.abs() + p.z.abs());
    t.lt(-tol)
}

#[inline(always)]
fn zero_lt<S: Real>(x: S) -> bool {
    S::cst(0.0).lt(x)
}

/// Sag and its derivative with respect to u = x² + y² for an even asphere; `ok` is false beyond
/// the conic's rim.
#[inline(always)]
pub(crate) fn asphere_sag<S: Real>(row: &SurfaceRow<S>, u: S) -> (S, S, bool) {
    let one = S::cst(1.0);
    let arg = one - row.k1 * row.c * row.c * u;
    let ok = zero_lt(arg);
    let q = S::pick(ok, arg, one).sqrt();
    let mut z = row.c * u / (one + q);
    let mut dz = row.c / (S::cst(2.0) * q);
    // Horner over a2 u + a4 u² + ... : z += u (a2 + u (a4 + ...)).
    let mut poly = S::cst(0.0);
    let mut dpoly = S::cst(0.0);
    for j in (0..row.n_asph).rev() {
        dpoly = dpoly * u + S::cst((j + 1) as f64) * row.asph[j];
        poly = poly * u + row.asph[j];
    }
    z += poly * u;
    dz += dpoly;
    (z, dz, ok)
}

/// Sag and gradient (z, ∂z/∂x, ∂z/∂y) of an odd asphere: the base conic plus β1 ρ + ... + β8 ρ⁸
/// (`asph` = β1..β8); `ok` is false beyond the conic's rim. At the vertex the cone term β1 ρ
/// has no slope; the normal there is taken as the axis.
#[inline(always)]
fn odd_sag<S: Real>(row: &SurfaceRow<S>, x: S, y: S) -> (S, S, S, bool) {
    let one = S::cst(1.0);
    let zero = S::cst(0.0);
    let u = x * x + y * y;
    let arg = one - row.k1 * row.c * row.c * u;
    let ok = zero_lt(arg);
    let q = S::pick(ok, arg, one).sqrt();
    let z = row.c * u / (one + q);
    // (dz/dρ) / ρ of the conic.
    let slope_over_r = row.c / q;
    // ρ without the infinite derivative of the square root at 0.
    let off_axis = zero_lt(u);
    let r = S::pick(off_axis, S::pick(off_axis, u, one).sqrt(), zero);
    let n = row.n_asph;
    // Horner: P(ρ) = ρ (β1 + ρ (β2 + ...)), and P'(ρ)/ρ = β1/ρ + Σ_{i>=2} i β_i ρ^(i-2).
    let mut poly = zero;
    let mut rest = zero;
    for j in (0..n).rev() {
        poly = poly * r + row.asph[j];
        if j >= 1 {
            rest = rest * r + S::cst((j + 1) as f64) * row.asph[j];
        }
    }
    let inv_r = S::pick(off_axis, one / S::pick(off_axis, r, one), zero);
    let g = slope_over_r + rest + row.asph[0] * inv_r;
    (z + poly * r, x * g, y * g, ok)
}

/// Sag and gradient of a toroid: the y-z profile z_y(y) (base conic and even terms, the even
/// asphere routine at u = y²) rotated about the axis parallel to y at z = 1/c_rot. With
/// g = c_rot / (1 - c_rot z_y), z = z_y + g x² / (1 + sqrt(1 - g² x²)), ∂z/∂x = g x / sqrt(..)
/// and ∂z/∂y = z_y' / sqrt(..): exact at c_rot = 0 (a cylinder), without the subtraction of
/// R - sqrt((R - z_y)² - x²).
#[inline(always)]
fn toroid_sag<S: Real>(row: &SurfaceRow<S>, x: S, y: S) -> (S, S, S, bool) {
    let one = S::cst(1.0);
    let (zy, dzu, ok1) = asphere_sag(row, y * y);
    let dzy = S::cst(2.0) * y * dzu;
    let w = one - row.c_rot * zy;
    let ok2 = !w.is_zero();
    let g = row.c_rot / S::pick(ok2, w, one);
    let qq = one - g * g * x * x;
    let ok3 = zero_lt(qq);
    let sq = S::pick(ok3, qq, one).sqrt();
    let z = zy + g * x * x / (one + sq);
    let inv = one / sq;
    (z, g * x * inv, dzy * inv, ok1 & ok2 & ok3)
}

/// Sag and gradient (z, ∂z/∂x, ∂z/∂y) of a surface traced by the asphere routine, by shape.
#[inline(always)]
pub(crate) fn sag_xy<S: Real>(row: &SurfaceRow<S>, x: S, y: S) -> (S, S, S, bool) {
    match row.shape {
        // A thin lens is flat and never reaches Newton.
        Shape::Even | Shape::Paraxial { .. } => {
            let (z, dz, ok) = asphere_sag(row, x * x + y * y);
            let two = S::cst(2.0);
            (z, two * x * dz, two * y * dz, ok)
        }
        Shape::Odd => odd_sag(row, x, y),
        Shape::Toroidal { .. } => toroid_sag(row, x, y),
        Shape::Zernike { .. } => {
            // The even asphere plus the merged Zernike terms.
            let (z, dz, ok) = asphere_sag(row, x * x + y * y);
            let two = S::cst(2.0);
            let (zz, zx, zy) = match &row.zernike {
                Some(t) => t.eval(x, y),
                None => (S::cst(0.0), S::cst(0.0), S::cst(0.0)),
            };
            (z + zz, two * x * dz + zx, two * y * dz + zy, ok)
        }
        Shape::Qbfs { .. } | Shape::Qcon { .. } => {
            // Direct calls (not a function pointer): both inline into the Newton loop.
            let (c, k1, a, n, s, u) = (
                row.c,
                row.k1,
                &row.asph,
                row.n_asph,
                row.inv_norm2,
                x * x + y * y,
            );
            let (z, dz, ok) = if matches!(row.shape, Shape::Qbfs { .. }) {
                crate::lens::qbfs::sag_u(c, k1, a, n, s, u)
            } else {
                crate::lens::qcon::sag_u(c, k1, a, n, s, u)
            };
            let two = S::cst(2.0);
            (z, two * x * dz, two * y * dz, ok)
        }
    }
}

/// Newton on f(t) = z(t) - sag(x(t), y(t)) from `t` for the shapes without the even asphere's
/// radial form; returns (t, ok, unnormalized normal pointing toward -z). The even asphere keeps
/// its own loop in [`intersect`] (one dz/du for both slopes, and the operations, hence the
/// numbers, of every earlier build).
#[inline(always)]
fn newton_xy<S: Real>(
    row: &SurfaceRow<S>,
    p: Vec3<S>,
    d: Vec3<S>,
    t0: S,
    ok0: bool,
) -> (S, bool, Vec3<S>) {
    let mut t = t0;
    let mut ok = ok0;
    let mut converged = false;
    for _ in 0..40 {
        let h = p + d * t;
        let (z, zx, zy, in_rim) = sag_xy(row, h.x, h.y);
        ok &= in_rim;
        let f = h.z - z;
        let fp = d.z - (zx * d.x + zy * d.y);
        let step = f / fp;
        t -= step;
        if !(step.value().abs() > 4.0 * S::EPSILON * (1.0 + t.value().abs())) {
            converged = step.value().is_finite();
            break;
        }
    }
    let h = p + d * t;
    let (_, zx, zy, in_rim) = sag_xy(row, h.x, h.y);
    // A slope that overflows (an absurd high-order term far out) gives no normal: a miss, not
    // a ray whose NaN direction would pass later surfaces as alive.
    ok &= converged && in_rim && zx.value().is_finite() && zy.value().is_finite();
    (t, ok, Vec3::new(zx, zy, -S::cst(1.0)))
}

/// Start for a toroid's Newton: the ray's crossing of the y-z profile's base conic swept along
/// x, c (y² + k1 z²) - 2 z = 0 (exact for a cylinder without even terms), nearest the vertex
/// plane: the quadric's root with the ray's x parts left out.
#[inline(always)]
fn cylinder_root<S: Real>(row: &SurfaceRow<S>, p: Vec3<S>, d: Vec3<S>) -> (S, bool) {
    let zero = S::cst(0.0);
    quadric_root(row, Vec3::new(zero, p.y, p.z), Vec3::new(zero, d.y, d.z))
}

/// The ray's crossing of the quadric c (x² + y² + k1 z²) - 2 z = 0 nearest its crossing of the
/// vertex plane: (t, ok).
#[inline(always)]
fn quadric_root<S: Real>(row: &SurfaceRow<S>, p: Vec3<S>, d: Vec3<S>) -> (S, bool) {
    conic_root(row.c, row.k1, p, d)
}

/// As [`quadric_root`] for the quadric of curvature `c` and `k1` = 1 + conic (a curved image
/// surface's, in its own frame).
#[inline(always)]
pub(crate) fn conic_root<S: Real>(c: S, k1: S, p: Vec3<S>, d: Vec3<S>) -> (S, bool) {
    // Solved from the ray's crossing of the vertex plane (where the constant term is small). Of
    // the two roots this takes the one nearest that crossing, without cancellation; it tends to
    // the plane solution as c -> 0. The crossing (x0, y0) and the coefficients are kept
    // multiplied by powers of d.z, which leaves a single division: with X0 = x0 d.z, B = b d.z,
    // C = cc d.z², D = den d.z, t = t0 - cc / den = -(z D + C) / (d.z D).
    let zero = S::cst(0.0);
    let one = S::cst(1.0);
    let mut ok = !d.z.is_zero();
    let (x0, y0) = (p.x * d.z - d.x * p.z, p.y * d.z - d.y * p.z);
    let a = c * (d.x * d.x + d.y * d.y + k1 * d.z * d.z);
    let b = c * (x0 * d.x + y0 * d.y) - d.z * d.z;
    let cc = c * (x0 * x0 + y0 * y0);
    let disc = b * b - a * cc;
    ok &= !disc.lt(zero);
    let s = S::pick(ok, disc, zero).sqrt();
    let den = b + s.copysign(b);
    ok &= !den.is_zero();
    let t = -(p.z * den + cc) / S::pick(ok, d.z * den, one);
    (t, ok)
}

/// Intersection in the surface frame: returns (t, ok, unnormalized normal pointing toward -z).
#[inline(always)]
fn intersect<S: Real, const KIND: u8>(
    row: &SurfaceRow<S>,
    p: Vec3<S>,
    d: Vec3<S>,
) -> (S, bool, Vec3<S>) {
    let zero = S::cst(0.0);
    let one = S::cst(1.0);
    if KIND == PLANE || (KIND == SHAPED && row.kind == SurfaceKind::Plane) {
        let t = -p.z / d.z;
        return (t, !d.z.is_zero(), Vec3::new(zero, zero, -one));
    }
    if KIND == SHAPED {
        let (t, ok) = match row.shape {
            Shape::Toroidal { .. } => cylinder_root(row, p, d),
            _ => quadric_root(row, p, d),
        };
        return newton_xy(row, p, d, t, ok);
    }
    let (mut t, mut ok) = quadric_root(row, p, d);
    let (c, k1) = (row.c, row.k1);
    if KIND == QUADRIC {
        let h = p + d * t;
        // Only the vertex-side sheet of the quadric is the lens surface.
        ok &= (c * k1 * h.z).lt(one);
        return (t, ok, Vec3::new(c * h.x, c * h.y, c * k1 * h.z - one));
    }
    // Even asphere: Newton on f(t) = z(t) - sag(x(t)² + y(t)²) from the quadric root.
    let mut converged = false;
    for _ in 0..40 {
        let h = p + d * t;
        let u = h.x * h.x + h.y * h.y;
        let (z, dz, in_rim) = asphere_sag(row, u);
        ok &= in_rim;
        let f = h.z - z;
        let fp = d.z - dz * S::cst(2.0) * (h.x * d.x + h.y * d.y);
        let step = f / fp;
        t -= step;
        if !(step.value().abs() > 4.0 * S::EPSILON * (1.0 + t.value().abs())) {
            converged = step.value().is_finite();
            break;
        }
    }
    let h = p + d * t;
    let (_, dz, in_rim) = asphere_sag(row, h.x * h.x + h.y * h.y);
    // As in newton_xy: an overflowing slope is a miss.
    ok &= converged && in_rim && dz.value().is_finite();
    let two = S::cst(2.0);
    (t, ok, Vec3::new(two * h.x * dz, two * h.y * dz, -one))
}

/// How a ray leaves a surface, for one lane: the kernel's form of [`reference::bend`]
/// (refraction, reflection, a grating's order or a diffractive phase, an ideal thin lens, or
/// straight through a bare aperture). `d` is the unit direction in, `h` the crossing and `nrm`
/// the unnormalized normal (either sign), all in the surface's frame; `eta` = n1 / n2 and `kick`
/// a grating's or phase's tangential kick over n1 ([`diffract_lane`]). Returns
/// the direction out and whether the ray ends here (total internal reflection, or an order that
/// does not propagate). Written without branches: every case is computed where it can apply and
/// chosen by selects, so that the lane loop stays vectorizable.
///
/// [`reference::bend`]: super::reference::bend
#[inline(always)]
pub(super) fn turn<S: Real, const KIND: u8>(
    row: &SurfaceRow<S>,
    d: Vec3<S>,
    h: Vec3<S>,
    nrm: Vec3<S>,
    eta: S,
    kick: (S, S),
) -> (Vec3<S>, bool) {
    let one = S::cst(1.0);
    let zero = S::cst(0.0);
    let mirror = row.reflect;
    if KIND == PLANE {
        // A bare aperture passes rays straight.
        return (d, false);
    }
    if KIND == SHAPED && (row.grating.is_some() || row.phase.is_some()) {
        return diffract_lane(d, nrm, eta, kick, mirror);
    }
    if KIND == SHAPED && !row.power.is_zero() {
        // An ideal thin lens: the slopes turn by -h P; the direction (d.x - h.x P d.z,
        // d.y - h.y P d.z, d.z), normalized, keeps the sign of travel.
        let v = Vec3::new(
            d.x - h.x * row.power * d.z,
            d.y - h.y * row.power * d.z,
            d.z,
        );
        return (v * (one / v.dot(v).sqrt()), false);
    }
    // Refraction (vector Snell) with the normal N flipped to face the incoming ray: with
    // a = -N.d = |N| cos i, the refracted direction is eta d + (eta a - sqrt(k N.N)) / N.N N
    // (one division and one square root). A mirror reflects: d + 2 (a / N.N) N.
    let (nrm, a, nn, inv_nn) = facing(nrm, d);
    let k = one - eta * eta * (one - a * a * inv_nn);
    let tir = !mirror & k.lt(zero);
    let g = (eta * a - S::pick(tir, zero, k * nn).sqrt()) * inv_nn;
    let refl = S::cst(2.0) * a * inv_nn;
    let (gm, em) = (S::pick(mirror, refl, g), S::pick(mirror, one, eta));
    (d * em + nrm * gm, tir)
}

/// The normal `nrm` turned to face a ray going `d` (so that `a = -N.d >= 0`), with `a`, `N.N`
/// and `1 / N.N` (taken before the turn: the selects would hide from LLVM that they are equal).
#[inline(always)]
fn facing<S: Real>(nrm: Vec3<S>, d: Vec3<S>) -> (Vec3<S>, S, S, S) {
    let nn = nrm.dot(nrm);
    let inv_nn = S::cst(1.0) / nn;
    let a = -nrm.dot(d);
    let flip = a.lt(S::cst(0.0));
    let nrm = Vec3::new(
        S::pick(flip, -nrm.x, nrm.x),
        S::pick(flip, -nrm.y, nrm.y),
        S::pick(flip, -nrm.z, nrm.z),
    );
    (nrm, S::pick(flip, -a, a), nn, inv_nn)
}

/// A grating's order or a diffractive phase, for one lane (the kernel's form of
/// [`reference::diffract`]): the tangential parts gain the kick `k` = (k_x, k_y, 0) / n1 (a
/// grating: (0, m λ T); a phase: λ ∇Φ / 2π). With e = n1 / n_out (1 for a mirror) and q = e k,
/// v = e d + q_t, where q_t = q - (q.N / N.N) N is the kick in the tangent plane; v.N = -e a,
/// and d' = v + β N is the unit root behind the surface (refraction) or in front of it
/// (reflection). Returns d' and whether the order does not propagate.
///
/// [`reference::diffract`]: super::reference::diffract
#[inline(always)]
fn diffract_lane<S: Real>(
    d: Vec3<S>,
    nrm: Vec3<S>,
    eta: S,
    kick: (S, S),
    mirror: bool,
) -> (Vec3<S>, bool) {
    let one = S::cst(1.0);
    let (nrm, a, nn, inv_nn) = facing(nrm, d);
    let e = S::pick(mirror, one, eta);
    let (qx, qy) = (kick.0 * e, kick.1 * e);
    let qn = (qx * nrm.x + qy * nrm.y) * inv_nn;
    let v = Vec3::new(
        e * d.x + qx - qn * nrm.x,
        e * d.y + qy - qn * nrm.y,
        e * d.z - qn * nrm.z,
    );
    let disc = e * e * a * a - nn * (v.dot(v) - one);
    let evanescent = disc.lt(S::cst(0.0));
    let s = S::pick(evanescent, S::cst(0.0), disc).sqrt();
    (
        v + nrm * ((e * a + S::pick(mirror, s, -s)) * inv_nn),
        evanescent,
    )
}

/// One surface for every lane of a group of blocks, from `src` into `dst`. `KIND`, `ROT`
/// (rotated frame) and `CLIP` (apertures on) are compile-time so that the lane loop has no control
/// flow left and vectorizes. A plane surface is a bare aperture: it clips but never refracts. A
/// mirror is a runtime select (a compile-time flag doubled the kernel's instances and the build
/// time of every dual-number width). A grating (`ruling` = m λ T / n1) or a diffractive phase
/// (`ruling` = λ / (2π n1)) is traced in the `SHAPED` loop only. How each ray leaves the surface is [`turn`].
#[inline(always)]
fn lanes<S: Real, const KIND: u8, const ROT: bool, const CLIP: bool>(
    row: &SurfaceRow<S>,
    n1: S,
    eta: S,
    ruling: S,
    code: u32,
    src: &[Block<S>],
    dst: &mut [Block<S>],
) {
    // A stack copy, which LLVM can see is not aliased by `dst` (see the module documentation).
    // The scalar `SHAPED` loop needs none, and its rows may own heap data (Zernike terms, a
    // phase) that a copy per group of blocks would allocate anew.
    let copy;
    let row = if KIND == SHAPED {
        row
    } else {
        copy = row.clone();
        &copy
    };
    let ruled = KIND == SHAPED && (row.grating.is_some() || row.phase.is_some());
    for (s, b) in src.iter().zip(dst.iter_mut()) {
        for l in 0..LANES {
            let (o, d0) = load(s, l);
            let mut p = o - row.pos;
            let mut d = d0;
            if ROT {
                p = row.rot.apply_t(p);
                d = row.rot.apply_t(d);
            }
            let (t, hit, nrm) = intersect::<S, KIND>(row, p, d);
            let backward = !row.virtual_ok & behind(t, p);
            let h = p + d * t;
            let vignetted = CLIP & row.clip.stops(h.x, h.y);
            // The phase the surface adds (radians over 2π / λ: a grating's y, or Φ) and the
            // tangential kick, both times `ruling`.
            let (phase, kick) = if ruled {
                let (ph, gx, gy) = match &row.phase {
                    Some(p) => p.eval(h.x, h.y),
                    None => (h.y, S::cst(0.0), S::cst(1.0)),
                };
                (ph, (ruling * gx, ruling * gy))
            } else {
                (S::cst(0.0), (S::cst(0.0), S::cst(0.0)))
            };
            // Into a gradient-index medium: its index where the ray enters it.
            let (eta, dense) = match &row.grin {
                Some(g) if KIND == SHAPED => {
                    let n2 = g.index(h);
                    (n1 / n2, S::cst(0.0).lt(n2))
                }
                // (Other kinds never see a medium: `surface` sends such rows here, to SHAPED.)
                _ => (eta, true),
            };
            let (dr, dead) = turn::<S, KIND>(row, d, h, nrm, eta, kick);
            let (og, dg) = if ROT {
                (row.rot.apply(h) + row.pos, row.rot.apply(dr))
            } else {
                (h + row.pos, dr)
            };
            // The first failure in the order missed, backward, vignetted, TIR; 0 if the ray goes on.
            let mut why = select_u32(dead, CODE_TIR | code, 0);
            why = select_u32(!dense, CODE_MISSED | code, why);
            why = select_u32(vignetted, CODE_VIGNETTED | code, why);
            why = select_u32(backward, CODE_BACKWARD | code, why);
            why = select_u32(!hit, CODE_MISSED | code, why);
            // A grating adds the phase m λ T y (in path length) where the ray crosses it, a
            // diffractive phase λ Φ / 2π.
            let dopl = if ruled {
                n1 * (t + ruling * phase)
            } else {
                n1 * t
            };
            commit(s, b, l, why, og, dg, dopl);
        }
    }
}

/// Where the ray at `p` going `d` (both in the image surface's frame) crosses the image plane
/// or the curved image surface: (t, hit). The scalar tracers' form of what
/// [`image_lanes`] does per lane.
#[inline(always)]
pub(crate) fn image_root<S: Real>(sys: &System<S>, p: Vec3<S>, d: Vec3<S>) -> (S, bool) {
    if sys.image_c.is_zero() {
        let hit = !d.z.is_zero();
        (-p.z / S::pick(hit, d.z, S::cst(1.0)), hit)
    } else {
        conic_root(sys.image_c, sys.image_k1, p, d)
    }
}

/// The image plane (or, `CURVED`, the curved image surface) for every lane of a group of
/// blocks, from `src` into `dst`.
#[inline(always)]
fn image_lanes<S: Real, const ROT: bool, const CURVED: bool>(
    sys: &System<S>,
    n_last: S,
    code: u32,
    src: &[Block<S>],
    dst: &mut [Block<S>],
) {
    let img = &sys.image;
    for (s, b) in src.iter().zip(dst.iter_mut()) {
        for l in 0..LANES {
            let (o, d0) = load(s, l);
            let mut p = o - img.translation;
            let mut d = d0;
            if ROT {
                p = img.rotation.apply_t(p);
                d = img.rotation.apply_t(d);
            }
            let (t, hit) = if CURVED {
                conic_root(sys.image_c, sys.image_k1, p, d)
            } else {
                let hit = !d.z.is_zero();
                (-p.z / S::pick(hit, d.z, S::cst(1.0)), hit)
            };
            let backward = !sys.image_virtual & behind(t, p);
            let h = p + d * t;
            let og = if ROT {
                img.rotation.apply(h) + img.translation
            } else {
                h + img.translation
            };
            // A ray that reaches the image with positions past the range of the numbers (a
            // surface term that overflows far from the axis) lands nowhere: a miss, never an
            // alive ray with NaN coordinates.
            let finite = og.x.value().is_finite()
                & og.y.value().is_finite()
                & og.z.value().is_finite()
                & t.value().is_finite();
            let why = select_u32(backward, CODE_BACKWARD | code, 0);
            let why = select_u32(hit & finite, why, CODE_MISSED | code);
            commit(s, b, l, why, og, d0, n_last * t);
        }
    }
}
