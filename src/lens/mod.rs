//! Lens prescriptions: the editable [`Lens`], its files, and the compiled [`System`] the tracer runs.
//!
//! A [`Lens`] is a sequence of surfaces in the DeepLens sense: each surface owns the medium that
//! follows it (`material`) and the gap to the next surface (`d_next_mm`); the last gap reaches the
//! image plane. Surfaces are counted from 0. Compiling a lens ([`Lens::compile`]) yields an
//! immutable flat table in one number type, with every surface's rigid placement resolved.
//!
//! Files: DeepLens JSON ([`json`]) and Zemax OpticStudio .zmx ([`zemax`]); glass catalogs are
//! built in ([`material::catalog`]) or read from Zemax AGF files ([`agf`]).

pub mod agf;
mod builtin;
mod catalog_data;
pub mod field;
pub mod json;
pub mod material;
pub mod paraxial;
pub mod qbfs;
pub mod qcon;
mod system;
mod text;
pub mod zemax;

pub use builtin::{builtin, builtin_names};
pub use field::{Field, FieldPoint, Vignetting};
pub use material::{GlassCatalogs, Material};
pub use paraxial::Paraxial;
pub use system::{Adjustments, Clip, Param, SurfaceKind, SurfaceRow, System};

use crate::error::{Error, Result};
use crate::math::{Mat3, Vec3};
use std::path::Path;

/// Number of even-asphere coefficients stored per surface: a2, a4, ..., a16.
pub const N_ASPH: usize = 8;

/// What a surface does to light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceRole {
    /// A refracting interface between two media.
    Refractive,
    /// A flat aperture (DeepLens "Aperture"/"Stop"): it clips rays but does not refract.
    Aperture,
    /// A mirror: rays reflect and travel back along the axis, so the gaps after it are negative
    /// (as OpticStudio writes them) until the next mirror; its `material` is the medium the
    /// reflected light travels in (the one before it).
    Mirror,
}

/// The shape of a hard aperture, in the surface's own frame (sizes in mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ApertureShape {
    /// A circle of the surface's semi-diameter ([`Surface::semi_aperture_mm`]): the meaning of
    /// DeepLens' `r`, which clips; it follows the semi-diameter when that changes.
    SemiDiameter,
    /// An annulus from `min_mm` to `max_mm` (OpticStudio `CLAP`, or `OBSC` for an obscuration).
    Circular {
        /// Inner radius, mm (0 for a disk).
        min_mm: f64,
        /// Outer radius, mm.
        max_mm: f64,
    },
    /// A rectangle of half-widths `half_x_mm` × `half_y_mm` (OpticStudio `SQAP` / `OBSQ`).
    Rectangular {
        /// Half-width along x, mm.
        half_x_mm: f64,
        /// Half-width along y, mm.
        half_y_mm: f64,
    },
    /// An ellipse of semi-axes `half_x_mm` × `half_y_mm` (OpticStudio `ELAP` / `OBEL`).
    Elliptical {
        /// Semi-axis along x, mm.
        half_x_mm: f64,
        /// Semi-axis along y, mm.
        half_y_mm: f64,
    },
}

/// A hard aperture: rays outside it (or, for an obscuration, inside it) are stopped. Unlike the
/// semi-diameter, which is the surface's drawn size and clips only through
/// [`ApertureShape::SemiDiameter`], a hard aperture always clips when tracing with apertures.
///
/// ```
/// use tolray::lens::{Aperture, ApertureShape};
/// let clap = Aperture::circular(0.0, 5.0);
/// assert!(!clap.stops(3.0, 3.0, 10.0) && clap.stops(4.0, 4.0, 10.0));
/// let mut obsc = Aperture::circular(0.0, 1.0);
/// obsc.obscuration = true;
/// assert!(obsc.stops(0.5, 0.0, 10.0) && !obsc.stops(2.0, 0.0, 10.0));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aperture {
    /// Shape and size.
    pub shape: ApertureShape,
    /// Centre of the shape in the surface frame, mm (OpticStudio `OBDC`).
    pub decenter_mm: [f64; 2],
    /// True for an obscuration: the shape blocks light instead of passing it.
    pub obscuration: bool,
}

impl Aperture {
    /// A circle of the surface's semi-diameter (DeepLens' clipping `r`).
    pub const SEMI_DIAMETER: Aperture = Aperture {
        shape: ApertureShape::SemiDiameter,
        decenter_mm: [0.0, 0.0],
        obscuration: false,
    };
    /// A centred annulus (a disk when `min_mm` is 0) that passes light.
    pub fn circular(min_mm: f64, max_mm: f64) -> Aperture {
        Aperture {
            shape: ApertureShape::Circular { min_mm, max_mm },
            decenter_mm: [0.0, 0.0],
            obscuration: false,
        }
    }
    /// True when a ray crossing the surface at local `(x, y)` mm is stopped, for a surface of
    /// semi-diameter `semi_mm`.
    pub fn stops(&self, x: f64, y: f64, semi_mm: f64) -> bool {
        let (x, y) = (x - self.decenter_mm[0], y - self.decenter_mm[1]);
        let inside = match self.shape {
            ApertureShape::SemiDiameter => x * x + y * y <= semi_mm * semi_mm,
            ApertureShape::Circular { min_mm, max_mm } => {
                let r2 = x * x + y * y;
                r2 <= max_mm * max_mm && r2 >= min_mm * min_mm
            }
            ApertureShape::Rectangular {
                half_x_mm,
                half_y_mm,
            } => x.abs() <= half_x_mm && y.abs() <= half_y_mm,
            ApertureShape::Elliptical {
                half_x_mm,
                half_y_mm,
            } => (x / half_x_mm).powi(2) + (y / half_y_mm).powi(2) <= 1.0,
        };
        inside == self.obscuration
    }
    /// The largest distance from the surface vertex at which a ray can pass, mm (infinite for an
    /// obscuration).
    pub fn reach_mm(&self, semi_mm: f64) -> f64 {
        if self.obscuration {
            return f64::INFINITY;
        }
        let d = self.decenter_mm[0].hypot(self.decenter_mm[1]);
        d + match self.shape {
            ApertureShape::SemiDiameter => semi_mm,
            ApertureShape::Circular { max_mm, .. } => max_mm,
            ApertureShape::Rectangular {
                half_x_mm,
                half_y_mm,
            } => half_x_mm.hypot(half_y_mm),
            ApertureShape::Elliptical {
                half_x_mm,
                half_y_mm,
            } => half_x_mm.max(half_y_mm),
        }
    }
    /// Checks sizes: finite, positive, an annulus' inner radius below its outer one.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] saying which size is wrong.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid(format!("hard aperture: {m}")));
        if !self
            .decenter_mm
            .iter()
            .all(|v| v.is_finite() && v.abs() <= 1e6)
        {
            return bad(format!("decenter {:?} mm is not finite", self.decenter_mm));
        }
        let pos = |v: f64| v > 0.0 && v <= 1e6;
        match self.shape {
            ApertureShape::SemiDiameter => Ok(()),
            ApertureShape::Circular { min_mm, max_mm } => {
                if !(pos(max_mm) && min_mm >= 0.0 && min_mm < max_mm) {
                    bad(format!(
                        "annulus {min_mm} to {max_mm} mm: need 0 <= inner < outer <= 1e6"
                    ))
                } else {
                    Ok(())
                }
            }
            ApertureShape::Rectangular {
                half_x_mm,
                half_y_mm,
            }
            | ApertureShape::Elliptical {
                half_x_mm,
                half_y_mm,
            } => {
                if !(pos(half_x_mm) && pos(half_y_mm)) {
                    bad(format!(
                        "half-widths {half_x_mm} x {half_y_mm} mm must be positive (at most 1e6)"
                    ))
                } else {
                    Ok(())
                }
            }
        }
    }
}

