//! The optical path difference of a traced bundle against the reference sphere, in any number
//! type: the one computation behind [`super::wavefront`] (in `f64`) and the differentiable
//! wavefront loss of training ([`crate::optim::WavefrontLoss`], in dual numbers).

use super::Reference;
use crate::lens::paraxial::exit_pupil_from_image_lifted;
use crate::lens::{Lens, Object, Param};
use crate::math::{Rigid, Vec3};
use crate::real::Real;
use crate::trace::{RayBatch, RayStatus};

/// Why a bundle has no OPD.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum OpdFailure {
    /// The chief ray (last in the batch) did not reach the image.
    ChiefLost(RayStatus),
    /// No ray reached the image (for a centroid reference).
    NoRay,
    /// The exit pupil lies on the reference point.
    PupilOnImage,
    /// The chief ray does not meet the reference sphere.
    ChiefMissesSphere,
}

/// The OPD of the rays of a traced bundle that reach the reference sphere.
pub(crate) struct SphereOpd<S> {
    /// For each such ray: its index in the batch, its OPD in waves and its point on the sphere
    /// (global frame, mm).
    pub rays: Vec<(usize, S, Vec3<S>)>,
    /// Centre of the sphere, global frame, mm.
    pub centre: Vec3<S>,
    /// Radius of the sphere, mm.
    pub radius: S,
    /// The chief ray's point on the sphere, global frame, mm.
    pub chief_point: Vec3<S>,
}

/// The optical path from the start of the trace to where the ray was launched, added so that
/// every ray starts on one wavefront: a plane normal to the rays for an object at infinity, the
/// object point for a finite object, the sphere converging on a virtual object.
fn start_path<S: Real>(object: Object, n0: S, o: Vec3<S>, d: Vec3<S>) -> S {
    match object {
        Object::Infinite => n0 * o.dot(d),
        Object::Finite { distance_mm } if distance_mm >= 0.0 => S::cst(0.0),
        // Rays converge on the point at z = -distance_mm: the path still to go there.
        Object::Finite { distance_mm } => -n0 * (S::cst(-distance_mm) - o.z) / d.z,
    }
}

/// The exit pupil's axial distance from the image plane (mm, in the image plane's frame) of
/// `lens` with its stop at `stop`, each design parameter passed through `lift`: the paraxial
/// exit pupil at the primary wavelength, or the last vertex when that pupil is at infinity
/// (telecentric in image space).
pub(crate) fn pupil_from_image<S: Real>(
    lens: &Lens,
    stop: usize,
    lift: &dyn Fn(Param, S) -> S,
) -> S {
    let last = lens.surfaces.len() - 1;
    let z_img: f64 = lens.surfaces.iter().map(|s| s.d_next_mm).sum();
    match exit_pupil_from_image_lifted(lens, lens.primary_wavelength_nm, stop, lift) {
        Some(t) if t.value().is_finite() && t.value().abs() <= 1e6 * (1.0 + z_img.abs()) => t,
        _ => -lift(Param::Gap(last), S::cst(lens.surfaces[last].d_next_mm)),
    }
}

