//! A plain scalar `f64` reference tracer, one ray at a time, written independently of the fast
//! kernel: every surface is intersected by Newton's method on its sag function (started at the
//! vertex plane, or at the base conic's root when the plane's crossing lies beyond a steep
//! surface's rim), refraction uses the tangential-component form of Snell's law, reflection
//! reverses the normal component, and a grating adds m λ T times the groove normal to the
//! tangential component. Tests prove
//! that the kernel agrees with it.

use super::RayStatus;
use crate::lens::gradient::GradientRow;
use crate::lens::{Shape, SurfaceKind, SurfaceRow, System};
use crate::math::Vec3;

/// Result of tracing one ray to the image plane (global frame, mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefRay {
    /// Final position.
    pub o: Vec3<f64>,
    /// Final unit direction.
    pub d: Vec3<f64>,
    /// Optical path length, mm.
    pub opl: f64,
    /// Outcome.
    pub status: RayStatus,
}

fn sag(c: f64, k1: f64, asph: &[f64], u: f64) -> Option<(f64, f64)> {
    let arg = 1.0 - k1 * c * c * u;
    if arg <= 0.0 {
        return None;
    }
    let q = arg.sqrt();
    let mut z = c * u / (1.0 + q);
    let mut dz = c / (2.0 * q);
    for (j, a) in asph.iter().enumerate() {
        z += a * u.powi(j as i32 + 1);
        dz += (j + 1) as f64 * a * u.powi(j as i32);
    }
    Some((z, dz))
}

/// Sag `z` (mm) and `dz/du` of a compiled even-asphere surface at `u = x² + y²` (mm²), in its
/// local frame; `None` beyond the conic's rim. Only for [`Shape::Even`] rows (the Embree mesh).
pub fn surface_sag(row: &SurfaceRow<f64>, u: f64) -> Option<(f64, f64)> {
    sag(row.c, row.k1, &row.asph[..row.n_asph], u)
}

/// Sag `z` (mm) and `dz/du` of a compiled Q-type asphere ([`Shape::Qbfs`] or [`Shape::Qcon`]) at
/// `u = x² + y²` (mm²), in its local frame, from the polynomials' definitions term by term;
/// `None` beyond the base conic's rim or for another shape (the Embree mesh).
pub fn q_sag(row: &SurfaceRow<f64>, u: f64) -> Option<(f64, f64)> {
    let sag_and_slope = match row.shape {
        Shape::Qbfs { .. } => crate::lens::qbfs::sag_and_slope,
        Shape::Qcon { .. } => crate::lens::qcon::sag_and_slope,
        _ => return None,
    };
    sag_and_slope(
        row.c,
        row.k1 - 1.0,
        &row.asph[..row.n_asph],
        row.inv_norm2.sqrt().recip(),
        u,
    )
}

/// Where the ray at `p` going `d` (both in the image surface's frame, mm) crosses the image
/// plane or curved image surface: (distance along `d`, whether it does), as the kernel finds it.
pub fn image_crossing(sys: &System<f64>, p: Vec3<f64>, d: Vec3<f64>) -> (f64, bool) {
    crate::trace::kernel::image_root(sys, p, d)
}