/// The form of a surface's sag beyond its base conic (`c`, `k`), and what [`Surface::asph`]
/// holds.
///
/// ```
/// use tolray::lens::{Shape, Surface, Material};
/// // A cylinder lens face: radius 2.02 mm in y, flat in x (OpticStudio TOROIDAL, PARM 1 = 0).
/// let mut s = Surface::sphere(1.0 / 2.02, 2.0, 3.8, Material::Air);
/// s.shape = Shape::Toroidal { c_rot: 0.0 };
/// assert_eq!(s.sag_xy(1.5, 0.0), Some(0.0));
/// assert!(s.sag_xy(0.0, 1.5).unwrap() > 0.6);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Shape {
    /// Rotationally symmetric even asphere: `asph` = a2, a4, ..., a16 on ρ², ρ⁴, ..., ρ¹⁶
    /// (OpticStudio STANDARD and EVENASPH, DeepLens "Aspheric").
    #[default]
    Even,
    /// Rotationally symmetric odd asphere: `asph` = β1, ..., β8 on ρ¹, ρ², ..., ρ⁸ (OpticStudio
    /// ODDASPHE). β1 makes a cone point at the vertex, where the normal is taken as the axis.
    Odd,
    /// A toroid (OpticStudio TOROIDAL): the profile in the y-z plane (`c`, `k`, and `asph` on
    /// y², y⁴, ..., y¹⁶) rotated about an axis parallel to y through the point z = 1/`c_rot`
    /// on the axis. `c_rot = 0` sweeps the profile straight along x: a cylinder.
    Toroidal {
        /// Curvature of the rotation, 1/mm (1 / OpticStudio's radius of rotation; 0 = none).
        c_rot: f64,
    },
    /// A flat ideal thin lens (OpticStudio PARAXIAL, DeepLens "ThinLens") between equal media:
    /// each ray's slopes change by minus its height over the focal length, so every ray of
    /// one direction meets the focal plane at one point (perfect imaging). `c`, `k` and `asph`
    /// are 0.
    Paraxial {
        /// Focal length, mm (negative for a diverging lens).
        focal_mm: f64,
    },
    /// Forbes' slope-orthogonal Q polynomials on the base conic (OpticStudio's Q-type asphere
    /// of type 0, `QED_TYPE`): `asph` = a_0..a_7 (mm), the coefficients of Q_0^bfs..Q_7^bfs in
    /// a departure along the base conic's normal, `φ(ρ) x (1 - x) Σ a_m Q_m(x)` with
    /// `x = (ρ / norm_radius_mm)²`; the formula and its checks are in [`qbfs`]. The departure
    /// vanishes at the vertex and at the normalization radius; beyond that radius the same
    /// formula continues.
    Qbfs {
        /// Normalization radius ρ_n, mm (positive).
        norm_radius_mm: f64,
    },
    /// Forbes' Q^con polynomials on the base conic (OpticStudio's Q-type asphere of type 1):
    /// `asph` = a_0..a_7 (mm), the coefficients of Q_0^con..Q_7^con in an axial departure
    /// `x² Σ a_m Q_m(x)`, `x = (ρ / norm_radius_mm)²`, which starts at ρ⁴ (the paraxial
    /// curvature is `c`); the formula and its checks are in [`qcon`].
    Qcon {
        /// Normalization radius ρ_n, mm (positive).
        norm_radius_mm: f64,
    },
}

impl Shape {
    /// The coefficient on ρ² (y² for a toroid) that each of [`Surface::asph`] contributes to
    /// the sag's Taylor series at the vertex: the paraxial curvature is
    /// `c + 2 Σ_j w_j asph_j`.
    ///
    /// ```
    /// use tolray::lens::Shape;
    /// assert_eq!(Shape::Even.r2_weights()[0], 1.0);
    /// assert_eq!(Shape::Odd.r2_weights()[1], 1.0);
    /// // Qbfs: Q_m(0) / ρ_n² (Q_0 = 1).
    /// assert_eq!(Shape::Qbfs { norm_radius_mm: 2.0 }.r2_weights()[0], 0.25);
    /// ```
    pub fn r2_weights(self) -> [f64; N_ASPH] {
        let mut w = [0.0; N_ASPH];
        match self {
            Shape::Even | Shape::Toroidal { .. } => w[0] = 1.0,
            Shape::Odd => w[1] = 1.0,
            Shape::Paraxial { .. } => {}
            Shape::Qbfs { norm_radius_mm } => {
                let r2 = norm_radius_mm * norm_radius_mm;
                w = qbfs::polynomials(0.0).map(|q| q / r2);
            }
            Shape::Qcon { .. } => {}
        }
        w
    }
    /// The normalization radius (mm) of a Q-type asphere ([`Shape::Qbfs`], [`Shape::Qcon`]).
    ///
    /// ```
    /// use tolray::lens::Shape;
    /// assert_eq!(Shape::Qcon { norm_radius_mm: 3.0 }.norm_radius_mm(), Some(3.0));
    /// assert_eq!(Shape::Even.norm_radius_mm(), None);
    /// ```
    pub fn norm_radius_mm(self) -> Option<f64> {
        match self {
            Shape::Qbfs { norm_radius_mm } | Shape::Qcon { norm_radius_mm } => Some(norm_radius_mm),
            _ => None,
        }
    }
    /// The paraxial (vertex) curvature of a surface of this shape with curvature `c` and
    /// coefficients `asph`, 1/mm: `c + 2 Σ_j w_j asph_j` ([`Shape::r2_weights`]).
    ///
    /// ```
    /// use tolray::lens::Shape;
    /// let mut a = [0.0; 8];
    /// a[0] = 1e-3; // 1e-3 ρ² on an even asphere adds 2e-3 /mm
    /// assert!((Shape::Even.paraxial_curvature(0.01, &a) - 0.012).abs() < 1e-15);
    /// ```
    pub fn paraxial_curvature(self, c: f64, asph: &[f64; N_ASPH]) -> f64 {
        c + 2.0
            * self
                .r2_weights()
                .iter()
                .zip(asph)
                .map(|(w, a)| w * a)
                .sum::<f64>()
    }
    /// True for shapes without rotational symmetry about the surface's axis.
    pub fn is_rotational(self) -> bool {
        !matches!(self, Shape::Toroidal { .. })
    }
}