/// The OPD of each ray of `traced` (the chief ray last) against the reference sphere centred on
/// `reference`'s point of the image surface `image`, through the exit pupil's centre
/// `to_pupil` mm from the image plane along its normal, in waves of `wavelength_nm`: the chief
/// ray's optical path to the sphere minus the ray's. `launch` holds each ray's launch point and
/// direction (the chief ray's last), `n0` and `n_img` the indices of object and image space.
#[allow(clippy::too_many_arguments)]
pub(crate) fn sphere_opd<S: Real>(
    object: Object,
    launch: &[(Vec3<S>, Vec3<S>)],
    traced: &RayBatch<S>,
    n0: S,
    n_img: S,
    image: &Rigid<S>,
    to_pupil: S,
    reference: Reference,
    wavelength_nm: f64,
) -> Result<SphereOpd<S>, OpdFailure> {
    let m = launch.len() - 1;
    let chief = traced.get(m);
    if !chief.status.is_alive() {
        return Err(OpdFailure::ChiefLost(chief.status));
    }
    let path = |i: usize, opl: S| opl + start_path(object, n0, launch[i].0, launch[i].1);
    let centre = match reference {
        Reference::Chief => chief.o,
        Reference::Centroid => {
            let alive: Vec<Vec3<S>> = (0..m)
                .map(|i| traced.get(i))
                .filter(|r| r.status.is_alive())
                .map(|r| r.o)
                .collect();
            if alive.is_empty() {
                return Err(OpdFailure::NoRay);
            }
            let k = S::cst(1.0 / alive.len() as f64);
            alive
                .iter()
                .fold(Vec3::cst(0.0, 0.0, 0.0), |a, &p| a + p * k)
        }
    };
    let pupil_centre = image
        .rotation
        .apply(Vec3::new(S::cst(0.0), S::cst(0.0), to_pupil))
        + image.translation;
    let axis = pupil_centre - centre;
    let radius = axis.norm();
    if !(radius.value() > 0.0) || !radius.value().is_finite() {
        return Err(OpdFailure::PupilOnImage);
    }
    // A ray's point on the sphere: the root of |p + t d - c| = R on the exit pupil's side.
    let on_sphere = |p: Vec3<S>, d: Vec3<S>| -> Option<S> {
        let v = p - centre;
        let b = v.dot(d);
        let disc = b * b - (v.dot(v) - radius * radius);
        if !(disc.value() >= 0.0) {
            return None;
        }
        let s = disc.sqrt();
        let side = |t: S| (v + d * t).dot(axis).value();
        let (t1, t2) = (-b - s, -b + s);
        Some(if side(t1) >= side(t2) { t1 } else { t2 })
    };
    let t_chief = on_sphere(chief.o, chief.d).ok_or(OpdFailure::ChiefMissesSphere)?;
    let chief_point = chief.o + chief.d * t_chief;
    let ref_path = path(m, chief.opl) + n_img * t_chief;
    let lambda_mm = S::cst(wavelength_nm * 1e-6);
    let mut rays = Vec::with_capacity(m);
    for i in 0..m {
        let r = traced.get(i);
        if !r.status.is_alive() {
            continue;
        }
        let Some(t) = on_sphere(r.o, r.d) else {
            continue;
        };
        let opd = (ref_path - (path(i, r.opl) + n_img * t)) / lambda_mm;
        if opd.value().is_finite() {
            rays.push((i, opd, r.o + r.d * t));
        }
    }
    Ok(SphereOpd {
        rays,
        centre,
        radius,
        chief_point,
    })
}

/// The weighted least-squares plane `a + b x + c y` through the values `v` at the points
/// `pupil` with weights `w`: `[a, b, c]`. The normal equations depend on the points alone, so
/// the coefficients are linear in the values in any number type; `None` when the points
/// determine no plane.
pub(crate) fn plane_fit<S: Real>(pupil: &[[f64; 2]], w: &[f64], v: &[S]) -> Option<[S; 3]> {
    // M = Σ w b bᵀ with b = (1, x, y).
    let mut m = [[0.0f64; 3]; 3];
    for (p, &wi) in pupil.iter().zip(w) {
        let b = [1.0, p[0], p[1]];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] += wi * b[r] * b[c];
            }
        }
    }
    let inv = invert3(&m)?;
    let mut rhs = [S::cst(0.0); 3];
    for ((p, &wi), &v) in pupil.iter().zip(w).zip(v) {
        let b = [1.0, p[0], p[1]];
        for r in 0..3 {
            rhs[r] += v * S::cst(wi * b[r]);
        }
    }
    Some(std::array::from_fn(|r| {
        rhs[0] * S::cst(inv[r][0]) + rhs[1] * S::cst(inv[r][1]) + rhs[2] * S::cst(inv[r][2])
    }))
}

