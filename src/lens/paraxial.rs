//! First-order (paraxial) optics by y-nu ray tracing.

use super::material::model_index;
use super::{Lens, Material, Object, Param, Shape};
use crate::error::{Error, Result};
use crate::real::Real;
use serde::Serialize;

/// First-order properties of a lens at one wavelength. Lengths in mm; axial positions are global
/// z (first vertex at 0, light toward +z).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Paraxial {
    /// Wavelength of the analysis, nm.
    pub wavelength_nm: f64,
    /// Optical power Φ = 1 / EFL, 1/mm: 0 for an afocal lens.
    pub power_per_mm: f64,
    /// Effective focal length 1/Φ, mm: OpticStudio's "Effective Focal Length (in air)"; `None`
    /// for an afocal lens (no focal length).
    pub efl_mm: Option<f64>,
    /// Effective focal length in image space n'/Φ, mm: OpticStudio's "Effective Focal Length
    /// (in image space)", with the image-space index n' signed as OpticStudio signs it
    /// (negative after an odd number of mirrors), so 1.333 times [`Paraxial::efl_mm`] for an
    /// image in water and negative for a single concave mirror; `None` for an afocal lens.
    ///
    /// ```
    /// let p = tolray::Lens::load("lens1").unwrap().paraxial(587.5618).unwrap();
    /// assert_eq!(p.efl_image_space_mm, p.efl_mm); // an image in air
    /// ```
    pub efl_image_space_mm: Option<f64>,
    /// Back focal distance: last vertex to the paraxial infinity focus, mm; `None` for an
    /// afocal lens.
    pub bfd_mm: Option<f64>,
    /// Last vertex to the paraxial image of the stated object, mm (= BFD for an object at
    /// infinity); `None` when that image is at infinity (an afocal lens and an object at
    /// infinity).
    pub image_distance_mm: Option<f64>,
    /// Axial position of the entrance pupil, mm.
    pub entrance_pupil_z_mm: f64,
    /// Entrance pupil diameter, mm.
    pub entrance_pupil_diameter_mm: f64,
    /// Axial position of the exit pupil, mm (infinite for a lens telecentric in image space).
    pub exit_pupil_z_mm: f64,
    /// Exit pupil diameter, mm (infinite for a lens telecentric in image space).
    pub exit_pupil_diameter_mm: f64,
    /// Image-space F-number for an object at infinity, EFL / EPD; `None` for an afocal lens.
    pub fnum: Option<f64>,
    /// Working (paraxial) F-number for the stated object, 1 / (2 |u'|); `None` when the image
    /// is at infinity (an afocal lens and an object at infinity).
    pub working_fnum: Option<f64>,
    /// Paraxial lateral magnification for the stated object (0 at infinity).
    pub magnification: f64,
    /// Angular magnification of an afocal lens, the ratio u' / u of a paraxial ray's slopes
    /// leaving and entering it (negative for an image turned over, as a Keplerian telescope's);
    /// `None` for a lens with a focal length.
    pub angular_magnification: Option<f64>,
    /// Half field of view from the sensor's half-diagonal, degrees: atan(r_sensor / EFL);
    /// `None` for an afocal lens.
    pub half_fov_deg: Option<f64>,
    /// Index of the aperture-stop surface (the marked stop, or the limiting aperture).
    pub stop_surface: usize,
    /// First vertex to the image plane, mm.
    pub total_track_mm: f64,
    /// The paraxial chief ray's height on the image plane for a unit field, at the primary
    /// wavelength (whatever the analysis' wavelength, so that a field means the same rays at
    /// every wavelength): a field angle of tangent 1 (object at infinity; the ray rising,
    /// OpticStudio's sign) or an object height of 1 mm (finite object), in mm (mm per mm).
    /// Divides an image-height field ([`crate::trace::Field::ImageHeightMm`]) into an angle or
    /// an object height.
    pub chief_image_height_mm: f64,
}