/// One surface of a prescription.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    /// Refracting surface or bare aperture.
    pub role: SurfaceRole,
    /// Vertex curvature, 1/mm (0 = flat). Optimize curvature, not radius.
    pub c: f64,
    /// Conic constant (0 = sphere, -1 = paraboloid).
    pub k: f64,
    /// Polynomial coefficients of the sag; their powers depend on [`Surface::shape`] (even
    /// asphere: a2, a4, ..., a16 on ρ², ..., ρ¹⁶, in mm^{1-2i}).
    pub asph: [f64; N_ASPH],
    /// The sag's form: even asphere (the default), odd asphere or toroid.
    pub shape: Shape,
    /// Semi-diameter, mm: the surface's size (drawings, edge thickness, the clear size). It clips
    /// rays only through an [`ApertureShape::SemiDiameter`] aperture (as DeepLens' `r` does) or
    /// on the stop.
    pub semi_aperture_mm: f64,
    /// Hard aperture: `None` when the surface does not clip (an OpticStudio surface with only a
    /// semi-diameter); the stop clips at its semi-diameter unless it has a hard aperture.
    pub aperture: Option<Aperture>,
    /// Axial gap from this vertex to the next (the last: to the image plane), mm.
    pub d_next_mm: f64,
    /// Medium after this surface.
    pub material: Material,
    /// True if this surface is the aperture stop.
    pub is_stop: bool,
    /// Lateral vertex offset (DeepLens `pos_xy`), mm.
    pub pos_xy_mm: [f64; 2],
    /// Unit surface normal at the vertex (DeepLens `vec_local`), nominally (0, 0, 1).
    pub vec_local: [f64; 3],
    /// Rotation of the surface about its own axis, degrees (right-handed about the axis), applied
    /// before the axis is turned to [`Surface::vec_local`] by the shortest arc. It matters only for
    /// what is not rotationally symmetric: a toroid, a grating's grooves, a rectangular,
    /// elliptical or decentred aperture. A .zmx coordinate break that rolls the frame sets it.
    pub roll_deg: f64,
    /// A diffraction grating ruled on the surface (OpticStudio `DGRATING`), or `None`.
    pub grating: Option<Grating>,
    /// On a fold mirror: how the axis turns here for every surface after this one (and the
    /// image), or `None` for a straight axis.
    pub fold: Option<Fold>,
}

/// The turn of the optical axis at a fold mirror.
///
/// A lens is described *unfolded*: every vertex lies at its axial position (the sum of the gaps
/// before it) plus its [`Surface::pos_xy_mm`], as if the axis were straight, and the paraxial
/// model, tolerances and gaps all work in these coordinates. A fold on surface `m` places
/// everything after `m` in a frame turned by [`Fold::rotation`] about the point of the axis
/// [`Fold::pivot_mm`] beyond `m`'s axial position (a decentred mirror's vertex lies off that
/// axis): the mechanical frame of a fold mirror's downstream
/// optics (OpticStudio's coordinate break after a fold mirror). After a 45° mirror the fold turns
/// the axis by 90° and the light goes on along the new axis' −z, the unfolded system's direction
/// after a mirror (negative gaps, as in OpticStudio).
///
/// ```
/// use tolray::lens::Fold;
/// // A 45 degree fold mirror about x sends the axis from +z to -y (tilts as a .zmx coordinate
/// // break: about x, the new y, the new z).
/// let f = Fold { tilt_deg: [90.0, 0.0, 0.0], pivot_mm: 0.0 };
/// let r = f.rotation();
/// assert_eq!((r.rows[0].z, r.rows[1].z, r.rows[2].z), (0.0, -1.0, 0.0));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fold {
    /// The turn as tilts about x, then the new y, then the new z, degrees (a .zmx coordinate
    /// break with order flag 0).
    pub tilt_deg: [f64; 3],
    /// Where the axis turns, mm along the axis from the surface's vertex (0: at the vertex). A
    /// fold mirror moved along the axis keeps its downstream optics in place through it.
    pub pivot_mm: f64,
}

impl Fold {
    /// The turn as a rotation matrix (local-to-global axes of the downstream frame in the
    /// upstream one), with entries within 1e-15 of 0 or ±1 made exact, so a 90° fold is exact.
    pub fn rotation(&self) -> crate::math::Mat3<f64> {
        system::clean_rotation(system::rotation_xyz_deg(self.tilt_deg))
    }
}

/// A ruled diffraction grating on a surface: grooves parallel to the surface's local x axis,
/// equally spaced in y as projected on the local x-y plane (OpticStudio's Diffraction Grating
/// surface). A ray leaves in the given order by the grating equation on the tangential
/// components, `n' t' = n t + m λ T ŷ_t`, where `ŷ_t` is the local y axis projected on the
/// surface's tangent plane at the hit (so a flat grating obeys n' sin θ' = n sin θ + m λ T in the
/// y-z plane); the optical path gains `m λ T y`. An order that cannot propagate stops the ray
/// with [`crate::trace::RayStatus::Tir`].
///
/// ```
/// use tolray::lens::Grating;
/// // 600 lines/mm, first order: at 500 nm, m λ T = 0.3 (the sine of the angle at normal incidence).
/// let g = Grating { lines_per_um: 0.6, order: 1.0 };
/// assert!((g.deflection(500.0) - 0.3).abs() < 1e-15);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grating {
    /// Groove density T, lines per µm (OpticStudio's PARM 1).
    pub lines_per_um: f64,
    /// Diffraction order m (OpticStudio's PARM 2); its sign follows OpticStudio's.
    pub order: f64,
}

impl Grating {
    /// `m λ T` at `wavelength_nm`: the change of n sin θ in the local y-z plane.
    pub fn deflection(&self, wavelength_nm: f64) -> f64 {
        self.order * self.lines_per_um * wavelength_nm * 1e-3
    }
}

