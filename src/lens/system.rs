//! The compiled lens: an immutable flat table of surfaces in one number type.

use super::gradient::GradientRow;
use super::phase::PhaseRow;
use super::zernike::ZernikeSag;
use super::{Aperture, ApertureShape, Grating, Lens, Material, Shape, N_ASPH};
use crate::math::{Mat3, Rigid, Vec3};
use crate::real::Real;

/// Which intersection routine a surface needs; chosen once at compile time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceKind {
    /// Flat (c = 0, no asphere terms): one division.
    Plane,
    /// Sphere or conic: closed-form, cancellation-free quadratic.
    Quadric,
    /// Even asphere: Newton's method started from the quadric solution.
    Asphere,
}

/// A design parameter of a lens, for compiling with overridden (e.g. dual-number) values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Param {
    /// Curvature of surface `i`, 1/mm.
    Curvature(usize),
    /// Conic constant of surface `i`.
    Conic(usize),
    /// Asphere coefficient `j` of surface `i`: [`crate::lens::Surface::asph`]`[j]` (0 = a2,
    /// 1 = a4, ... on an even asphere; β(j+1) on an odd asphere; the y^(2j+2) term of a toroid).
    Asphere(usize, usize),
    /// Gap after surface `i`, mm (the last surface's gap is the image distance).
    Gap(usize),
    /// n_d of the model glass after surface `i`.
    GlassNd(usize),
    /// Zernike coefficient `j` of surface `i` (mm): [`crate::lens::Surface::zernike`]`[j]`, the
    /// coefficient of Z_(j+1) on a Zernike sag surface.
    Zernike(usize, usize),
    /// Diffractive phase coefficient `j` of surface `i` (radians): the A_(j+1) on ρ^(2j+2) of
    /// [`crate::lens::Surface::phase`].
    Phase(usize, usize),
    /// V_d of the model glass after surface `i`.
    GlassVd(usize),
    /// Coefficient `j` of the gradient-index medium after surface `i`
    /// ([`crate::lens::Gradient`]): 0 = n0, 1 to 6 the terms on r², ..., r¹², 7 to 9 those on z,
    /// z², z³.
    Gradient(usize, usize),
}

/// Rigid motions and curvature offsets applied to a nominal lens (tolerances, placements).
///
/// A motion maps the nominal global frame to the moved one: a surface's placement becomes
/// `motion ∘ nominal placement`. The nominal [`Lens`] is never edited.
#[derive(Clone, Debug, PartialEq)]
pub struct Adjustments {
    /// One rigid motion per surface.
    pub surface_motion: Vec<Rigid<f64>>,
    /// Curvature offset per surface, 1/mm.
    pub curvature_offset: Vec<f64>,
    /// Relative curvature error per surface (a fraction: the curvature becomes
    /// `c · (1 + curvature_error) + curvature_offset`). Tolerance patterns use it, so that a
    /// pattern's curvature error scales with the design's curvature in gradients too.
    pub curvature_error: Vec<f64>,
    /// Rigid motion of the image plane.
    pub image_motion: Rigid<f64>,
}

impl Adjustments {
    /// No adjustment for a lens of `n` surfaces.
    pub fn none(n: usize) -> Self {
        Adjustments {
            surface_motion: vec![Rigid::identity(); n],
            curvature_offset: vec![0.0; n],
            curvature_error: vec![0.0; n],
            image_motion: Rigid::identity(),
        }
    }
}

/// A compiled hard aperture, tested without branches: a ray at local `(x, y)` is inside when,
/// with `(u, v) = (x - dx, y - dy)`, `u² + q v² <= r2_max`, `u² + v² >= r2_min`, `|u| <= hx` and
/// `|v| <= hy` (unused bounds are infinite); it is stopped when `on` and inside equals
/// `obscuration`.
#[derive(Clone, Copy, Debug)]
pub struct Clip<S> {
    /// False when the surface does not clip.
    pub on: bool,
    /// True for an obscuration.
    pub obscuration: bool,
    /// Decenter, mm.
    pub dx: S,
    /// Decenter, mm.
    pub dy: S,
    /// Ellipse axis ratio squared (a²/b²; 1 for circles).
    pub q: S,
    /// Outer bound of `u² + q v²`, mm².
    pub r2_max: S,
    /// Inner bound of `u² + v²`, mm².
    pub r2_min: S,
    /// Half-width in x, mm.
    pub hx: S,
    /// Half-width in y, mm.
    pub hy: S,
    /// Largest radius at which a ray passes, mm (infinite without a clip or for obscurations).
    pub reach_mm: f64,
}