/// Sag `z` (mm) and its gradient (`∂z/∂x`, `∂z/∂y`) of a compiled surface of any shape at
/// `(x, y)` in its local frame, written from the shapes' definitions term by term (powers, not
/// the kernel's Horner forms); `None` where the surface is undefined.
pub fn surface_sag_xy(row: &SurfaceRow<f64>, x: f64, y: f64) -> Option<(f64, f64, f64)> {
    let asph = &row.asph[..row.n_asph];
    match row.shape {
        Shape::Even => {
            let (z, dzu) = sag(row.c, row.k1, asph, x * x + y * y)?;
            Some((z, 2.0 * x * dzu, 2.0 * y * dzu))
        }
        Shape::Odd => {
            let u = x * x + y * y;
            let (mut z, dzu) = sag(row.c, row.k1, &[], u)?;
            let r = u.sqrt();
            // dz/dr / r of the polynomial; the cone term β1 ρ has no slope at the vertex.
            let mut slope_over_r = 2.0 * dzu;
            for (j, b) in asph.iter().enumerate() {
                let i = j as i32 + 1;
                z += b * r.powi(i);
                if i >= 2 {
                    slope_over_r += i as f64 * b * r.powi(i - 2);
                } else if r > 0.0 {
                    slope_over_r += b / r;
                }
            }
            Some((z, x * slope_over_r, y * slope_over_r))
        }
        Shape::Paraxial { .. } => Some((0.0, 0.0, 0.0)),
        Shape::Zernike {
            ordering,
            norm_radius_mm,
            decenter_mm,
            extrapolate,
        } => {
            let (mut z, dzu) = sag(row.c, row.k1, asph, x * x + y * y)?;
            let (mut gx, mut gy) = (2.0 * x * dzu, 2.0 * y * dzu);
            let terms = row.zernike.as_ref().map_or(&[][..], |t| t.terms());
            let (zz, zx, zy) = zernike_sum(
                ordering,
                terms,
                (x - decenter_mm[0]) / norm_radius_mm,
                (y - decenter_mm[1]) / norm_radius_mm,
                extrapolate,
            );
            z += zz;
            gx += zx / norm_radius_mm;
            gy += zy / norm_radius_mm;
            Some((z, gx, gy))
        }
        Shape::Qbfs { .. } | Shape::Qcon { .. } => {
            let norm = row.inv_norm2.sqrt().recip();
            let sag_and_slope = if matches!(row.shape, Shape::Qbfs { .. }) {
                crate::lens::qbfs::sag_and_slope
            } else {
                crate::lens::qcon::sag_and_slope
            };
            let (z, dzu) = sag_and_slope(row.c, row.k1 - 1.0, asph, norm, x * x + y * y)?;
            Some((z, 2.0 * x * dzu, 2.0 * y * dzu))
        }
        Shape::Toroidal { .. } => {
            // The y-z profile, rotated about the axis parallel to y at z = 1 / c_rot: with
            // R = 1 / c_rot, z = R - sqrt((R - z_y)² - x²) on the vertex side.
            let (zy, dzu) = sag(row.c, row.k1, asph, y * y)?;
            let dzy = 2.0 * y * dzu;
            if row.c_rot == 0.0 {
                return Some((zy, 0.0, dzy));
            }
            let rr = 1.0 / row.c_rot;
            let w = rr - zy;
            let s2 = w * w - x * x;
            if !(s2 > 0.0) {
                return None;
            }
            let s = s2.sqrt().copysign(w);
            Some((rr - s, x / s, w * dzy / s))
        }
    }
}