impl Surface {
    /// A spherical (or flat, `c = 0`) refracting surface that clips at its semi-diameter.
    pub fn sphere(c: f64, semi_aperture_mm: f64, d_next_mm: f64, material: Material) -> Self {
        Surface {
            role: SurfaceRole::Refractive,
            c,
            k: 0.0,
            asph: [0.0; N_ASPH],
            shape: Shape::Even,
            semi_aperture_mm,
            aperture: Some(Aperture::SEMI_DIAMETER),
            d_next_mm,
            material,
            is_stop: false,
            pos_xy_mm: [0.0; 2],
            vec_local: [0.0, 0.0, 1.0],
            roll_deg: 0.0,
            grating: None,
            fold: None,
        }
    }
    /// A flat aperture stop in air.
    pub fn stop(semi_aperture_mm: f64, d_next_mm: f64) -> Self {
        Surface {
            role: SurfaceRole::Aperture,
            is_stop: true,
            ..Surface::sphere(0.0, semi_aperture_mm, d_next_mm, Material::Air)
        }
    }
    /// The aperture that clips rays here: the hard aperture, else the semi-diameter on the stop,
    /// else none.
    pub fn clipping_aperture(&self) -> Option<Aperture> {
        self.aperture
            .or(self.is_stop.then_some(Aperture::SEMI_DIAMETER))
    }
    /// True if nothing about the surface changes when it turns about its own axis: a rotationally
    /// symmetric shape without a grating, clipped (if at all) by a centred circle. Then
    /// [`Surface::roll_deg`] does not matter.
    pub fn is_axially_symmetric(&self) -> bool {
        let round = match self.aperture {
            None => true,
            Some(a) => {
                a.decenter_mm == [0.0; 2]
                    && matches!(
                        a.shape,
                        ApertureShape::SemiDiameter | ApertureShape::Circular { .. }
                    )
            }
        };
        self.shape.is_rotational() && self.grating.is_none() && round
    }
    /// True if the surface is not a plain conic: an asphere coefficient is non-zero or the
    /// shape is not the even asphere.
    pub fn is_aspheric(&self) -> bool {
        self.shape != Shape::Even || self.asph.iter().any(|&a| a != 0.0)
    }
    /// Sag at radial distance `rho` mm in the meridional (y-z) section, or `None` beyond the
    /// conic's rim. For rotationally symmetric shapes this is the sag at every azimuth.
    pub fn sag(&self, rho: f64) -> Option<f64> {
        self.sag_xy(0.0, rho)
    }
    /// Sag z(x, y), mm, or `None` where the surface is undefined (beyond the conic's rim, or
    /// beyond a toroid's rotation).
    pub fn sag_xy(&self, x: f64, y: f64) -> Option<f64> {
        let conic = |u: f64| {
            let arg = 1.0 - (1.0 + self.k) * self.c * self.c * u;
            (arg >= 0.0).then(|| self.c * u / (1.0 + arg.sqrt()))
        };
        let even = |u: f64| {
            let mut z = conic(u)?;
            let mut p = u;
            for a in self.asph {
                z += a * p;
                p *= u;
            }
            Some(z)
        };
        match self.shape {
            Shape::Even => even(x * x + y * y),
            Shape::Odd => {
                let u = x * x + y * y;
                let r = u.sqrt();
                let mut z = conic(u)?;
                let mut p = r;
                for a in self.asph {
                    z += a * p;
                    p *= r;
                }
                Some(z)
            }
            Shape::Paraxial { .. } => Some(0.0),
            Shape::Qbfs { norm_radius_mm } => {
                qbfs::sag(self.c, self.k, &self.asph, norm_radius_mm, x * x + y * y)
            }
            Shape::Qcon { norm_radius_mm } => {
                qcon::sag(self.c, self.k, &self.asph, norm_radius_mm, x * x + y * y)
            }
            Shape::Toroidal { c_rot } => {
                let zy = even(y * y)?;
                let g = c_rot / (1.0 - c_rot * zy);
                let q = 1.0 - g * g * x * x;
                (g.is_finite() && q >= 0.0).then(|| zy + g * x * x / (1.0 + q.sqrt()))
            }
        }
    }
}

/// Where the object is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Object {
    /// At infinity: every field is a bundle of parallel rays.
    Infinite,
    /// At a finite distance in front of the first vertex (the object plane is `z = -distance_mm`).
    Finite {
        /// Distance from the object plane to the first vertex, mm: positive for a real object;
        /// negative for a virtual object behind the first vertex, on which the entering beam
        /// converges (OpticStudio's negative object thickness).
        distance_mm: f64,
    },
}

impl Object {
    /// Parses `inf` / `infinity`, a distance in mm to a real object in front of the first
    /// vertex (its magnitude: DeepLens' negative `obj_depth` is accepted), or `virtual:MM`, a
    /// virtual object MM behind the first vertex (a beam converging on it).
    ///
    /// ```
    /// use tolray::Object;
    /// assert_eq!(Object::parse("-1000").unwrap(), Object::Finite { distance_mm: 1000.0 });
    /// assert_eq!(Object::parse("virtual:50").unwrap(), Object::Finite { distance_mm: -50.0 });
    /// assert_eq!(Object::parse("inf").unwrap(), Object::Infinite);
    /// assert!(Object::parse("virtual:inf").is_err());
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for anything else, a zero distance, or a virtual object
    /// that is not a finite positive distance.
    pub fn parse(s: &str) -> Result<Object> {
        let t = s.trim().to_ascii_lowercase();
        if matches!(t.as_str(), "inf" | "infinity" | "-inf") {
            return Ok(Object::Infinite);
        }
        if let Some(v) = t.strip_prefix("virtual:") {
            return match v.trim().parse::<f64>() {
                Ok(v) if v.is_finite() && v > 0.0 => Ok(Object::Finite { distance_mm: -v }),
                _ => Err(Error::argument(format!(
                    "object distance \"{s}\": a virtual object needs a distance in mm behind the first vertex, greater than 0 (e.g. virtual:50)"
                ))),
            };
        }
        match t.parse::<f64>() {
            Ok(v) if v.is_infinite() => Ok(Object::Infinite),
            Ok(v) if v.is_finite() && v != 0.0 => Ok(Object::Finite {
                distance_mm: v.abs(),
            }),
            _ => Err(Error::argument(format!(
                "object distance \"{s}\": give a distance in mm (e.g. 1000), \"inf\", or virtual:MM for a virtual object MM behind the first vertex"
            ))),
        }
    }
}

/// The image sensor: a rectangle of square pixels whose aspect ratio follows the resolution,
/// sized by its half-diagonal (DeepLens' `r_sensor`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sensor {
    /// Half-diagonal (image-circle radius), mm.
    pub r_mm: f64,
    /// Pixel columns and rows.
    pub resolution: [u32; 2],
}

impl Sensor {
    /// A sensor with half-diagonal `r_mm` and `resolution` pixels.
    pub fn from_half_diagonal(r_mm: f64, resolution: [u32; 2]) -> Sensor {
        Sensor { r_mm, resolution }
    }
    /// Half-diagonal (image-circle radius), mm.
    pub fn half_diagonal_mm(&self) -> f64 {
        self.r_mm
    }
    /// Width and height, mm.
    pub fn size_mm(&self) -> [f64; 2] {
        let (w, h) = (self.resolution[0] as f64, self.resolution[1] as f64);
        let diag = w.hypot(h);
        [2.0 * self.r_mm * w / diag, 2.0 * self.r_mm * h / diag]
    }
    /// Pixel pitch, mm.
    pub fn pixel_pitch_mm(&self) -> f64 {
        self.size_mm()[0] / self.resolution[0] as f64
    }
}