impl<S: Real> Clip<S> {
    /// Compiles `aperture` (`None`: no clipping) for a surface of semi-diameter `semi_mm`.
    pub fn new(aperture: Option<Aperture>, semi_mm: f64) -> Clip<S> {
        let inf = f64::INFINITY;
        let (q, r2_max, r2_min, hx, hy) = match aperture.map(|a| a.shape) {
            None => (1.0, inf, 0.0, inf, inf),
            Some(ApertureShape::SemiDiameter) => (1.0, semi_mm * semi_mm, 0.0, inf, inf),
            Some(ApertureShape::Circular { min_mm, max_mm }) => {
                (1.0, max_mm * max_mm, min_mm * min_mm, inf, inf)
            }
            Some(ApertureShape::Rectangular {
                half_x_mm,
                half_y_mm,
            }) => (1.0, inf, 0.0, half_x_mm, half_y_mm),
            Some(ApertureShape::Elliptical {
                half_x_mm,
                half_y_mm,
            }) => (
                (half_x_mm / half_y_mm).powi(2),
                half_x_mm * half_x_mm,
                0.0,
                inf,
                inf,
            ),
        };
        let d = aperture.map_or([0.0; 2], |a| a.decenter_mm);
        Clip {
            on: aperture.is_some(),
            obscuration: aperture.is_some_and(|a| a.obscuration),
            dx: S::cst(d[0]),
            dy: S::cst(d[1]),
            q: S::cst(q),
            r2_max: S::cst(r2_max),
            r2_min: S::cst(r2_min),
            hx: S::cst(hx),
            hy: S::cst(hy),
            reach_mm: aperture.map_or(inf, |a| a.reach_mm(semi_mm)),
        }
    }

    /// True when a ray crossing the surface at local `(x, y)` is stopped (branch-free).
    #[inline(always)]
    pub fn stops(&self, x: S, y: S) -> bool {
        let (u, v) = (x - self.dx, y - self.dy);
        let (u2, v2) = (u * u, v * v);
        let inside = !self.r2_max.lt(u2 + self.q * v2)
            & !(u2 + v2).lt(self.r2_min)
            & !self.hx.lt(u.abs())
            & !self.hy.lt(v.abs());
        self.on & (inside == self.obscuration)
    }

    /// The same clip in another number type.
    pub fn convert<T: Real>(&self) -> Clip<T> {
        Clip {
            on: self.on,
            obscuration: self.obscuration,
            dx: T::cst(self.dx.value()),
            dy: T::cst(self.dy.value()),
            q: T::cst(self.q.value()),
            r2_max: T::cst(self.r2_max.value()),
            r2_min: T::cst(self.r2_min.value()),
            hx: T::cst(self.hx.value()),
            hy: T::cst(self.hy.value()),
            reach_mm: self.reach_mm,
        }
    }
}