impl Paraxial {
    /// True for an afocal lens (no optical power: a parallel beam leaves parallel).
    ///
    /// ```
    /// let p = tolray::Lens::load("lens1").unwrap().paraxial(587.5618).unwrap();
    /// assert!(!p.is_afocal() && p.efl_mm.is_some());
    /// ```
    pub fn is_afocal(&self) -> bool {
        self.angular_magnification.is_some()
    }

    /// The effective focal length, or an error saying the lens is afocal (for what needs one:
    /// `what`, e.g. "a field given as a fraction of the sensor").
    ///
    /// # Errors
    /// [`crate::ErrorKind::Numerical`] for an afocal lens.
    pub fn focal_length_for(&self, what: &str) -> Result<f64> {
        self.efl_mm.ok_or_else(|| {
            Error::numerical(format!(
                "the lens is afocal (no focal length; angular magnification {:.6}), so {what} \
                 is not defined",
                self.angular_magnification.unwrap_or(0.0)
            ))
        })
    }
}

/// Paraxial heights at every surface and the final height and slope after the last one.
struct Ynu<S> {
    heights: Vec<S>,
    y_last: S,
    u_last: S,
}

/// What a paraxial trace reads of a lens, in number type `S`: the paraxial curvature c + 2 a2
/// of each surface, whether it bends rays, the signed index after it and the gap after it.
///
/// `n` holds the signed indices of [`signed_indices`]: a mirror is a refraction into `-n`, and
/// the gaps after it are negative, so the y-nu equations hold unchanged through mirrors.
struct Prescription<S> {
    curvature: Vec<S>,
    /// Power of an ideal thin lens (n / f), 0 for other surfaces.
    thin_power: Vec<S>,
    bends: Vec<bool>,
    n: Vec<S>,
    gap: Vec<S>,
    /// Through a gradient-index medium after a surface: the transfer matrix of (y, n u) and
    /// the axial index where it ends (`None` for a homogeneous medium).
    medium: Vec<Option<([S; 4], S)>>,
    /// Index of the object medium.
    n_object: S,
}

impl Prescription<f64> {
    fn of(lens: &Lens, wavelength_nm: f64) -> Self {
        Prescription::lifted(lens, wavelength_nm, &|_, v| v)
    }
}