/// An editable lens prescription.
#[derive(Clone, Debug, PartialEq)]
pub struct Lens {
    /// Free-text description.
    pub info: String,
    /// Surfaces, counted from 0.
    pub surfaces: Vec<Surface>,
    /// Object position.
    pub object: Object,
    /// Image sensor (placed `surfaces.last().d_next_mm` behind the last vertex; a gap against
    /// the travel puts it in front: a virtual image, to which rays are extended backwards).
    pub sensor: Sensor,
    /// Primary (design) wavelength, nm.
    pub primary_wavelength_nm: f64,
    /// Red, green and blue wavelengths, nm.
    pub rgb_wavelengths_nm: [f64; 3],
    /// Aim rays at the real stop by default (OpticStudio's ray aiming, `RAIM`; JSON
    /// `"ray_aiming": true`) instead of at the paraxial entrance pupil. The CLI's `--aim` and
    /// `--no-aim` override it.
    pub ray_aiming: bool,
    /// The medium in front of the first surface (object space): air unless the lens file names
    /// another (a .zmx `GLAS` on `SURF 0`; JSON `"object_medium"`), as for immersion optics.
    pub object_medium: Material,
    /// The field points the lens file defines, with their vignetting factors (a .zmx file's
    /// fields; JSON `"fields"`): the CLI's default fields when `--fields` is not given. Rays of
    /// a field equal to one of them fill its vignetted pupil ([`Lens::vignetting_of`]). Empty
    /// for the built-in lenses.
    pub fields: Vec<FieldPoint>,
    /// Where the image plane sits and how it is turned (a .zmx coordinate break before the image
    /// surface; JSON `"image_plane"`): centred on the axis and perpendicular to it by default.
    pub image_plane: ImagePlane,
}

/// The image plane's pose: decentred from the axis, tilted, rolled. Ray positions and directions
/// at the image are reported in the plane's own frame (x, y on the plane; its centre at the
/// axial image position), as OpticStudio reports them on a tilted image surface; for the
/// default pose that frame is the global one.
///
/// ```
/// use tolray::lens::ImagePlane;
/// // A sensor tilted 3 degrees about x (a Scheimpflug tilt).
/// let t = 3f64.to_radians();
/// let p = ImagePlane { normal: [0.0, -t.sin(), t.cos()], ..ImagePlane::default() };
/// assert!(!p.is_default());
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImagePlane {
    /// Offset of the plane's centre from the axis, mm.
    pub decenter_mm: [f64; 2],
    /// The plane's normal (its local z axis), with a positive z component.
    pub normal: [f64; 3],
    /// Turn of the plane's x and y axes about its normal, degrees (as [`Surface::roll_deg`]).
    pub roll_deg: f64,
}

impl Default for ImagePlane {
    fn default() -> Self {
        ImagePlane {
            decenter_mm: [0.0; 2],
            normal: [0.0, 0.0, 1.0],
            roll_deg: 0.0,
        }
    }
}

impl ImagePlane {
    /// True for the plane centred on the axis and perpendicular to it, unrolled.
    pub fn is_default(&self) -> bool {
        *self == ImagePlane::default()
    }
}

/// A lens read by [`Lens::load_file`], with what its file says besides the prescription.
#[derive(Clone, Debug)]
pub struct Loaded {
    /// The lens.
    pub lens: Lens,
    /// The reader's warnings, each naming the file and the line.
    pub warnings: Vec<String>,
}

impl Lens {
    /// Loads a lens from a file path (DeepLens JSON, or Zemax .zmx by its extension) or a
    /// built-in name (`lens1`, `lens2`, `cooke-triplet`), with the built-in glass catalog.
    /// Warnings of the .zmx reader are dropped; see [`Lens::load_with_catalogs`].
    ///
    /// # Errors
    /// I/O, JSON, .zmx and validation errors, each naming the file and the place.
    pub fn load(name_or_path: &str) -> Result<Lens> {
        Lens::load_with_catalogs(name_or_path, &GlassCatalogs::builtin()).map(|(l, _)| l)
    }

    /// As [`Lens::load`], looking glasses up in `catalogs` (the user's AGF catalogs first), and
    /// returning the reader's warnings (skipped .zmx commands, approximations), each naming the
    /// file and the line.
    ///
    /// # Errors
    /// As [`Lens::load`].
    pub fn load_with_catalogs(
        name_or_path: &str,
        catalogs: &GlassCatalogs,
    ) -> Result<(Lens, Vec<String>)> {
        Lens::load_file(name_or_path, catalogs).map(|l| (l.lens, l.warnings))
    }

    /// As [`Lens::load_with_catalogs`], as a [`Loaded`]. A .zmx file's field points are in
    /// [`Lens::fields`] (what the CLI's commands use when no `--fields` is given).
    ///
    /// ```
    /// use tolray::lens::GlassCatalogs;
    /// let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zemax/cooke-triplet.zmx");
    /// let l = tolray::Lens::load_file(path, &GlassCatalogs::builtin())?;
    /// assert!(!l.lens.fields.is_empty());
    /// let b = tolray::Lens::load_file("lens2", &GlassCatalogs::builtin())?;
    /// assert!(b.lens.fields.is_empty() && b.warnings.is_empty());
    /// # Ok::<(), tolray::Error>(())
    /// ```
    ///
    /// # Errors
    /// As [`Lens::load`].
    pub fn load_file(name_or_path: &str, catalogs: &GlassCatalogs) -> Result<Loaded> {
        if let Some(lens) = builtin(name_or_path) {
            return Ok(Loaded {
                lens,
                warnings: Vec::new(),
            });
        }
        let path = Path::new(name_or_path);
        if !path.exists() {
            return Err(Error::new(
                crate::ErrorKind::Io,
                format!(
                    "{name_or_path}: no such file, and not a built-in lens (built-ins: {})",
                    builtin_names().join(", ")
                ),
            ));
        }
        if zemax::is_zmx_path(path) {
            let z = zemax::read_file(path, catalogs)?;
            return Ok(Loaded {
                lens: z.lens,
                warnings: z.warnings,
            });
        }
        Ok(Loaded {
            lens: json::read_file_with(path, catalogs)?,
            warnings: Vec::new(),
        })
    }

    /// The vignetting factors of `field`: those of the first of [`Lens::fields`] equal to it,
    /// else none (the whole pupil). OpticStudio likewise applies a field's factors to its own
    /// field point.
    ///
    /// ```
    /// use tolray::trace::{Field, FieldPoint, Vignetting};
    /// let mut lens = tolray::lens::Lens::load("lens1").unwrap();
    /// let v = Vignetting { compress_y: 0.2, ..Vignetting::default() };
    /// let field = Field::angle(10.0);
    /// lens.fields.push(FieldPoint { field, weight: 1.0, vignetting: v });
    /// assert_eq!(lens.vignetting_of(field), v);
    /// assert!(lens.vignetting_of(Field::angle(5.0)).is_none());
    /// ```
    pub fn vignetting_of(&self, field: Field) -> Vignetting {
        self.fields
            .iter()
            .find(|p| p.field == field)
            .map(|p| p.vignetting)
            .unwrap_or_default()
    }