/// One compiled surface.
#[derive(Clone, Debug)]
pub struct SurfaceRow<S> {
    /// Intersection routine.
    pub kind: SurfaceKind,
    /// False for bare apertures (rays pass unrefracted).
    pub refract: bool,
    /// True for a mirror: rays reflect instead of refracting.
    pub reflect: bool,
    /// Curvature (with any offset), 1/mm.
    pub c: S,
    /// 1 + conic constant.
    pub k1: S,
    /// Asphere coefficients a2..a16.
    pub asph: [S; N_ASPH],
    /// Number of leading asphere coefficients in use.
    pub n_asph: usize,
    /// The sag's form (what `asph` means); anything but [`Shape::Even`] is traced by the
    /// asphere routine.
    pub shape: Shape,
    /// The Zernike terms of a [`Shape::Zernike`] surface, merged for evaluation (`None`
    /// otherwise).
    pub zernike: Option<Box<ZernikeSag<S>>>,
    /// The surface's diffractive phase, compiled (`None` without one).
    pub phase: Option<Box<PhaseRow<S>>>,
    /// Curvature of a toroid's rotation, 1/mm (0 otherwise).
    pub c_rot: S,
    /// 1 / a Q-type asphere's normalization radius², 1/mm² (0 otherwise).
    pub inv_norm2: S,
    /// Power of an ideal thin lens (1 / focal length), 1/mm; 0 otherwise. Such a surface is a
    /// [`SurfaceKind::Plane`] that turns each ray's slopes by minus its height times the power.
    pub power: S,
    /// Squared semi-diameter, mm² (the surface's size; clipping is [`SurfaceRow::clip`]).
    pub ap2: S,
    /// The hard aperture (or the stop's semi-diameter) that clips rays here.
    pub clip: Clip<S>,
    /// True if the surface frame is rotated relative to the global frame.
    pub rotated: bool,
    /// Local-to-global rotation.
    pub rot: Mat3<S>,
    /// Vertex position in the global frame, mm.
    pub pos: Vec3<S>,
    /// True when the gap before this surface runs against the direction of travel (negative
    /// before any mirror, positive after one): the lens asks for virtual propagation (as Zemax
    /// allows), so an intersection behind the ray is accepted.
    /// Otherwise a ray that would have to travel backwards to reach the surface stops with
    /// [`crate::trace::RayStatus::Backward`].
    pub virtual_ok: bool,
    /// The grating ruled on the surface, if any (grooves along the surface frame's x axis).
    pub grating: Option<Grating>,
    /// The gradient-index medium after the surface, compiled (`None` for a homogeneous one).
    pub grin: Option<Box<GradientRow<S>>>,
}

/// A compiled lens: flat, immutable, in number type `S`.
#[derive(Clone, Debug)]
pub struct System<S> {
    /// The surfaces, counted from 0.
    pub rows: Vec<SurfaceRow<S>>,
    /// Placement of the image plane (its local z is the plane's normal).
    pub image: Rigid<S>,
    /// True if the image plane is rotated.
    pub image_rotated: bool,
    /// True when the last gap runs against the travel (a virtual image plane; see
    /// [`SurfaceRow::virtual_ok`]).
    pub image_virtual: bool,
    /// Vertex curvature of a curved image surface, 1/mm (0: the plane).
    pub image_c: S,
    /// 1 + the conic constant of a curved image surface.
    pub image_k1: S,
    /// Medium in front of the first surface (object space).
    pub object_medium: Material,
    /// Medium after each surface.
    pub materials: Vec<Material>,
    /// Lifted (n_d, V_d) of each model glass (None for other materials), so that indices carry
    /// glass derivatives.
    pub model_glass: Vec<Option<(S, S)>>,
    /// Index of the aperture-stop surface, if any.
    pub stop: Option<usize>,
}

/// Rotation taking +z to the unit vector `v` by the shortest arc.
pub(crate) fn rotation_to(v: [f64; 3]) -> Mat3<f64> {
    let n: Vec3<f64> = Vec3::cst(v[0], v[1], v[2]).normalized();
    let (x, y) = (n.x, n.y);
    let s2 = x * x + y * y;
    if s2 == 0.0 {
        return Mat3::identity();
    }
    let c = n.z;
    let f = (1.0 - c) / s2;
    Mat3 {
        rows: [
            Vec3::new(1.0 - f * x * x, -f * x * y, x),
            Vec3::new(-f * x * y, 1.0 - f * y * y, y),
            Vec3::new(-x, -y, c),
        ],
    }
}

/// A surface's (or the image plane's) frame: +z turned onto `axis` by the shortest arc after a
/// roll of `roll_deg` about z.
pub(crate) fn frame_rotation(axis: [f64; 3], roll_deg: f64) -> Mat3<f64> {
    if roll_deg == 0.0 {
        rotation_to(axis)
    } else {
        rotation_to(axis) * Mat3::rot_z(roll_deg.to_radians())
    }
}

/// The turn of `frame` about its own axis beyond the shortest-arc turn of +z onto `axis` (the
/// `roll_deg` that [`frame_rotation`] takes), degrees.
pub(crate) fn roll_of(frame: &Mat3<f64>, axis: [f64; 3]) -> f64 {
    let m = rotation_to(axis).transpose() * *frame;
    let r = m.rows[1].x.atan2(m.rows[0].x).to_degrees();
    if r.abs() > 1e-10 {
        r
    } else {
        0.0
    }
}