/// `Σ A_j Z_j` and its gradient in the normalized coordinates (X, Y), from the polar
/// definitions: each term's normalisation times R_n^m(ρ) times cos mθ or sin mθ, differentiated
/// by ∂/∂X = cos θ ∂/∂ρ − (sin θ / ρ) ∂/∂θ and ∂/∂Y = sin θ ∂/∂ρ + (cos θ / ρ) ∂/∂θ; at ρ = 0
/// only the m = 1 terms have a slope, R_n^1'(0) along x (cosine) or y (sine).
fn zernike_sum(
    ordering: crate::math::zernike::Ordering,
    terms: &[f64],
    px: f64,
    py: f64,
    extrapolate: bool,
) -> (f64, f64, f64) {
    use crate::math::zernike::{radial, term_nm, Ordering};
    let rho = px.hypot(py);
    if !extrapolate && rho > 1.0 {
        return (0.0, 0.0, 0.0);
    }
    let theta = py.atan2(px);
    let fact = |k: usize| (1..=k).map(|v| v as f64).product::<f64>();
    let (mut z, mut gx, mut gy) = (0.0, 0.0, 0.0);
    for (j, &a) in terms.iter().enumerate() {
        let (n, m, sine) = term_nm(ordering, j + 1);
        let norm = match ordering {
            Ordering::Standard if m == 0 => ((n + 1) as f64).sqrt(),
            Ordering::Standard => (2.0 * (n + 1) as f64).sqrt(),
            Ordering::Fringe => 1.0,
        };
        // dR/dρ from R's definition, term by term.
        let mut dr = 0.0;
        for k in 0..=(n - m) / 2 {
            let c = fact(n - k) / (fact(k) * fact((n + m) / 2 - k) * fact((n - m) / 2 - k));
            let p = n - 2 * k;
            if p >= 1 {
                let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
                dr += sign * c * p as f64 * rho.powi(p as i32 - 1);
            }
        }
        let r = radial(n, m, rho);
        let mt = m as f64 * theta;
        let (ang, dang) = match (m, sine) {
            (0, _) => (1.0, 0.0),
            (_, false) => (mt.cos(), -(m as f64) * mt.sin()),
            (_, true) => (mt.sin(), m as f64 * mt.cos()),
        };
        z += a * norm * r * ang;
        if rho > 0.0 {
            let (dz_drho, dz_dtheta) = (norm * dr * ang, norm * r * dang);
            let (c, s) = (px / rho, py / rho);
            gx += a * (c * dz_drho - s * dz_dtheta / rho);
            gy += a * (s * dz_drho + c * dz_dtheta / rho);
        } else if m == 1 {
            if sine {
                gy += a * norm * dr;
            } else {
                gx += a * norm * dr;
            }
        }
    }
    (z, gx, gy)
}

/// A radial phase `Φ = Σ c_i ρ^(2i)` (`c` = M A_1, M A_2, ...; ρ = r / `rn`) and its gradient
/// at `h`'s (x, y), from the powers of r term by term (dΦ/dr x / r, with the limit 0 at the
/// vertex).
fn radial_phase(c: &[f64], rn: f64, h: Vec3<f64>) -> (f64, f64, f64) {
    let (x, y) = (h.x, h.y);
    let r = x.hypot(y);
    let (mut phi, mut dphi_dr) = (0.0, 0.0);
    for (i, ci) in c.iter().enumerate() {
        let k = 2 * (i as i32 + 1);
        phi += ci * (r / rn).powi(k);
        dphi_dr += ci * k as f64 * r.powi(k - 1) / rn.powi(k);
    }
    if r > 0.0 {
        (phi, dphi_dr * x / r, dphi_dr * y / r)
    } else {
        (phi, 0.0, 0.0)
    }
}

/// Intersects the local-frame ray `p + t dl` with the surface of `row` by Newton's method on the
/// sag, started at the vertex plane, or, when that start fails (the ray crosses the vertex
/// plane beyond a steep surface's rim, where the sag is undefined, though it meets the surface
/// nearer the axis), at the base conic's vertex-side intersection nearest that crossing.
/// Returns `t` and the sag's gradient (`∂z/∂x`, `∂z/∂y`) at the hit, or `None` when the ray is
/// parallel to the vertex plane or Newton does not converge from either start (a miss).
pub fn intersect_local(
    row: &SurfaceRow<f64>,
    p: Vec3<f64>,
    dl: Vec3<f64>,
) -> Option<(f64, [f64; 2])> {
    if dl.z == 0.0 {
        return None;
    }
    let t = -p.z / dl.z;
    if row.kind == SurfaceKind::Plane {
        return Some((t, [0.0; 2]));
    }
    newton(row, p, dl, t).or_else(|| newton(row, p, dl, conic_start(row, p, dl, t)?))
}

/// The unit normal of a surface with sag gradient `g`, pointing toward +z.
pub fn unit_normal(g: [f64; 2]) -> Vec3<f64> {
    Vec3::new(-g[0], -g[1], 1.0).normalized()
}