    /// Index of the aperture stop surface, if one is marked.
    pub fn stop_index(&self) -> Option<usize> {
        self.surfaces.iter().position(|s| s.is_stop)
    }

    /// Makes every surface without a hard aperture clip at its semi-diameter, as DeepLens does
    /// (the CLI's `--clip-at-semi-diameter`). Returns how many surfaces changed.
    ///
    /// ```
    /// let mut lens = tolray::lens::Lens::load("lens1").unwrap();
    /// lens.surfaces[1].aperture = None;
    /// assert_eq!(lens.clip_at_semi_diameters(), 1);
    /// ```
    pub fn clip_at_semi_diameters(&mut self) -> usize {
        let mut n = 0;
        for s in &mut self.surfaces {
            if s.aperture.is_none() {
                s.aperture = Some(Aperture::SEMI_DIAMETER);
                n += 1;
            }
        }
        n
    }

    /// The direction of travel along z before each surface and, last, before the image plane:
    /// +1 from the object, flipped by each mirror. A gap must have the sign of the travel after
    /// its surface (OpticStudio's negative thicknesses after a mirror).
    pub fn travel_directions(&self) -> Vec<f64> {
        let mut dir = 1.0;
        let mut out = Vec::with_capacity(self.surfaces.len() + 1);
        for s in &self.surfaces {
            out.push(dir);
            if s.role == SurfaceRole::Mirror {
                dir = -dir;
            }
        }
        out.push(dir);
        out
    }

    /// True if surface `i` is a mirror.
    pub fn reflects(&self, i: usize) -> bool {
        self.surfaces[i].role == SurfaceRole::Mirror
    }

    /// True if surface `i` bends rays: every refracting surface and mirror, and a bare aperture that
    /// separates two different media (a flat interface, as OpticStudio treats a stop surface
    /// with a glass; it was once passed straight through, which changed the optics).
    pub fn refracts(&self, i: usize) -> bool {
        let s = &self.surfaces[i];
        s.role != SurfaceRole::Aperture || s.material != *self.medium_before(i)
    }

    /// The medium in front of surface `i`: the object medium for the first surface, else the
    /// medium after surface `i - 1`.
    pub fn medium_before(&self, i: usize) -> &Material {
        i.checked_sub(1)
            .map_or(&self.object_medium, |j| &self.surfaces[j].material)
    }

    /// Axial vertex positions of every surface and, last, of the image plane, mm (first vertex at 0).
    pub fn vertex_z_mm(&self) -> Vec<f64> {
        let mut z = Vec::with_capacity(self.surfaces.len() + 1);
        let mut acc = 0.0;
        for s in &self.surfaces {
            z.push(acc);
            acc += s.d_next_mm;
        }
        z.push(acc);
        z
    }

    /// Distance from the last vertex to the image plane, mm.
    pub fn image_distance_mm(&self) -> f64 {
        self.surfaces.last().map_or(0.0, |s| s.d_next_mm)
    }