/// Tilts about x, then the new y, then the new z (degrees; a .zmx coordinate break with order
/// flag 0): `Rx(a) Ry(b) Rz(g)`.
pub(crate) fn rotation_xyz_deg([a, b, g]: [f64; 3]) -> Mat3<f64> {
    Mat3::rot_x(a.to_radians()) * Mat3::rot_y(b.to_radians()) * Mat3::rot_z(g.to_radians())
}

/// `r` with entries within 1e-15 of 0, 1 or -1 set to them (a turn by a multiple of 90° then
/// is exact).
pub(crate) fn clean_rotation(r: Mat3<f64>) -> Mat3<f64> {
    let snap = |v: f64| {
        if v.abs() <= 1e-15 {
            0.0
        } else if (v.abs() - 1.0).abs() <= 1e-15 {
            v.signum()
        } else {
            v
        }
    };
    Mat3 {
        rows: r.rows.map(|v| Vec3::new(snap(v.x), snap(v.y), snap(v.z))),
    }
}

fn is_identity(m: &Mat3<f64>) -> bool {
    *m == Mat3::identity()
}

impl<S: Real> System<S> {
    /// Compiles `lens` with `adj` applied; `lift` turns each design parameter's value into an `S`
    /// (identity for values, a seeded dual number for gradients).
    pub fn compile(lens: &Lens, adj: &Adjustments, lift: &dyn Fn(Param, S) -> S) -> System<S> {
        let mut z = S::cst(0.0);
        let dirs = lens.travel_directions();
        let mut rows = Vec::with_capacity(lens.surfaces.len());
        let lift_c = |m: Mat3<f64>| Mat3 {
            rows: m.rows.map(|r| r.map_value::<S>()),
        };
        // The frame of the current leg of the axis (unfolded coordinates to global): the
        // identity until a fold mirror turns it.
        let mut leg_rot = Mat3::<f64>::identity();
        let mut leg_t = Vec3::new(S::cst(0.0), S::cst(0.0), S::cst(0.0));
        let mut folded = false;
        for (i, s) in lens.surfaces.iter().enumerate() {
            let r0 = frame_rotation(s.vec_local, s.roll_deg);
            let motion = &adj.surface_motion[i];
            let nominal = Vec3::new(S::cst(s.pos_xy_mm[0]), S::cst(s.pos_xy_mm[1]), z);
            let mut rot = motion.rotation * r0;
            let mut pos =
                motion.translation.map_value::<S>() + lift_c(motion.rotation).apply(nominal);
            if folded {
                rot = leg_rot * rot;
                pos = lift_c(leg_rot).apply(pos) + leg_t;
            }
            if let Some(f) = s.fold {
                // The next leg turns about the axis point `pivot_mm` past this vertex:
                // x ↦ leg(p + R (x - p)).
                let r = f.rotation();
                let p = Vec3::new(S::cst(0.0), S::cst(0.0), z + S::cst(f.pivot_mm));
                leg_t = leg_t + lift_c(leg_rot).apply(p - lift_c(r).apply(p));
                leg_rot = leg_rot * r;
                folded = true;
            }
            let c = lift(Param::Curvature(i), S::cst(s.c)) * S::cst(1.0 + adj.curvature_error[i])
                + S::cst(adj.curvature_offset[i]);
            let k = lift(Param::Conic(i), S::cst(s.k));
            let mut asph = [S::cst(0.0); N_ASPH];
            for (j, a) in asph.iter_mut().enumerate() {
                *a = lift(Param::Asphere(i, j), S::cst(s.asph[j]));
            }
            // A coefficient being differentiated counts as in use even at zero, so that its
            // derivative (the sag term it switches on) is not lost with the asphere routine.
            let n_asph = asph
                .iter()
                .rposition(|a| a.value() != 0.0 || !a.is_constant())
                .map_or(0, |j| j + 1);
            let zernike_terms: Vec<S> = (s.zernike.iter().enumerate())
                .map(|(j, &a)| lift(Param::Zernike(i, j), S::cst(a)))
                .collect();
            let zernike = s.shape.zernike_sag(&zernike_terms).map(Box::new);
            let phase = s.phase.as_ref().map(|ph| {
                let a: Vec<S> = (ph.coefficients.iter().enumerate())
                    .map(|(j, &a)| lift(Param::Phase(i, j), S::cst(a)))
                    .collect();
                Box::new(PhaseRow::new(ph, &a))
            });
            // Flat refracting surfaces use the quadric routine, which is exact at c = 0 and keeps
            // curvature derivatives; only bare apertures take the plane shortcut.
            let kind = if matches!(s.shape, Shape::Paraxial { .. }) {
                SurfaceKind::Plane
            } else if n_asph > 0 || s.shape != Shape::Even {
                SurfaceKind::Asphere
            } else if !lens.refracts(i) {
                SurfaceKind::Plane
            } else {
                SurfaceKind::Quadric
            };
            rows.push(SurfaceRow {
                kind,
                refract: lens.refracts(i),
                reflect: lens.reflects(i),
                c,
                k1: S::cst(1.0) + k,
                asph,
                n_asph,
                shape: s.shape,
                zernike,
                phase,
                c_rot: S::cst(match s.shape {
                    Shape::Toroidal { c_rot } => c_rot,
                    _ => 0.0,
                }),
                inv_norm2: S::cst(match s.shape.norm_radius_mm() {
                    Some(norm_radius_mm) => 1.0 / (norm_radius_mm * norm_radius_mm),
                    None => 0.0,
                }),
                power: S::cst(match s.shape {
                    Shape::Paraxial { focal_mm } => 1.0 / focal_mm,
                    _ => 0.0,
                }),
                ap2: S::cst(s.semi_aperture_mm * s.semi_aperture_mm),
                clip: Clip::new(s.clipping_aperture(), s.semi_aperture_mm),
                rotated: !is_identity(&rot),
                rot: lift_c(rot),
                pos,
                virtual_ok: i > 0 && lens.surfaces[i - 1].d_next_mm * dirs[i] < 0.0,
                grating: s.grating,
                grin: match &s.material {
                    Material::Gradient(g) => Some(Box::new(
                        GradientRow::new(g, i, lift).limit_steps(s.d_next_mm, g.step_mm),
                    )),
                    _ => None,
                },
            });
            z += lift(Param::Gap(i), S::cst(s.d_next_mm));
        }
        // The image plane: its nominal pose (decenter, tilt, roll), then the perturbation's
        // motion in the global frame.
        let m = &adj.image_motion;
        let ip = &lens.image_plane;
        let [dx, dy] = ip.decenter_mm;
        let mut rotation = m.rotation * frame_rotation(ip.normal, ip.roll_deg);
        let mut translation = m.translation.map_value::<S>()
            + lift_c(m.rotation).apply(Vec3::new(S::cst(dx), S::cst(dy), z));
        if folded {
            rotation = leg_rot * rotation;
            translation = lift_c(leg_rot).apply(translation) + leg_t;
        }
        let image = Rigid {
            rotation: lift_c(rotation),
            translation,
        };
        System {
            rows,
            image,
            image_rotated: !is_identity(&rotation),
            image_virtual: lens
                .surfaces
                .last()
                .is_some_and(|s| s.d_next_mm * dirs[dirs.len() - 1] < 0.0),
            image_c: S::cst(ip.curvature_per_mm),
            image_k1: S::cst(1.0 + ip.conic),
            object_medium: lens.object_medium.clone(),
            materials: lens.surfaces.iter().map(|s| s.material.clone()).collect(),
            model_glass: lens
                .surfaces
                .iter()
                .enumerate()
                .map(|(i, s)| match s.material {
                    Material::Model { nd, vd } => Some((
                        lift(Param::GlassNd(i), S::cst(nd)),
                        lift(Param::GlassVd(i), S::cst(vd)),
                    )),
                    _ => None,
                })
                .collect(),
            stop: lens.stop_index(),
        }
    }