/// Newton on `z(t) - sag(x(t), y(t))` from `t`.
fn newton(row: &SurfaceRow<f64>, p: Vec3<f64>, dl: Vec3<f64>, t: f64) -> Option<(f64, [f64; 2])> {
    let mut t = t;
    for _ in 0..100 {
        let h = p + dl * t;
        let (z, zx, zy) = surface_sag_xy(row, h.x, h.y)?;
        let f = h.z - z;
        let fp = dl.z - (zx * dl.x + zy * dl.y);
        let step = f / fp;
        t -= step;
        if step.abs() < 1e-13 * (1.0 + t.abs()) {
            let h = p + dl * t;
            // An overflowing slope gives no normal: a miss (as the kernel).
            return surface_sag_xy(row, h.x, h.y)
                .filter(|&(_, zx, zy)| zx.is_finite() && zy.is_finite())
                .map(|(_, zx, zy)| (t, [zx, zy]));
        }
    }
    None
}

/// The root of the base conic `c (x² + y² + k₁ z²) - 2 z = 0` (`k₁ = 1 + κ`, `row.k1`) along
/// `p + t dl` on its vertex side (`c k₁ z < 1`) nearest `t0`.
fn conic_start(row: &SurfaceRow<f64>, p: Vec3<f64>, dl: Vec3<f64>, t0: f64) -> Option<f64> {
    let (c, k) = (row.c, row.k1);
    let a = c * (dl.x * dl.x + dl.y * dl.y + k * dl.z * dl.z);
    let b = 2.0 * (c * (p.x * dl.x + p.y * dl.y + k * p.z * dl.z) - dl.z);
    let cc = c * (p.x * p.x + p.y * p.y + k * p.z * p.z) - 2.0 * p.z;
    let disc = b * b - 4.0 * a * cc;
    if !(disc >= 0.0) {
        return None;
    }
    let q = -0.5 * (b + disc.sqrt().copysign(b));
    [q / a, cc / q]
        .into_iter()
        .filter(|t| t.is_finite() && c * k * (p.z + dl.z * t) < 1.0)
        .min_by(|x, y| (x - t0).abs().total_cmp(&(y - t0).abs()))
}

/// Refracts the unit direction `dl` at a surface with unit normal `nrm` from index `n1` into
/// `n2` (Snell's law on the tangential component). `None` on total internal reflection.
pub fn refract(dl: Vec3<f64>, nrm: Vec3<f64>, n1: f64, n2: f64) -> Option<Vec3<f64>> {
    diffract(dl, nrm, n1, n2, Vec3::new(0.0, 0.0, 0.0), false)
}

/// Leaves a surface with unit normal `nrm` from index `n1` into `n2` with the tangential
/// component `n2 t' = n1 t + k_t` (the grating equation, `kick` = m λ T ŷ, or a diffractive
/// phase's, `kick` = λ ∇Φ / 2π; 0 for plain refraction), where `k_t` is `kick` projected on the
/// tangent plane; the normal
/// component follows from `|d'| = 1`, on the far side (`reflect` false, `n2` the index behind) or
/// back on the near side (`reflect` true, `n2 = n1`). `None` when no such direction exists
/// (total internal reflection, an order that does not propagate).
pub fn diffract(
    dl: Vec3<f64>,
    nrm: Vec3<f64>,
    n1: f64,
    n2: f64,
    kick: Vec3<f64>,
    reflect: bool,
) -> Option<Vec3<f64>> {
    let cos1 = dl.dot(nrm);
    let kick_t = kick - nrm * kick.dot(nrm);
    let tang = ((dl - nrm * cos1) * n1 + kick_t) * (1.0 / n2);
    let s2 = tang.dot(tang);
    if s2 > 1.0 {
        return None;
    }
    let side = if reflect {
        -cos1.signum()
    } else {
        cos1.signum()
    };
    Some(tang + nrm * ((1.0 - s2).sqrt() * side))
}