impl<S: Real> Prescription<S> {
    /// The prescription of `lens` with each design parameter passed through `lift` (as
    /// [`crate::lens::System::compile`] does), so that dual numbers carry its derivatives.
    fn lifted(lens: &Lens, wavelength_nm: f64, lift: &dyn Fn(Param, S) -> S) -> Self {
        let dirs = lens.travel_directions();
        let mut p = Prescription {
            curvature: Vec::with_capacity(lens.surfaces.len()),
            thin_power: Vec::with_capacity(lens.surfaces.len()),
            bends: Vec::with_capacity(lens.surfaces.len()),
            n: Vec::with_capacity(lens.surfaces.len()),
            gap: Vec::with_capacity(lens.surfaces.len()),
            medium: Vec::with_capacity(lens.surfaces.len()),
            n_object: S::cst(lens.object_medium.index(wavelength_nm)),
        };
        for (i, s) in lens.surfaces.iter().enumerate() {
            let c = lift(Param::Curvature(i), S::cst(s.c));
            // The ρ² terms add 2 Σ w_j a_j to the vertex curvature (y² for a toroid: the
            // paraxial trace is in the y-z plane, as OpticStudio's; Qbfs: every Q_m(0)).
            let mut c_par = c;
            for (j, w) in s.shape.r2_weights().into_iter().enumerate() {
                if w != 0.0 {
                    let a = lift(Param::Asphere(i, j), S::cst(s.asph[j]));
                    c_par += S::cst(2.0 * w) * a;
                }
            }
            // A Zernike sag surface's terms add their y² coefficients at the vertex, and their
            // sag there moves the vertex along the axis (the gaps before and after it).
            let mut vertex_sag = S::cst(0.0);
            for (j, [z0, w]) in s.zernike_vertex_weights().into_iter().enumerate() {
                if w != 0.0 || z0 != 0.0 {
                    let a = lift(Param::Zernike(i, j), S::cst(s.zernike[j]));
                    c_par += S::cst(2.0 * w) * a;
                    vertex_sag += S::cst(z0) * a;
                }
            }
            if let Some(g) = p.gap.last_mut() {
                *g += vertex_sag;
            }
            p.curvature.push(c_par);
            // An ideal thin lens in a medium of (signed) index n: n u' = n u - y n / f.
            let mut thin = match s.shape {
                Shape::Paraxial { focal_mm } => {
                    let n_before = match i {
                        0 => p.n_object,
                        _ => p.n_exit(i - 1),
                    };
                    n_before / S::cst(focal_mm)
                }
                _ => S::cst(0.0),
            };
            // A diffractive phase M Σ A_i ρ^(2i) kicks n u by λ ∂Φ/∂y / 2π = y λ M A_1 / (π R²)
            // near the axis: a thin power −M λ A_1 / (π R²), mirror or not.
            if let Some(ph) = &s.phase {
                if let Some(&a1) = ph.coefficients.first() {
                    let a1 = lift(Param::Phase(i, 0), S::cst(a1));
                    let k = -ph.order * wavelength_nm * 1e-6
                        / (std::f64::consts::PI * ph.norm_radius_mm * ph.norm_radius_mm);
                    thin += S::cst(k) * a1;
                }
            }
            p.thin_power.push(thin);
            p.bends.push(lens.refracts(i));
            let gap = lift(Param::Gap(i), S::cst(s.d_next_mm)) - vertex_sag;
            let mut medium = None;
            let n = match s.material {
                Material::Model { nd, vd } => model_index(
                    lift(Param::GlassNd(i), S::cst(nd)),
                    lift(Param::GlassVd(i), S::cst(vd)),
                    wavelength_nm,
                ),
                // Validation keeps mirrors away from these media: their indices are unsigned.
                Material::Gradient(ref g) => {
                    let (m, n_in, n_out) =
                        super::gradient::GradientRow::new(g, i, lift).paraxial_transfer(gap);
                    medium = Some((m, n_out));
                    n_in
                }
                ref m => S::cst(m.index(wavelength_nm)),
            };
            p.n.push(n * S::cst(dirs[i + 1]));
            p.medium.push(medium);
            p.gap.push(gap);
        }
        p
    }

    /// A paraxial ray's height and slope at the vertex plane of surface `i + 1` from those
    /// leaving surface `i`'s.
    fn across(&self, i: usize, y: S, u: S) -> (S, S) {
        match &self.medium[i] {
            Some(([a, b, c, d], n_end)) => {
                let w = self.n[i] * u;
                (*a * y + *b * w, (*c * y + *d * w) / *n_end)
            }
            None => (y + u * self.gap[i], u),
        }
    }

    /// The (signed) index where the medium after surface `i` ends.
    fn n_exit(&self, i: usize) -> S {
        self.medium[i].map_or(self.n[i], |(_, n)| n)
    }

    /// Traces a paraxial ray that arrives at the vertex plane of surface `start` (before
    /// refracting there) with height `y0` and slope `u0`; heights of surfaces before `start` are
    /// left 0.
    fn ynu(&self, start: usize, y0: S, u0: S) -> Ynu<S> {
        let (mut y, mut u) = (y0, u0);
        let mut heights = vec![S::cst(0.0); self.n.len()];
        let last = self.n.len() - 1;
        for i in start..self.n.len() {
            heights[i] = y;
            let n0 = if i == 0 {
                self.n_object
            } else {
                self.n_exit(i - 1)
            };
            if self.bends[i] {
                let power = self.curvature[i] * (self.n[i] - n0) + self.thin_power[i];
                u = (n0 * u - y * power) / self.n[i];
            }
            if i < last {
                (y, u) = self.across(i, y, u);
            }
        }
        Ynu {
            heights,
            y_last: y,
            u_last: u,
        }
    }

    /// The effective focal length of a unit-height parallel ray, -1 / (n' u') (n' = -1 after an
    /// odd number of mirrors), and that ray.
    fn efl(&self) -> (S, Ynu<S>) {
        let n_last = self.n[self.n.len() - 1];
        let parallel = self.ynu(0, S::cst(1.0), S::cst(0.0));
        (S::cst(-1.0) / (n_last * parallel.u_last), parallel)
    }