    /// The surface before surface `i` and its gradient-index medium, when one ends at `i`.
    ///
    /// ```
    /// use tolray::lens::{Gradient, GradientForm, Material, Surface};
    /// let mut lens = tolray::Lens::load("lens1").unwrap();
    /// let rod = Gradient::radial(GradientForm::Index, 1.6, &[-0.05], 0.05);
    /// lens.surfaces = vec![
    ///     Surface::sphere(0.0, 1.0, 3.0, Material::Gradient(Box::new(rod))),
    ///     Surface::sphere(0.0, 1.0, 2.0, Material::Air),
    /// ];
    /// let sys = lens.compile();
    /// assert!(sys.gradient_before(1).is_some() && sys.gradient_before(0).is_none());
    /// ```
    pub fn gradient_before(&self, i: usize) -> Option<(&SurfaceRow<S>, &GradientRow<S>)> {
        let entry = self.rows.get(i.checked_sub(1)?)?;
        entry.grin.as_deref().map(|g| (entry, g))
    }

    /// Refractive indices at `wavelength_nm`: `n[0]` of the object medium, then `n[i + 1]`
    /// after surface `i` (so surface `i` goes from `n[i]` to `n[i + 1]`; `rows.len() + 1`
    /// values).
    pub fn indices(&self, wavelength_nm: f64) -> Vec<S> {
        let after = self
            .materials
            .iter()
            .zip(&self.model_glass)
            .map(|(m, g)| match g {
                // The model glass' Cauchy law, evaluated in S.
                Some((nd, vd)) => crate::lens::material::model_index(*nd, *vd, wavelength_nm),
                None => S::cst(m.index(wavelength_nm)),
            });
        std::iter::once(S::cst(self.object_medium.index(wavelength_nm)))
            .chain(after)
            .collect()
    }