/// The direction in which a ray of direction `dl` (surface frame) leaves surface `row` where it
/// meets it at `h` with unit normal `nrm`, from index `n1` into `n2` (the index after the
/// surface; a mirror keeps `n1`), and the path length the surface adds (a grating's phase
/// m λ T y, a diffractive phase's λ Φ / 2π, else 0): a grating or a phase diffracts, an ideal thin lens turns the slopes by minus the
/// height over its focal length, a mirror reflects, a refracting surface obeys Snell's law, a
/// bare aperture passes the ray. `None` for total internal reflection or an order that does not
/// propagate. The one rule of the reference tracer and of the Embree check.
pub fn bend(
    row: &SurfaceRow<f64>,
    dl: Vec3<f64>,
    h: Vec3<f64>,
    nrm: Vec3<f64>,
    n1: f64,
    n2: f64,
    wavelength_nm: f64,
) -> Option<(Vec3<f64>, f64)> {
    if let Some(g) = row.grating {
        let n2 = if row.reflect { n1 } else { n2 };
        let m_lambda_t = g.deflection(wavelength_nm);
        // The grating's phase, as path length: m λ T y at the crossing.
        let kick = Vec3::new(0.0, m_lambda_t, 0.0);
        return diffract(dl, nrm, n1, n2, kick, row.reflect).map(|v| (v, m_lambda_t * h.y));
    }
    if let Some(p) = &row.phase {
        let n2 = if row.reflect { n1 } else { n2 };
        let (phi, gx, gy) = radial_phase(p.order_times_coefficients(), p.norm_radius_mm(), h);
        // The phase as path length, λ Φ / 2π, and the kick λ ∇Φ / 2π (λ in mm).
        let l = wavelength_nm * 1e-6 / std::f64::consts::TAU;
        let kick = Vec3::new(l * gx, l * gy, 0.0);
        return diffract(dl, nrm, n1, n2, kick, row.reflect).map(|v| (v, l * phi));
    }
    let dn = if let Shape::Paraxial { focal_mm } = row.shape {
        // The ideal thin lens: slopes change by minus the height over the focal length.
        let (mx, my) = (dl.x / dl.z - h.x / focal_mm, dl.y / dl.z - h.y / focal_mm);
        Vec3::new(mx, my, 1.0).normalized() * dl.z.signum()
    } else if row.reflect {
        // The law of reflection: the normal component reverses.
        dl - nrm * (2.0 * dl.dot(nrm))
    } else if row.refract {
        // Snell on the tangential component.
        refract(dl, nrm, n1, n2)?
    } else {
        dl
    };
    Some((dn, 0.0))
}

/// The points (global frame) a ray at `o` going `d` on surface `i` passes through in the
/// gradient-index medium after it, one per integration step, up to where it meets surface
/// `i + 1` (that point included); empty when the medium is homogeneous or the ray does not get
/// through. For drawing the curved paths (the lens layout).
///
/// ```
/// use tolray::lens::{Gradient, GradientForm, Material, Surface};
/// use tolray::math::Vec3;
/// let mut lens = tolray::Lens::load("lens1").unwrap();
/// let rod = Gradient::radial(GradientForm::Index, 1.6, &[-0.05], 0.05);
/// lens.surfaces = vec![
///     Surface::sphere(0.0, 1.0, 3.0, Material::Gradient(Box::new(rod))),
///     Surface::sphere(0.0, 1.0, 2.0, Material::Air),
/// ];
/// let sys = lens.compile();
/// let (o, d) = (Vec3::new(0.0, 0.5, 0.0), Vec3::new(0.0, 0.0, 1.0));
/// let path = tolray::trace::reference::gradient_path(&sys, 0, o, d);
/// // About 3 mm / 0.05 mm steps; the ray bends toward the axis (the index falls outward).
/// assert!(path.len() > 50);
/// let end = path.last().unwrap();
/// assert!((end.z - 3.0).abs() < 1e-12 && end.y < 0.5);
/// ```
pub fn gradient_path(sys: &System<f64>, i: usize, o: Vec3<f64>, d: Vec3<f64>) -> Vec<Vec3<f64>> {
    let (Some((entry, g)), Some(row)) = (sys.gradient_before(i + 1), sys.rows.get(i + 1)) else {
        return Vec::new();
    };
    let mut points = Vec::new();
    match through_medium(entry, g, row, o, d, Some(&mut points)) {
        Ok(_) => points,
        Err(_) => Vec::new(),
    }
}