    /// The entrance pupil's axial position and radius for the stop surface `stop` of
    /// semi-diameter `r_stop`: the stop's image in object space, from the heights there of the
    /// unit-height `parallel` ray (of [`Prescription::efl`]) and of a ray through the first
    /// vertex.
    fn pupil(&self, parallel: &Ynu<S>, stop: usize, r_stop: f64) -> (S, S) {
        let a = parallel.heights[stop];
        let b = self.ynu(0, S::cst(0.0), S::cst(1.0)).heights[stop];
        (b / a, S::cst(r_stop) / a.abs())
    }

    /// The paraxial chief ray of a unit field through the entrance-pupil centre at `z_ep`: slope
    /// 1 from an object at infinity, or from an object height of 1 mm.
    fn chief(&self, z_ep: S, object: Object) -> Ynu<S> {
        match object {
            Object::Infinite => self.ynu(0, S::cst(0.0) - z_ep, S::cst(1.0)),
            Object::Finite { distance_mm } => {
                let d = S::cst(distance_mm);
                let u = S::cst(-1.0) / (d + z_ep);
                self.ynu(0, S::cst(1.0) + u * d, u)
            }
        }
    }

    /// [`Paraxial::chief_image_height_mm`] for the stop at `stop`, from this prescription (at
    /// `wavelength_nm`, its entrance pupil at `z_ep`) when that is the primary wavelength, else
    /// from the primary wavelength's, its parameters passed through `lift` as this one's.
    fn primary_chief_image_height(
        &self,
        lens: &Lens,
        wavelength_nm: f64,
        z_ep: S,
        stop: usize,
        lift: &dyn Fn(Param, S) -> S,
    ) -> S {
        if wavelength_nm == lens.primary_wavelength_nm {
            return self.on_image(&self.chief(z_ep, lens.object));
        }
        let p = Prescription::lifted(lens, lens.primary_wavelength_nm, lift);
        let (_, parallel) = p.efl();
        // The pupil's position alone (its size does not enter).
        let (z, _) = p.pupil(&parallel, stop, 0.0);
        p.on_image(&p.chief(z, lens.object))
    }

    /// A ray's height on the image plane (the last gap past the last surface).
    fn on_image(&self, r: &Ynu<S>) -> S {
        r.y_last + r.u_last * self.gap[self.gap.len() - 1]
    }
}

/// A unit-height parallel ray leaving with a slope below this is leaving parallel: the lens is
/// afocal.
const AFOCAL_SLOPE: f64 = 1e-14;

/// True when the unit-height parallel ray `parallel` leaves the lens parallel to the axis.
fn is_afocal<S: Real>(parallel: &Ynu<S>) -> bool {
    parallel.u_last.value().abs() < AFOCAL_SLOPE
}

/// The first-order numbers a ray launch depends on, in any number type: where the rays of a
/// field are aimed (the paraxial entrance pupil) and the focal length that turns a fraction of
/// the field into an angle. [`launch_optics`] computes them with dual numbers so that a
/// gradient includes a design variable's effect on the launch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaunchOptics<S> {
    /// Effective focal length, mm (0 for an afocal lens, which has none: see `afocal`).
    pub efl_mm: S,
    /// True for an afocal lens: no fraction of the field is an angle.
    pub afocal: bool,
    /// Axial position of the entrance pupil, mm.
    pub entrance_pupil_z_mm: S,
    /// Entrance pupil radius, mm.
    pub entrance_pupil_radius_mm: S,
    /// The paraxial chief ray's image-plane height for a unit field
    /// ([`Paraxial::chief_image_height_mm`]).
    pub chief_image_height_mm: S,
}

impl LaunchOptics<f64> {
    /// The launch numbers of a paraxial analysis.
    pub fn of(p: &Paraxial) -> Self {
        LaunchOptics {
            efl_mm: p.efl_mm.unwrap_or(0.0),
            afocal: p.is_afocal(),
            entrance_pupil_z_mm: p.entrance_pupil_z_mm,
            entrance_pupil_radius_mm: 0.5 * p.entrance_pupil_diameter_mm,
            chief_image_height_mm: p.chief_image_height_mm,
        }
    }
}

