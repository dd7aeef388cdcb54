//! The tracing kernel, written once for every number type.
//!
//! Per surface: move the ray into the surface frame (translation, then the inverse rotation when
//! the surface is rotated), intersect (plane, cancellation-free quadric, or Newton for an even
//! asphere started from the quadric root), clip at the clear aperture, refract by the vector
//! form of Snell's law, and move back. Conditions are evaluated on values and applied as
//! selects; a dead ray keeps its last state and its status.

use super::{Block, CODE_MISSED, CODE_TIR, CODE_VIGNETTED, LANES};
use crate::lens::{SurfaceKind, SurfaceRow, System};
use crate::math::Vec3;
use crate::real::Real;

const PLANE: u8 = 0;
const QUADRIC: u8 = 1;
const ASPHERE: u8 = 2;

/// A number type the tracer can run on. `f32` and `f64` override [`Traceable::trace_blocks`] with
/// builds for several instruction sets chosen at run time; other types use the generic build.
pub trait Traceable: Real {
    /// Traces `blocks` through `sys` with refractive indices `n` (after each surface).
    fn trace_blocks(sys: &System<Self>, n: &[Self], clip: bool, blocks: &mut [Block<Self>]) {
        trace_blocks_generic(sys, n, clip, blocks);
    }
}

#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.2"))]
fn trace_blocks_f32(sys: &System<f32>, n: &[f32], clip: bool, blocks: &mut [Block<f32>]) {
    trace_blocks_generic(sys, n, clip, blocks);
}

#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.2"))]
fn trace_blocks_f64(sys: &System<f64>, n: &[f64], clip: bool, blocks: &mut [Block<f64>]) {
    trace_blocks_generic(sys, n, clip, blocks);
}

impl Traceable for f32 {
    fn trace_blocks(sys: &System<f32>, n: &[f32], clip: bool, blocks: &mut [Block<f32>]) {
        trace_blocks_f32(sys, n, clip, blocks);
    }
}

impl Traceable for f64 {
    fn trace_blocks(sys: &System<f64>, n: &[f64], clip: bool, blocks: &mut [Block<f64>]) {
        trace_blocks_f64(sys, n, clip, blocks);
    }
}