/// A ray at `o` going `d` (global frame, on the surface `entry`) through the gradient-index
/// medium `g` to the surface `row`: where it meets `row` and its unit direction there (both in
/// `row`'s frame), the sag gradient there, the medium's index there and the path's optical
/// length; or the status for surface code `i`. With `record`, the points it passes (global
/// frame), one per step, and the crossing.
///
/// Written apart from the kernel's integrator: the classical Runge-Kutta method on the
/// first-order ray equations in arc length s (dR/ds = T / n, dT/ds = ∇n, dL/ds = n, with T = n
/// times the unit direction), steps of the medium's length along the ray, and the crossing
/// found by bisecting the last step's length.
#[allow(clippy::type_complexity)]
fn through_medium(
    entry: &SurfaceRow<f64>,
    g: &GradientRow<f64>,
    row: &SurfaceRow<f64>,
    o: Vec3<f64>,
    d: Vec3<f64>,
    mut record: Option<&mut Vec<Vec3<f64>>>,
) -> Result<(Vec3<f64>, Vec3<f64>, [f64; 2], f64, f64), fn(u32) -> RayStatus> {
    // State: position, optical direction, optical length (medium frame).
    type State = (Vec3<f64>, Vec3<f64>, f64);
    let rate = |(r, t, _): State| -> Option<State> {
        let (n2, force) = g.n2_and_force(r);
        (n2 > 0.0).then(|| {
            let n = n2.sqrt();
            (t * (1.0 / n), force * (1.0 / n), n)
        })
    };
    let rk4 = |y: State, h: f64| -> Option<State> {
        let add = |a: State, k: State, s: f64| (a.0 + k.0 * s, a.1 + k.1 * s, a.2 + k.2 * s);
        let k1 = rate(y)?;
        let k2 = rate(add(y, k1, h / 2.0))?;
        let k3 = rate(add(y, k2, h / 2.0))?;
        let k4 = rate(add(y, k3, h))?;
        let sum = add(add(add(k1, k2, 2.0), k3, 2.0), k4, 1.0);
        Some(add(y, sum, h / 6.0))
    };
    let to_row = |r: Vec3<f64>| row.rot.apply_t(entry.rot.apply(r) + entry.pos - row.pos);
    let past = |r: Vec3<f64>| {
        let q = to_row(r);
        surface_sag_xy(row, q.x, q.y).map(|(z, _, _)| q.z - z)
    };
    let r0 = entry.rot.apply_t(o - entry.pos);
    let n0 = g.index(r0);
    if !(n0 > 0.0) {
        return Err(RayStatus::Missed);
    }
    let mut y: State = (r0, entry.rot.apply_t(d) * n0, 0.0);
    if !past(r0).is_some_and(|f| f < 0.0) {
        return Err(RayStatus::Backward);
    }
    let missed: fn(u32) -> RayStatus = RayStatus::Missed;
    let h = g.dt * n0;
    let mut steps = 0;
    loop {
        let next = rk4(y, h).ok_or(missed)?;
        match past(next.0) {
            Some(f) if f >= 0.0 => break,
            _ if steps >= g.max_steps => return Err(missed),
            _ => {}
        }
        y = next;
        steps += 1;
        if let Some(r) = record.as_deref_mut() {
            r.push(entry.rot.apply(y.0) + entry.pos);
        }
    }
    // Bisection on the last step's length: `lo` before the surface, `hi` past it.
    let (mut lo, mut hi) = (0.0, h);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        let s = rk4(y, mid).ok_or(missed)?;
        if past(s.0).is_some_and(|f| f >= 0.0) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let (r, t, opl) = rk4(y, hi).ok_or(missed)?;
    let q = to_row(r);
    let (_, gx, gy) = surface_sag_xy(row, q.x, q.y).ok_or(missed)?;
    let dir = row.rot.apply_t(entry.rot.apply(t)).normalized();
    if let Some(points) = record {
        points.push(row.rot.apply(q) + row.pos);
    }
    Ok((q, dir, [gx, gy], g.index(r), opl))
}