impl<S: Real> LaunchOptics<S> {
    /// True when no number carries a derivative.
    pub fn is_constant(&self) -> bool {
        self.efl_mm.is_constant()
            && self.entrance_pupil_z_mm.is_constant()
            && self.entrance_pupil_radius_mm.is_constant()
            && self.chief_image_height_mm.is_constant()
    }
}

/// The [`LaunchOptics`] of `lens` at `wavelength_nm` with the aperture stop at surface `stop`
/// (a [`Paraxial::stop_surface`]: which surface limits the beam is a discrete choice, held),
/// each design parameter passed through `lift` as [`crate::lens::System::compile`] does. With
/// the identity lift the numbers are those of [`analyze`], bit for bit.
///
/// ```
/// use tolray::lens::paraxial::{launch_optics, LaunchOptics};
/// use tolray::lens::Param;
/// use tolray::real::Dual;
/// let lens = tolray::Lens::load("lens2").unwrap();
/// let p = lens.paraxial(lens.primary_wavelength_nm).unwrap();
/// let same: LaunchOptics<f64> =
///     launch_optics(&lens, p.wavelength_nm, p.stop_surface, &|_, v| v);
/// assert_eq!(same, LaunchOptics::of(&p));
/// // d EFL / d c0 by a dual number.
/// let lift = |q: Param, v: Dual<f64, 1>| if q == Param::Curvature(0) { Dual::var(v.re, 0) } else { v };
/// let d = launch_optics(&lens, p.wavelength_nm, p.stop_surface, &lift);
/// assert_eq!(Some(d.efl_mm.re), p.efl_mm);
/// assert!(d.efl_mm.eps[0] < 0.0); // a stronger front surface shortens the focal length
/// ```
pub fn launch_optics<S: Real>(
    lens: &Lens,
    wavelength_nm: f64,
    stop: usize,
    lift: &dyn Fn(Param, S) -> S,
) -> LaunchOptics<S> {
    let p = Prescription::lifted(lens, wavelength_nm, lift);
    let r_stop = lens.surfaces[stop].semi_aperture_mm;
    let (efl, parallel) = p.efl();
    let afocal = is_afocal(&parallel);
    let (z, r) = p.pupil(&parallel, stop, r_stop);
    LaunchOptics {
        efl_mm: if afocal { S::cst(0.0) } else { efl },
        afocal,
        entrance_pupil_z_mm: z,
        entrance_pupil_radius_mm: r,
        chief_image_height_mm: p.primary_chief_image_height(lens, wavelength_nm, z, stop, lift),
    }
}

/// Paraxial effective focal length of `lens` at `wavelength_nm` in any number type, each design
/// parameter passed through `lift` (the EFL target of training).
pub fn efl_lifted<S: Real>(lens: &Lens, wavelength_nm: f64, lift: &dyn Fn(Param, S) -> S) -> S {
    Prescription::lifted(lens, wavelength_nm, lift).efl().0
}

/// The paraxial exit pupil's axial position relative to the image plane, mm (its
/// [`Paraxial::exit_pupil_z_mm`] minus the image plane's z, up to rounding), of `lens` at
/// `wavelength_nm` with the aperture stop at surface `stop`, each design parameter passed through
/// `lift` as [`crate::lens::System::compile`] does; `None` when the exit pupil is at infinity
/// (telecentric in image space). The reference sphere of a differentiated wavefront moves with
/// it.
///
/// ```
/// use tolray::lens::paraxial::exit_pupil_from_image_lifted;
/// let lens = tolray::Lens::load("lens2").unwrap();
/// let p = lens.paraxial(lens.primary_wavelength_nm).unwrap();
/// let z_img = *lens.vertex_z_mm().last().unwrap();
/// let t: f64 = exit_pupil_from_image_lifted(&lens, p.wavelength_nm, p.stop_surface, &|_, v| v).unwrap();
/// assert!((t - (p.exit_pupil_z_mm - z_img)).abs() < 1e-9);
/// ```
pub fn exit_pupil_from_image_lifted<S: Real>(
    lens: &Lens,
    wavelength_nm: f64,
    stop: usize,
    lift: &dyn Fn(Param, S) -> S,
) -> Option<S> {
    let p = Prescription::lifted(lens, wavelength_nm, lift);
    let last = lens.surfaces.len() - 1;
    let to_image = p.gap[last];
    if stop >= last {
        return Some(-to_image);
    }
    // Rays leave the stop vertex (after any refraction there) and meet surface stop + 1.
    let (y, u) = match p.medium[stop] {
        Some(_) => p.across(stop, S::cst(0.0), S::cst(1.0)),
        None => (p.gap[stop], S::cst(1.0)),
    };
    let chief = p.ynu(stop + 1, y, u);
    if chief.u_last.value().abs() < 1e-14 {
        return None;
    }
    Some(-(chief.y_last / chief.u_last) - to_image)
}