    /// Checks the prescription for things no tracer can handle and says which surface is wrong.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] naming the surface index and the problem.
    pub fn validate(&self) -> Result<()> {
        if self.surfaces.is_empty() {
            return Err(Error::invalid("the lens has no surfaces"));
        }
        let n_stops = self.surfaces.iter().filter(|s| s.is_stop).count();
        if n_stops > 1 {
            return Err(Error::invalid(
                "more than one surface is marked as the aperture stop",
            ));
        }
        let dirs = self.travel_directions();
        for (i, s) in self.surfaces.iter().enumerate() {
            let at = |m: String| Error::invalid(format!("surface {i}: {m}"));
            let finite = [s.c, s.k, s.semi_aperture_mm, s.d_next_mm]
                .iter()
                .chain(s.asph.iter())
                .all(|v| v.is_finite());
            if !finite {
                return Err(at("a number is not finite".into()));
            }
            if let Shape::Toroidal { c_rot } = s.shape {
                if !(c_rot.abs() <= 1e3) {
                    return Err(at(format!(
                        "toroid rotation curvature {c_rot} (1/mm) is not finite or beyond ±1e3"
                    )));
                }
                if s.asph[N_ASPH - 1] != 0.0 {
                    return Err(at(
                        "a toroid's profile has terms up to y^14 (OpticStudio's PARM 2 to 8); the y^16 term must be 0".into(),
                    ));
                }
            }
            if let Shape::Paraxial { focal_mm } = s.shape {
                if !(focal_mm.abs() >= 1e-3 && focal_mm.abs() <= 1e9) {
                    return Err(at(format!(
                        "ideal thin lens focal length {focal_mm} mm: needs 1e-3 <= |f| <= 1e9"
                    )));
                }
                if s.c != 0.0 || s.k != 0.0 || s.asph.iter().any(|&a| a != 0.0) {
                    return Err(at(
                        "an ideal thin lens is flat: its curvature, conic and asphere terms must be 0"
                            .into(),
                    ));
                }
                let before = self.medium_before(i);
                if s.role != SurfaceRole::Refractive || s.material != *before {
                    return Err(at(format!(
                        "an ideal thin lens sits in one medium; here {} before it and {} after",
                        before.json_name(),
                        s.material.json_name()
                    )));
                }
            }
            if let Some(norm_radius_mm) = s.shape.norm_radius_mm() {
                if !(norm_radius_mm > 1e-6 && norm_radius_mm <= 1e6) {
                    return Err(at(format!(
                        "Q-type normalization radius {norm_radius_mm} mm: needs 1e-6 < radius <= 1e6"
                    )));
                }
            }
            if s.shape != Shape::Even && s.role == SurfaceRole::Aperture {
                return Err(at(
                    "a bare aperture is flat; it cannot be an odd asphere, a toroid or a Q-type asphere".into(),
                ));
            }
            // Magnitudes past these give no lens but overflow in the tracer (NaN or inf spots):
            // a radius under 1 µm, a conic beyond ±1e6, lengths beyond 1 km.
            for (what, v, max) in [
                ("curvature (1/mm)", s.c, 1e3),
                ("conic constant", s.k, 1e6),
                ("clear semi-aperture (mm)", s.semi_aperture_mm, 1e6),
                ("gap to the next surface (mm)", s.d_next_mm, 1e6),
            ] {
                if v.abs() > max {
                    return Err(at(format!("{what} {v} is beyond ±{max}")));
                }
            }
            // The paraxial curvature adds twice the r² (a toroid: y²) term; past this bound the
            // paraxial model overflows (an infinite power: EFL -0, a NaN exit pupil).
            let c_par = s.shape.paraxial_curvature(s.c, &s.asph);
            if !(c_par.abs() <= 1e3) {
                return Err(at(format!(
                    "paraxial curvature {c_par} (1/mm; the curvature plus twice the r² term) is beyond ±1e3"
                )));
            }
            if !(s.semi_aperture_mm > 0.0) {
                return Err(at(format!(
                    "clear semi-aperture {} mm must be positive",
                    s.semi_aperture_mm
                )));
            }
            // The last gap may run against the travel: a virtual image plane (the rays are
            // extended backwards to it, as OpticStudio does with a negative image thickness).
            if s.d_next_mm * dirs[i + 1] < 0.0 && i + 1 < self.surfaces.len() {
                return Err(at(if dirs[i + 1] > 0.0 {
                    format!("gap to the next surface {} mm is negative", s.d_next_mm)
                } else {
                    format!(
                        "gap to the next surface {} mm is positive after an odd number of mirrors (light travels toward -z there)",
                        s.d_next_mm
                    )
                }));
            }
            if s.role == SurfaceRole::Mirror {
                let before = self.medium_before(i);
                if s.material != *before {
                    return Err(at(
                        "a mirror's medium must be the one before it (the light travels back in it)"
                            .into(),
                    ));
                }
            }
            let rim = (1.0 + s.k) * s.c * s.c * s.semi_aperture_mm * s.semi_aperture_mm;
            if rim > 1.0 {
                return Err(at(format!(
                    "clear semi-aperture {} mm exceeds the surface's rim (radius {} mm, conic {})",
                    s.semi_aperture_mm,
                    1.0 / s.c,
                    s.k
                )));
            }
            if let Some(a) = &s.aperture {
                a.validate().map_err(|e| at(e.full_message()))?;
            }
            let n = s.vec_local;
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if !(n[2] > 0.0) || !(len > 0.0) {
                return Err(at("vec_local must point along +z".into()));
            }
            if s.role == SurfaceRole::Aperture && (s.c != 0.0 || s.is_aspheric()) {
                return Err(at("an aperture surface must be flat".into()));
            }
            if !(s.roll_deg.abs() <= 360.0) {
                return Err(at(format!(
                    "roll about the axis {} degrees is not finite or beyond ±360",
                    s.roll_deg
                )));
            }
            if let Some(g) = s.grating {
                if !(g.lines_per_um >= 0.0 && g.lines_per_um <= 1e4) {
                    return Err(at(format!(
                        "grating density {} lines/µm: needs 0 to 1e4",
                        g.lines_per_um
                    )));
                }
                if !(g.order.abs() <= 1e4) {
                    return Err(at(format!(
                        "grating order {} is not finite or beyond ±1e4",
                        g.order
                    )));
                }
                // OpticStudio's DGRATING is a conic (sphere, plane) surface; other shapes could
                // not be written back to a .zmx file.
                if s.role == SurfaceRole::Aperture || s.is_aspheric() {
                    return Err(at(
                        "a grating is ruled on a refracting or reflecting conic surface (OpticStudio's DGRATING): not on a bare aperture, an asphere, a toroid or an ideal thin lens".into(),
                    ));
                }
            }
            if let Some(f) = s.fold {
                if s.role != SurfaceRole::Mirror {
                    return Err(at(
                        "a fold turns the axis at a mirror; this surface does not reflect".into(),
                    ));
                }
                if !(f.tilt_deg.iter().all(|a| a.abs() <= 360.0) && f.pivot_mm.abs() <= 1e6) {
                    return Err(at(format!(
                        "fold tilts {:?} degrees must be within ±360 and its pivot {} mm within ±1e6",
                        f.tilt_deg, f.pivot_mm
                    )));
                }
            }
            // What the readers refuse, validation refuses (a lens edited through the library or
            // the C ABI must still be a lens its own JSON can hold).
            if let Material::Model { nd, vd } = s.material {
                // A stored model glass disperses (V_d = 0 reads as a constant index instead).
                if !(vd > 0.0) {
                    return Err(at(format!(
                        "the medium after it: model glass Abbe number {vd} must be positive"
                    )));
                }
                Material::model(nd, vd).map_err(|e| at(format!("the medium after it: {e}")))?;
            }
        }
        if !(self.primary_wavelength_nm > 0.0) {
            return Err(Error::invalid("primary wavelength must be positive"));
        }
        self.check_indices(self.primary_wavelength_nm)?;
        // A negative distance is a virtual object behind the first vertex (a converging beam).
        if let Object::Finite { distance_mm } = self.object {
            if distance_mm == 0.0 || !distance_mm.is_finite() {
                return Err(Error::invalid(
                    "object distance must be finite and not 0 (negative: a virtual object)",
                ));
            }
        }
        let ip = &self.image_plane;
        let n = ip.normal;
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        // (A normal whose squares underflow to a zero length has no direction.)
        let ok = n[2] > 0.0
            && len.is_finite()
            && len > 0.0
            && ip.decenter_mm.iter().all(|d| d.abs() <= 1e6)
            && ip.roll_deg.abs() <= 360.0;
        if !ok {
            return Err(Error::invalid(format!(
                "image plane: normal {n:?} must point along +z, decenter {:?} mm be finite, roll {} degrees within ±360",
                ip.decenter_mm, ip.roll_deg
            )));
        }
        for (k, p) in self.fields.iter().enumerate() {
            let at = |m: String| Error::invalid(format!("field {}: {m}", k + 1));
            if let Field::Fraction { .. } = p.field {
                return Err(at(
                    "a lens' field points are angles, object heights or image heights, not fractions"
                        .into(),
                ));
            }
            let (x, y) = p.field.xy();
            if !(x.is_finite() && y.is_finite() && p.weight.is_finite() && p.weight >= 0.0) {
                return Err(at(format!(
                    "({x}, {y}) with weight {} must be finite (the weight not negative)",
                    p.weight
                )));
            }
            p.vignetting
                .check()
                .map_err(|e| at(e.message().to_string()))?;
            let kind = std::mem::discriminant(&p.field);
            if kind != std::mem::discriminant(&self.fields[0].field) {
                return Err(at(
                    "a lens' field points are all of one kind: angles, object heights, paraxial or real image heights (as in a .zmx file)"
                        .into(),
                ));
            }
        }
        Ok(())
    }

    /// Checks that every medium has a finite refractive index of at least 0.9
    /// ([`material::MIN_INDEX`]: vacuum and gases relative to air) and at most 5 at
    /// `wavelength_nm`: a model glass with an absurd Abbe number, or a catalog glass far outside
    /// the range its formula was fitted on, otherwise gives NaN focal lengths and spots.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] naming the surface, the material, the wavelength and the index.
    pub fn check_indices(&self, wavelength_nm: f64) -> Result<()> {
        let n = self.object_medium.index(wavelength_nm);
        if !(material::MIN_INDEX..=5.0).contains(&n) {
            return Err(Error::invalid(format!(
                "the object medium ({}) has index {n} at {wavelength_nm} nm; a usable index is \
                 finite and between 0.9 and 5",
                self.object_medium.json_name()
            )));
        }
        for (i, s) in self.surfaces.iter().enumerate() {
            let n = s.material.index(wavelength_nm);
            if !(material::MIN_INDEX..=5.0).contains(&n) {
                return Err(Error::invalid(format!(
                    "surface {i}: the medium after it ({}) has index {n} at {wavelength_nm} nm; \
                     a usable index is finite and between 0.9 and 5",
                    s.material.json_name()
                )));
            }
        }
        Ok(())
    }

