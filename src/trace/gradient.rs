//! The pass through a gradient-index medium to the surface that ends it, one lane at a time
//! (the medium and its integrator: [`crate::lens::gradient`]).
//!
//! Each ray starts where it left the surface before the medium (the medium's frame is that
//! surface's), takes Runge-Kutta-Nyström steps of the medium's length until it has crossed the
//! next surface, and then finds the length of its last step by Newton's method on the next
//! surface's sag, so that it ends on the surface. The Newton slope is the step's end direction,
//! which differs from the step's exact derivative by a few parts in a thousand; the iteration
//! runs three steps past the value's convergence, which makes the carried derivatives those of
//! the converged step (each step shrinks their error by that same factor). There the ray is
//! clipped and refracted as in the kernel, with the index the medium has at that point.

use super::kernel::{commit, load, sag_xy, select_u32, turn, SHAPED};
use super::{Block, CODE_BACKWARD, CODE_MISSED, CODE_TIR, CODE_VIGNETTED, LANES};
use crate::lens::gradient::GradientRow;
use crate::lens::SurfaceRow;
use crate::math::{Mat3, Vec3};
use crate::real::Real;

/// Where a ray ends in the medium before surface `row`: its crossing `q`, optical direction
/// `dir` (n times the unit direction) and the surface's slopes `zx`, `zy` there, in `row`'s
/// frame; the optical path gained and the medium's index there.
struct Exit<S> {
    q: Vec3<S>,
    dir: Vec3<S>,
    zx: S,
    zy: S,
    opl: S,
    n: S,
}

/// The medium's frame (the entry surface's) to the exit surface's: x ↦ `rot` x + `shift`.
struct ToExit<S> {
    rot: Mat3<S>,
    shift: Vec3<S>,
}

/// Traces every lane of `src` from the surface `entry` through its medium `g` to the surface
/// `row` and across it into `dst`; `n_out` is the index after `row` (unless another
/// gradient-index medium follows it), `code` its surface code.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
pub(super) fn exit_pass<S: Real>(
    entry: &SurfaceRow<S>,
    g: &GradientRow<S>,
    row: &SurfaceRow<S>,
    n_out: S,
    code: u32,
    clip: bool,
    src: &[Block<S>],
    dst: &mut [Block<S>],
) {
    let to_exit = ToExit {
        rot: row.rot.transpose() * entry.rot,
        shift: row.rot.apply_t(entry.pos - row.pos),
    };
    for (s, b) in src.iter().zip(dst.iter_mut()) {
        for l in 0..LANES {
            let (o, d0) = load(s, l);
            if s.status[l] != 0 {
                commit(s, b, l, 0, o, d0, S::cst(0.0));
                continue;
            }
            let e = match through(entry, g, row, &to_exit, o, d0) {
                Ok(e) => e,
                Err(why) => {
                    commit(s, b, l, why | code, o, d0, S::cst(0.0));
                    continue;
                }
            };
            let nrm = Vec3::new(e.zx, e.zy, -S::cst(1.0));
            let d = e.dir * (S::cst(1.0) / e.dir.dot(e.dir).sqrt());
            let n2 = match &row.grin {
                Some(next) => next.index(e.q),
                None => n_out,
            };
            let vignetted = clip & row.clip.stops(e.q.x, e.q.y);
            let zero = S::cst(0.0);
            let (dr, tir) = turn::<S, SHAPED>(row, d, e.q, nrm, e.n / n2, (zero, zero));
            let (og, dg) = (row.rot.apply(e.q) + row.pos, row.rot.apply(dr));
            let mut why = select_u32(tir, CODE_TIR | code, 0);
            why = select_u32(vignetted, CODE_VIGNETTED | code, why);
            why = select_u32(!zero.lt(n2), CODE_MISSED | code, why);
            commit(s, b, l, why, og, dg, e.opl);
        }
    }
}

/// The ray at `o` going `d` (global frame, on the surface `entry`) through `g` to `row`.
fn through<S: Real>(
    entry: &SurfaceRow<S>,
    g: &GradientRow<S>,
    row: &SurfaceRow<S>,
    to_exit: &ToExit<S>,
    o: Vec3<S>,
    d: Vec3<S>,
) -> Result<Exit<S>, u32> {
    let zero = S::cst(0.0);
    let p0 = entry.rot.apply_t(o - entry.pos);
    let d = entry.rot.apply_t(d);
    // The exit surface's equation in the medium's frame: f < 0 before it, with (-∂z/∂x,
    // -∂z/∂y, 1) its gradient in its own frame.
    let surface = |p: Vec3<S>| {
        let q = to_exit.rot.apply(p) + to_exit.shift;
        let (z, zx, zy, ok) = sag_xy(row, q.x, q.y);
        (q, q.z - z, zx, zy, ok)
    };
    let n_start = g.index(p0);
    if !zero.lt(n_start) {
        return Err(CODE_MISSED);
    }
    let (mut p, mut tv, mut opl) = (p0, d * n_start, zero);
    let (_, mut f0, _, _, _) = surface(p);
    if !f0.lt(zero) {
        // Already on or past the surface that ends the medium (the two faces cross here).
        return Err(CODE_BACKWARD);
    }
    let h = S::cst(g.dt);
    let mut crossed = None;
    for _ in 0..g.max_steps {
        let (p1, t1, dl, ok) = g.step(p, tv, h);
        let (_, f1, _, _, in_rim) = surface(p1);
        if !ok || !f1.value().is_finite() {
            return Err(CODE_MISSED);
        }
        if !f1.lt(zero) && in_rim {
            crossed = Some(f1);
            break;
        }
        (p, tv, opl, f0) = (p1, t1, opl + dl, f1);
    }
    let Some(f1) = crossed else {
        // Trapped in the medium, or past the exit surface's rim.
        return Err(CODE_MISSED);
    };
    // The last step's length: from the chord's estimate, Newton on f(step(s)).
    let mut s = h * f0 / (f0 - f1);
    let mut extra = 0;
    for _ in 0..60 {
        let (p1, t1, _, _) = g.step(p, tv, s);
        let (_, f, zx, zy, _) = surface(p1);
        let v = to_exit.rot.apply(t1);
        let slope = v.z - zx * v.x - zy * v.y;
        let ds = f / slope;
        s -= ds;
        // Rounding in f: a few units in the last place of the coordinates.
        let tol = 16.0
            * S::EPSILON
            * (1.0 + p1.x.value().abs() + p1.y.value().abs() + p1.z.value().abs());
        if !(ds.value().abs() > tol) {
            extra += 1;
            if extra == 3 {
                break;
            }
        }
    }
    let (p1, t1, dl, ok) = g.step(p, tv, s);
    let (q, _, zx, zy, in_rim) = surface(p1);
    if extra == 0 || !ok || !in_rim || s.value() < 0.0 {
        return Err(CODE_MISSED);
    }
    Ok(Exit {
        q,
        dir: to_exit.rot.apply(t1),
        zx,
        zy,
        opl: opl + dl,
        n: g.index(p1),
    })
}