/// Paraxial analysis of `lens` at `wavelength_nm`.
///
/// An afocal lens (a parallel beam leaves parallel: a beam expander, a telescope) has no focal
/// length: its [`Paraxial::efl_mm`], BFD and F-number are `None` and its
/// [`Paraxial::angular_magnification`] is given; pupils, magnification of a finite object
/// and the chief ray's image height are as for any lens.
///
/// ```
/// // A 2x Keplerian beam reducer of two ideal thin lenses, 100 mm and 50 mm, 150 mm apart.
/// let lens = tolray::lens::json::from_str(r#"{"surfaces": [
///     {"type": "ThinLens", "f": 100, "r": 10, "mat2": "air", "d_next": 150, "is_aperture": true},
///     {"type": "ThinLens", "f": 50, "r": 10, "mat2": "air", "d_next": 30}],
///   "r_sensor": 5}"#).unwrap();
/// let p = lens.paraxial(587.5618).unwrap();
/// assert!(p.is_afocal() && p.efl_mm.is_none() && p.fnum.is_none());
/// assert!((p.angular_magnification.unwrap() + 2.0).abs() < 1e-12);
/// ```
///
/// # Errors
/// [`crate::ErrorKind::Numerical`] if the stop's image is at infinity or a first-order quantity
/// is not finite; [`crate::ErrorKind::Invalid`] for a lens that does not validate or a medium
/// without a usable index at `wavelength_nm`.
pub fn analyze(lens: &Lens, wavelength_nm: f64) -> Result<Paraxial> {
    lens.validate()?;
    lens.check_indices(wavelength_nm)?;
    let p = Prescription::of(lens, wavelength_nm);
    let n_last = p.n.last().copied().unwrap_or(1.0);
    let last = lens.surfaces.len() - 1;
    let (efl, parallel) = p.efl();
    let afocal = is_afocal(&parallel);
    // Φ = -n' u' of the unit-height parallel ray (n' signed: -1 after an odd number of mirrors).
    let power = if afocal {
        0.0
    } else {
        -(n_last * parallel.u_last)
    };
    let (efl, bfd) = if afocal {
        (None, None)
    } else {
        (Some(efl), Some(-parallel.y_last / parallel.u_last))
    };
    let axial = match lens.object {
        Object::Infinite => None,
        Object::Finite { distance_mm } => Some(p.ynu(0, distance_mm, 1.0)),
    };
    // The image of the stated object: at infinity for an object at infinity seen through an
    // afocal lens; a finite object in the front focal plane has no finite image and no
    // magnification (an error, as before afocal lenses were answers).
    let image_distance = match &axial {
        None => bfd,
        Some(r) if r.u_last.abs() < AFOCAL_SLOPE => {
            return Err(Error::numerical(format!(
                "the paraxial image of the object is at infinity at {wavelength_nm} nm (the \
                 object is in the front focal plane): the lens has no finite first-order image"
            )))
        }
        Some(r) => Some(-r.y_last / r.u_last),
    };

    // The stop: the marked one, else the surface that limits the axial beam.
    let marginal = axial.as_ref().unwrap_or(&parallel);
    let stop = lens.stop_index().unwrap_or_else(|| {
        (0..lens.surfaces.len())
            .min_by(|&a, &b| {
                let ra = lens.surfaces[a].semi_aperture_mm / marginal.heights[a].abs();
                let rb = lens.surfaces[b].semi_aperture_mm / marginal.heights[b].abs();
                ra.total_cmp(&rb)
            })
            .unwrap_or(0)
    });
    let r_stop = lens.surfaces[stop].semi_aperture_mm;
    if parallel.heights[stop].abs() < 1e-14 {
        return Err(Error::numerical("the entrance pupil is at infinity"));
    }
    let (enp_z, enp_r) = p.pupil(&parallel, stop, r_stop);

    // Exit pupil: image of the stop through the surfaces after it.
    let z = lens.vertex_z_mm();
    let (xp_z, xp_r) = if stop == last {
        (z[last], r_stop)
    } else {
        // Rays leave the stop vertex (after any refraction there) and meet surface stop + 1.
        // (Through a gradient-index medium, by its transfer matrix.)
        let d = lens.surfaces[stop].d_next_mm;
        let from_stop = |y: f64, u: f64| match p.medium[stop] {
            Some(_) => p.across(stop, y, u),
            None => (y + u * d, u),
        };
        let (y, u) = from_stop(0.0, 1.0);
        let chief = p.ynu(stop + 1, y, u);
        let (y, u) = from_stop(r_stop, 0.0);
        let edge = p.ynu(stop + 1, y, u);
        if chief.u_last.abs() < 1e-14 {
            (f64::INFINITY, f64::INFINITY)
        } else {
            let zx = -chief.y_last / chief.u_last;
            (z[last] + zx, (edge.y_last + edge.u_last * zx).abs())
        }
    };

    let (working_fnum, magnification) = match lens.object {
        Object::Infinite => (efl.map(|f| f / (2.0 * enp_r)), 0.0),
        // (An object on the first vertex's plane meets this with the stop on the first surface.)
        Object::Finite { distance_mm } if enp_z + distance_mm == 0.0 => {
            return Err(Error::numerical(format!(
                "the paraxial entrance pupil lies on the object plane ({distance_mm} mm in front \
                 of the first vertex) at {wavelength_nm} nm: no cone of rays from an object point \
                 fills it"
            )))
        }
        Object::Finite { distance_mm } => {
            let u0 = enp_r / (enp_z + distance_mm);
            let r = p.ynu(0, u0 * distance_mm, u0);
            (
                Some(1.0 / (2.0 * r.u_last.abs())),
                p.n_object * u0 / (n_last * r.u_last),
            )
        }
    };
    // A unit-slope ray through the entrance pupil's centre leaves an afocal lens with the slope
    // of the angular magnification (its height there does not matter: every ray of a field
    // leaves parallel).
    // (Signed indices: after an odd number of mirrors the slope's sign is flipped back, so a
    // flat mirror's is +1.)
    let angular_magnification =
        afocal.then(|| p.chief(enp_z, Object::Infinite).u_last * n_last.signum());
    // An exit pupil at infinity (telecentric in image space) is an answer; NaN is not.
    if xp_z.is_nan() || xp_r.is_nan() {
        return Err(Error::numerical(format!(
            "paraxial exit pupil is NaN at {wavelength_nm} nm: the lens has no finite first-order image"
        )));
    }
    for (what, v) in [
        ("effective focal length", efl),
        ("back focal distance", bfd),
        ("image distance", image_distance),
        ("entrance pupil position", Some(enp_z)),
        ("entrance pupil diameter", Some(enp_r)),
        ("working F-number", working_fnum),
        ("magnification", Some(magnification)),
        ("angular magnification", angular_magnification),
    ] {
        if let Some(v) = v.filter(|v| !v.is_finite()) {
            return Err(Error::numerical(format!(
                "paraxial {what} is {v} at {wavelength_nm} nm: the lens has no finite first-order image"
            )));
        }
    }
    Ok(Paraxial {
        wavelength_nm,
        power_per_mm: power,
        efl_mm: efl,
        efl_image_space_mm: efl.map(|f| n_last * f),
        bfd_mm: bfd,
        image_distance_mm: image_distance,
        entrance_pupil_z_mm: enp_z,
        entrance_pupil_diameter_mm: 2.0 * enp_r,
        exit_pupil_z_mm: xp_z,
        exit_pupil_diameter_mm: 2.0 * xp_r,
        fnum: efl.map(|f| f / (2.0 * enp_r)),
        working_fnum,
        magnification,
        angular_magnification,
        half_fov_deg: efl.map(|f| (lens.sensor.half_diagonal_mm() / f).atan().to_degrees()),
        stop_surface: stop,
        total_track_mm: z[last + 1],
        chief_image_height_mm: p.primary_chief_image_height(
            lens,
            wavelength_nm,
            enp_z,
            stop,
            &|_, v| v,
        ),
    })
}