    /// Problems that do not stop tracing but an optical engineer should see: neighbouring
    /// surfaces whose sags cross inside their common clear aperture (negative edge thickness).
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        let dirs = self.travel_directions();
        for i in 0..self.surfaces.len().saturating_sub(1) {
            let (a, b) = (&self.surfaces[i], &self.surfaces[i + 1]);
            let r = a.semi_aperture_mm.min(b.semi_aperture_mm);
            for j in (0..=32).rev() {
                let rho = r * j as f64 / 32.0;
                if let (Some(za), Some(zb)) = (a.sag(rho), b.sag(rho)) {
                    // Along the light's path (toward -z after an odd number of mirrors).
                    let gap = (a.d_next_mm + zb - za) * dirs[i + 1];
                    if gap < -1e-9 {
                        out.push(format!(
                            "surfaces {i} and {} cross inside their clear apertures: at height {rho:.3} mm the gap is {gap:.4} mm (clear semi-apertures may be too large)",
                            i + 1
                        ));
                        break;
                    }
                }
            }
        }
        let mut waves = vec![self.primary_wavelength_nm];
        for w in self.rgb_wavelengths_nm {
            if !waves.contains(&w) {
                waves.push(w);
            }
        }
        for (i, s) in self.surfaces.iter().enumerate() {
            let (Some((lo, hi)), Some(name)) = (s.material.range_um(), s.material.catalog_name())
            else {
                continue;
            };
            let outside: Vec<String> = waves
                .iter()
                .filter(|&&w| w * 1e-3 < lo || w * 1e-3 > hi)
                .map(|w| format!("{w} nm"))
                .collect();
            if !outside.is_empty() {
                out.push(format!(
                    "surface {i}: glass {name} is defined from {lo} to {hi} µm; {} outside that range",
                    outside.join(", ")
                ));
            }
        }
        out
    }

    /// The lens with `adj` folded into its prescription: each surface's moved vertex and axis
    /// become its `pos_xy_mm`, `vec_local`, `roll_deg` (where the surface is not symmetric about
    /// its axis; elsewhere a turn about the axis changes nothing and is dropped) and gaps, the
    /// image plane's motion becomes its [`Lens::image_plane`], and curvature offsets are added to
    /// the curvatures. Compiling the result without adjustments traces the same rays as
    /// compiling `self` with `adj`. Gaps that no surface moves are kept bit for bit. The first
    /// vertex stays at z = 0, so an axial move of the first surface becomes a change of the object
    /// distance (and the global frame moves with it). This is how a fabricated (perturbed) lens is
    /// exported, e.g. to Zemax.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] if a surface ends up behind the previous one or a surface or
    /// the image plane is turned by 90 degrees or more.
    pub fn with_adjustments(&self, adj: &Adjustments) -> Result<Lens> {
        let n = self.surfaces.len();
        if adj.surface_motion.len() != n
            || adj.curvature_offset.len() != n
            || adj.curvature_error.len() != n
        {
            return Err(Error::argument(format!(
                "the adjustments are for {} surfaces; the lens has {n}",
                adj.surface_motion.len()
            )));
        }
        let im = &adj.image_motion;
        let z = self.vertex_z_mm();
        let mut out = self.clone();
        // Displacement of every vertex (and last, of the image plane) from its nominal place.
        let mut disp = Vec::with_capacity(n + 1);
        for (i, s) in out.surfaces.iter_mut().enumerate() {
            let m = &adj.surface_motion[i];
            let p = Vec3::new(s.pos_xy_mm[0], s.pos_xy_mm[1], z[i]);
            let d = if m.rotation == Mat3::identity() {
                m.translation
            } else {
                m.translation + (m.rotation.apply(p) - p)
            };
            if m.rotation != Mat3::identity() {
                let v = s.vec_local;
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                let a = m
                    .rotation
                    .apply(Vec3::new(v[0] / len, v[1] / len, v[2] / len));
                let frame = m.rotation * system::frame_rotation(v, s.roll_deg);
                s.vec_local = [a.x, a.y, a.z];
                if !s.is_axially_symmetric() {
                    s.roll_deg = system::roll_of(&frame, s.vec_local);
                }
            }
            s.pos_xy_mm = [p.x + d.x, p.y + d.y];
            s.c = s.c * (1.0 + adj.curvature_error[i]) + adj.curvature_offset[i];
            // A fold mirror moved along the axis leaves its downstream optics where they were:
            // the turn stays at its place on the axis.
            if let Some(f) = &mut s.fold {
                f.pivot_mm -= d.z;
            }
            disp.push(d.z);
        }
        // The image plane: its centre and frame moved as the System moves them.
        let ip = self.image_plane;
        let z_img = z[n];
        let c = Vec3::new(ip.decenter_mm[0], ip.decenter_mm[1], z_img);
        let c2 = im.rotation.apply(c) + im.translation;
        out.image_plane.decenter_mm = [c2.x, c2.y];
        if im.rotation == Mat3::identity() {
            // An axial shift alone: the image gap changes by exactly the shift.
            disp.push(im.translation.z);
        } else {
            let frame = im.rotation * system::frame_rotation(ip.normal, ip.roll_deg);
            let a = frame.apply(Vec3::new(0.0, 0.0, 1.0));
            out.image_plane.normal = [a.x, a.y, a.z];
            out.image_plane.roll_deg = system::roll_of(&frame, out.image_plane.normal);
            disp.push(c2.z - z_img);
        }
        for i in 0..n {
            let dz = disp[i + 1] - disp[i];
            if dz != 0.0 {
                out.surfaces[i].d_next_mm += dz;
            }
        }
        // The first vertex stays at z = 0: moving it along z moves the lens away from the object.
        if let Object::Finite { distance_mm } = &mut out.object {
            *distance_mm += disp[0];
        }
        out.validate()?;
        Ok(out)
    }

    /// Compiles the prescription with no adjustments into an `f64` table.
    pub fn compile(&self) -> System<f64> {
        System::compile(self, &Adjustments::none(self.surfaces.len()), &|_, v| v)
    }

    /// Paraxial (first-order) analysis at `wavelength_nm`.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Numerical`] for an afocal system or a lens without a stop.
    pub fn paraxial(&self, wavelength_nm: f64) -> Result<Paraxial> {
        paraxial::analyze(self, wavelength_nm)
    }
}