    /// The first medium without a usable index at `wavelength_nm`
    /// ([`crate::lens::material::is_usable_index`], as [`crate::Lens::check_indices`] asks): its place in [`System::indices`] (0 the object
    /// medium, `i + 1` the medium after surface `i`) and its index; `None` when all are usable.
    ///
    /// ```
    /// let sys = tolray::lens::builtin("lens1").unwrap().compile();
    /// assert_eq!(sys.unusable_index(587.6), None);
    /// assert!(sys.unusable_index(1e-300).is_some());
    /// ```
    pub fn unusable_index(&self, wavelength_nm: f64) -> Option<(usize, f64)> {
        self.indices(wavelength_nm)
            .iter()
            .map(|n| n.value())
            .enumerate()
            .find(|&(_, n)| !crate::lens::material::is_usable_index(n))
    }

    /// The same system in another number type (derivatives dropped).
    pub fn convert<T: Real>(&self) -> System<T> {
        let m3 = |m: &Mat3<S>| Mat3 {
            rows: m.rows.map(|r| r.map_value::<T>()),
        };
        System {
            rows: self
                .rows
                .iter()
                .map(|r| SurfaceRow {
                    kind: r.kind,
                    refract: r.refract,
                    reflect: r.reflect,
                    c: T::cst(r.c.value()),
                    k1: T::cst(r.k1.value()),
                    asph: r.asph.map(|a| T::cst(a.value())),
                    n_asph: r.n_asph,
                    shape: r.shape,
                    zernike: r.zernike.as_ref().map(|z| Box::new(z.convert())),
                    phase: r.phase.as_ref().map(|p| Box::new(p.convert())),
                    c_rot: T::cst(r.c_rot.value()),
                    inv_norm2: T::cst(r.inv_norm2.value()),
                    power: T::cst(r.power.value()),
                    ap2: T::cst(r.ap2.value()),
                    clip: r.clip.convert(),
                    rotated: r.rotated,
                    rot: m3(&r.rot),
                    pos: r.pos.map_value(),
                    virtual_ok: r.virtual_ok,
                    grating: r.grating,
                    grin: r.grin.as_ref().map(|g| Box::new(g.convert())),
                })
                .collect(),
            image: Rigid {
                rotation: m3(&self.image.rotation),
                translation: self.image.translation.map_value(),
            },
            image_rotated: self.image_rotated,
            image_virtual: self.image_virtual,
            image_c: T::cst(self.image_c.value()),
            image_k1: T::cst(self.image_k1.value()),
            object_medium: self.object_medium.clone(),
            materials: self.materials.clone(),
            model_glass: self
                .model_glass
                .iter()
                .map(|g| g.map(|(n, v)| (T::cst(n.value()), T::cst(v.value()))))
                .collect(),
            stop: self.stop,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_to_maps_z_onto_v() {
        let v = [0.1, -0.2, 0.97];
        let n: f64 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
        let r = rotation_to(v);
        let z = r.apply(Vec3::cst(0.0, 0.0, 1.0));
        let s = n.sqrt();
        assert!((z.x - v[0] / s).abs() < 1e-15 && (z.y - v[1] / s).abs() < 1e-15);
        let i = r.transpose() * r;
        assert!((i.rows[0].x - 1.0).abs() < 1e-15 && i.rows[0].y.abs() < 1e-15);
    }
}