/// The field of a paraxial chief ray, for [`beam_semi_diameters`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParaxialField {
    /// Field angle in object space, degrees.
    AngleDeg(f64),
    /// Object height, mm (finite objects).
    ObjectHeightMm(f64),
    /// Paraxial image height, mm.
    ImageHeightMm(f64),
}

/// Paraxial beam size at every surface and at the image plane (the last entry): the marginal
/// ray's height plus the chief ray's of `field`, in mm, as OpticStudio sizes surfaces whose
/// semi-diameter is not given. The stop's semi-diameter sets the marginal ray.
///
/// ```
/// use tolray::lens::paraxial::{beam_semi_diameters, ParaxialField};
/// let lens = tolray::Lens::load("cooke-triplet").unwrap();
/// let r = beam_semi_diameters(&lens, 587.5618, ParaxialField::AngleDeg(20.0)).unwrap();
/// let stop = lens.stop_index().unwrap();
/// assert!(r[stop] > lens.surfaces[stop].semi_aperture_mm);
/// assert_eq!(r.len(), lens.surfaces.len() + 1);
/// ```
///
/// # Errors
/// As [`analyze`].
pub fn beam_semi_diameters(
    lens: &Lens,
    wavelength_nm: f64,
    field: ParaxialField,
) -> Result<Vec<f64>> {
    let p = analyze(lens, wavelength_nm)?;
    let pres = Prescription::of(lens, wavelength_nm);
    let image_gap = lens.image_distance_mm();
    let with_image = |r: Ynu<f64>| {
        let mut h = r.heights;
        h.push(r.y_last + r.u_last * image_gap);
        h
    };
    let r_ep = p.entrance_pupil_diameter_mm / 2.0;
    let z_ep = p.entrance_pupil_z_mm;
    let marginal = with_image(match lens.object {
        Object::Infinite => pres.ynu(0, r_ep, 0.0),
        Object::Finite { distance_mm } => {
            let u = r_ep / (distance_mm + z_ep);
            pres.ynu(0, u * distance_mm, u)
        }
    });
    let chief = with_image(pres.chief(z_ep, lens.object));
    let unit_image = *chief.last().unwrap_or(&0.0);
    let scale = match (field, lens.object) {
        (ParaxialField::AngleDeg(a), Object::Infinite) => a.to_radians().tan(),
        (ParaxialField::AngleDeg(a), Object::Finite { distance_mm }) => {
            a.to_radians().tan() * (distance_mm + z_ep)
        }
        (ParaxialField::ObjectHeightMm(h), Object::Finite { .. }) => h,
        (ParaxialField::ObjectHeightMm(_), Object::Infinite) => {
            return Err(Error::invalid(
                "an object-height field needs an object at a finite distance",
            ))
        }
        (ParaxialField::ImageHeightMm(h), _) => {
            if unit_image.abs() < 1e-300 {
                return Err(Error::numerical("the chief ray does not reach the image"));
            }
            h / unit_image
        }
    };
    let out: Vec<f64> = marginal
        .iter()
        .zip(&chief)
        .map(|(m, c)| m.abs() + (c * scale).abs())
        .collect();
    if out.iter().all(|v| v.is_finite()) {
        Ok(out)
    } else {
        Err(Error::numerical("paraxial beam sizes are not finite"))
    }
}