/// The generic block loop: surfaces outside, lanes inside.
#[inline(always)]
pub(crate) fn trace_blocks_generic<S: Real>(
    sys: &System<S>,
    n: &[S],
    clip: bool,
    blocks: &mut [Block<S>],
) {
    for b in blocks.iter_mut() {
        for (i, row) in sys.rows.iter().enumerate() {
            let n1 = if i == 0 { S::cst(1.0) } else { n[i - 1] };
            let eta = n1 / n[i];
            let code = i as u32;
            macro_rules! go {
                ($kind:expr, $rot:expr, $clip:expr) => {
                    lanes::<S, { $kind }, { $rot }, { $clip }>(row, n1, eta, code, b)
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
        let n_last = n.last().copied().unwrap_or(S::cst(1.0));
        image_lanes(sys, n_last, sys.rows.len() as u32, b);
    }
}

/// The lane-loop trip count, hidden from LLVM's full unroller: a fully unrolled 16-lane loop is
/// left to the SLP vectorizer, which fails on this body, while the loop vectorizer succeeds.
#[inline(always)]
fn lane_count() -> usize {
    std::hint::black_box(LANES).min(LANES)
}

#[inline(always)]
fn load<S: Real>(b: &Block<S>, l: usize) -> (Vec3<S>, Vec3<S>) {
    (
        Vec3::new(b.o[0][l], b.o[1][l], b.o[2][l]),
        Vec3::new(b.d[0][l], b.d[1][l], b.d[2][l]),
    )
}

#[inline(always)]
fn store<S: Real>(b: &mut Block<S>, l: usize, keep: bool, o: Vec3<S>, d: Vec3<S>, dopl: S) {
    let s = |old: S, new: S| S::pick(keep, new, old);
    b.o[0][l] = s(b.o[0][l], o.x);
    b.o[1][l] = s(b.o[1][l], o.y);
    b.o[2][l] = s(b.o[2][l], o.z);
    b.d[0][l] = s(b.d[0][l], d.x);
    b.d[1][l] = s(b.d[1][l], d.y);
    b.d[2][l] = s(b.d[2][l], d.z);
    b.opl[l] = s(b.opl[l], b.opl[l] + dopl);
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

/// Intersection in the surface frame: returns (t, ok, unnormalized normal pointing toward -z).
#[inline(always)]
fn intersect<S: Real, const KIND: u8>(
    row: &SurfaceRow<S>,
    p: Vec3<S>,
    d: Vec3<S>,
) -> (S, bool, Vec3<S>) {
    let zero = S::cst(0.0);
    let one = S::cst(1.0);
    if KIND == PLANE {
        let t = -p.z / d.z;
        return (t, !d.z.is_zero(), Vec3::new(zero, zero, -one));
    }
    // Quadric c (x² + y² + k1 z²) - 2 z = 0, solved from the ray's crossing of the vertex plane
    // (where the constant term is small). Of the two roots this takes the one nearest that
    // crossing, without cancellation; it tends to the plane solution as c -> 0.
    let (c, k1) = (row.c, row.k1);
    let mut ok = !d.z.is_zero();
    let t0 = -p.z / S::pick(ok, d.z, one);
    let (x0, y0) = (p.x + d.x * t0, p.y + d.y * t0);
    let a = c * (d.x * d.x + d.y * d.y + k1 * d.z * d.z);
    let b = c * (x0 * d.x + y0 * d.y) - d.z;
    let cc = c * (x0 * x0 + y0 * y0);
    let disc = b * b - a * cc;
    ok &= !disc.lt(zero);
    let s = S::pick(ok, disc, zero).sqrt();
    let den = b + s.copysign(b);
    ok &= !den.is_zero();
    let mut t = t0 - cc / S::pick(ok, den, one);
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
    ok &= converged && in_rim;
    let two = S::cst(2.0);
    (t, ok, Vec3::new(two * h.x * dz, two * h.y * dz, -one))
}

/// One surface for every lane of a block. `KIND`, `ROT` (rotated frame) and `CLIP` (apertures
/// on) are compile-time so that the lane loop has no control flow left and vectorizes. A plane
/// surface is a bare aperture: it clips but never refracts.
#[inline(always)]
fn lanes<S: Real, const KIND: u8, const ROT: bool, const CLIP: bool>(
    row: &SurfaceRow<S>,
    n1: S,
    eta: S,
    code: u32,
    b: &mut Block<S>,
) {
    let one = S::cst(1.0);
    let zero = S::cst(0.0);
    for l in 0..lane_count() {
        let (o, d0) = load(b, l);
        let mut p = o - row.pos;
        let mut d = d0;
        if ROT {
            p = row.rot.apply_t(p);
            d = row.rot.apply_t(d);
        }
        let (t, hit, nrm) = intersect::<S, KIND>(row, p, d);
        let h = p + d * t;
        let vignetted = CLIP && row.ap2.lt(h.x * h.x + h.y * h.y);
        // Refraction (vector Snell). The normal is flipped to face the incoming ray.
        let nrm = nrm * (one / nrm.norm());
        let mut cosi = -nrm.dot(d);
        let flip = cosi.lt(zero);
        cosi = S::pick(flip, -cosi, cosi);
        let nrm = Vec3::new(
            S::pick(flip, -nrm.x, nrm.x),
            S::pick(flip, -nrm.y, nrm.y),
            S::pick(flip, -nrm.z, nrm.z),
        );
        let k = one - eta * eta * (one - cosi * cosi);
        let tir = KIND != PLANE && k.lt(zero);
        let g = eta * cosi - S::pick(tir, zero, k).sqrt();
        let dr = if KIND != PLANE { d * eta + nrm * g } else { d };
        let (og, dg) = if ROT {
            (row.rot.apply(h) + row.pos, row.rot.apply(dr))
        } else {
            (h + row.pos, dr)
        };
        let alive = b.status[l] == 0;
        let new_status = if !hit {
            CODE_MISSED | code
        } else if vignetted {
            CODE_VIGNETTED | code
        } else if tir {
            CODE_TIR | code
        } else {
            0
        };
        let keep = alive && new_status == 0;
        b.status[l] = if alive { new_status } else { b.status[l] };
        store(b, l, keep, og, dg, n1 * t);
    }
}

#[inline(always)]
fn image_lanes<S: Real>(sys: &System<S>, n_last: S, code: u32, b: &mut Block<S>) {
    let img = &sys.image;
    for l in 0..lane_count() {
        let (o, d0) = load(b, l);
        let mut p = o - img.translation;
        let mut d = d0;
        if sys.image_rotated {
            p = img.rotation.apply_t(p);
            d = img.rotation.apply_t(d);
        }
        let hit = !d.z.is_zero();
        let t = -p.z / S::pick(hit, d.z, S::cst(1.0));
        let h = p + d * t;
        let og = if sys.image_rotated {
            img.rotation.apply(h) + img.translation
        } else {
            h + img.translation
        };
        let alive = b.status[l] == 0;
        let keep = alive && hit;
        b.status[l] = if alive && !hit {
            CODE_MISSED | code
        } else {
            b.status[l]
        };
        store(b, l, keep, og, d0, n_last * t);
    }
}