/// The RMS of `opd` (waves) about the weighted least-squares plane `a + b x + c y` over the
/// entrance-pupil points `pupil` with weights `w` (summing to 1): the RMS wavefront error to
/// centroid. The plane's normal equations depend on the points alone, so the RMS is a smooth
/// function of the OPD in any number type; `None` when the points determine no plane.
pub(crate) fn rms_about_plane<S: Real>(pupil: &[[f64; 2]], w: &[f64], opd: &[S]) -> Option<S> {
    let coef = plane_fit(pupil, w, opd)?;
    let mut ss = S::cst(0.0);
    for ((p, &wi), &v) in pupil.iter().zip(w).zip(opd) {
        let r = v - coef[0] - coef[1] * S::cst(p[0]) - coef[2] * S::cst(p[1]);
        ss += r * r * S::cst(wi);
    }
    // √ss, 0 with derivative 0 at a perfect wavefront (sqrt's chain rule would give NaN).
    Some(if ss.value() > 0.0 {
        ss.sqrt()
    } else {
        S::cst(0.0)
    })
}

/// The inverse of a 3 × 3 matrix, `None` when it is (nearly) singular.
fn invert3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let cof = |r: usize, c: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (c1, c2) = ((c + 1) % 3, (c + 2) % 3);
        m[r1][c1] * m[r2][c2] - m[r1][c2] * m[r2][c1]
    };
    let det = m[0][0] * cof(0, 0) + m[0][1] * cof(0, 1) + m[0][2] * cof(0, 2);
    let scale = m.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
    if !(det.abs() > 1e-12 * scale.powi(3)) {
        return None;
    }
    let mut inv = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            // The adjugate is the transposed cofactor matrix.
            inv[c][r] = cof(r, c) / det;
        }
    }
    Some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane is removed exactly; what is left is the RMS of the rest; the 3 × 3 inverse is one.
    #[test]
    fn rms_about_plane_removes_a_plane() {
        let pts: Vec<[f64; 2]> = (0..40)
            .map(|k| {
                let t = k as f64 * 0.7;
                let r = (k as f64 / 40.0).sqrt();
                [r * t.cos(), r * t.sin()]
            })
            .collect();
        let w = vec![1.0 / 40.0; 40];
        let plane: Vec<f64> = pts.iter().map(|p| 0.3 - 1.5 * p[0] + 2.0 * p[1]).collect();
        assert!(rms_about_plane(&pts, &w, &plane).unwrap() < 1e-13);
        // Adding ρ² − mean: its plane fit is not zero in general, so compare with a direct
        // least-squares solution by normal equations in another order.
        let bowl: Vec<f64> = pts
            .iter()
            .zip(&plane)
            .map(|(p, v)| v + p[0] * p[0] + p[1] * p[1])
            .collect();
        let got = rms_about_plane(&pts, &w, &bowl).unwrap();
        let bare: Vec<f64> = pts.iter().map(|p| p[0] * p[0] + p[1] * p[1]).collect();
        assert!((got - rms_about_plane(&pts, &w, &bare).unwrap()).abs() < 1e-13);
        assert!(got > 0.1);
        let m = [[2.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 4.0]];
        let inv = invert3(&m).unwrap();
        for r in 0..3 {
            for c in 0..3 {
                let e: f64 = (0..3).map(|k| m[r][k] * inv[k][c]).sum();
                assert!((e - f64::from(u8::from(r == c))).abs() < 1e-14);
            }
        }
        assert!(invert3(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]).is_none());
        // Collinear points determine no plane.
        let line: Vec<[f64; 2]> = (0..5).map(|k| [k as f64 * 0.1, 0.0]).collect();
        assert!(rms_about_plane(&line, &[0.2; 5], &[0.0f64; 5]).is_none());
    }
}