/// Traces one ray of `wavelength_nm` through `sys` with indices `n` (as [`System::indices`]
/// gives them at that wavelength: the object medium's, then the one after each surface), up to
/// and including surface `upto` (or to the image plane when `upto` is `None`). Returns the state
/// in the global frame after that surface.
pub fn trace_ray(
    sys: &System<f64>,
    n: &[f64],
    wavelength_nm: f64,
    o: Vec3<f64>,
    d: Vec3<f64>,
    clip: bool,
    upto: Option<usize>,
) -> RefRay {
    let mut o = o;
    let mut d = d.normalized();
    let mut opl = 0.0;
    let last = upto.map_or(sys.rows.len(), |u| u + 1).min(sys.rows.len());
    for (i, row) in sys.rows.iter().enumerate().take(last) {
        let fail = |status| RefRay { o, d, opl, status };
        // Where the ray meets the surface, in its frame: straight, or through a gradient-index
        // medium (then also the direction there, the path's optical length and the index).
        let (h, dl, grad, n1, path) = match sys.gradient_before(i) {
            Some((entry, g)) => match through_medium(entry, g, row, o, d, None) {
                Ok(hit) => hit,
                Err(status) => return fail(status(i as u32)),
            },
            None => {
                let p = row.rot.apply_t(o - row.pos);
                let dl = row.rot.apply_t(d);
                let Some((t, grad)) = intersect_local(row, p, dl) else {
                    return fail(RayStatus::Missed(i as u32));
                };
                if !row.virtual_ok && crate::trace::kernel::behind(t, p) {
                    return fail(RayStatus::Backward(i as u32));
                }
                (p + dl * t, dl, grad, n[i], n[i] * t)
            }
        };
        if clip && row.clip.stops(h.x, h.y) {
            return fail(RayStatus::Vignetted(i as u32));
        }
        let n2 = match &row.grin {
            Some(g) => g.index(h),
            None => n[i + 1],
        };
        if !(n2 > 0.0) {
            return fail(RayStatus::Missed(i as u32));
        }
        let Some((dn, phase)) = bend(row, dl, h, unit_normal(grad), n1, n2, wavelength_nm) else {
            return fail(RayStatus::Tir(i as u32));
        };
        opl += phase;
        opl += path;
        o = row.rot.apply(h) + row.pos;
        d = row.rot.apply(dn);
    }
    if upto.is_some_and(|u| u < sys.rows.len()) {
        return RefRay {
            o,
            d,
            opl,
            status: RayStatus::Alive,
        };
    }
    let p = sys.image.point_to_local(o);
    let dl = sys.image.rotation.apply_t(d);
    let (t, hit) = crate::trace::kernel::image_root(sys, p, dl);
    let g = sys.image.point_to_global(p + dl * t);
    // (As the kernel: a crossing past the range of the numbers is a miss.)
    if !(hit && t.is_finite() && g.x.is_finite() && g.y.is_finite() && g.z.is_finite()) {
        return RefRay {
            o,
            d,
            opl,
            status: RayStatus::Missed(sys.rows.len() as u32),
        };
    }
    if !sys.image_virtual && crate::trace::kernel::behind(t, p) {
        return RefRay {
            o,
            d,
            opl,
            status: RayStatus::Backward(sys.rows.len() as u32),
        };
    }
    opl += n.last().copied().unwrap_or(1.0) * t;
    RefRay {
        o: g,
        d,
        opl,
        status: RayStatus::Alive,
    }
}
