//! A surface of a lens: its role, shape, hard aperture, fold and grating.

use super::*;

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
    /// A Zernike sag surface (OpticStudio's Zernike Fringe Sag `FZERNSAG` and Zernike Standard
    /// Sag `SZERNSAG`): the even asphere (`asph` = α1..α8 on ρ², ..., ρ¹⁶) plus
    /// `Σ A_j Z_j` over a normalization circle, the coefficients `A_j` (mm) in
    /// [`Surface::zernike`]; the formula is in [`super::zernike`].
    Zernike {
        /// Standard (Noll, normalised; up to 231 terms) or Fringe (37 terms).
        ordering: crate::math::zernike::Ordering,
        /// Normalization radius R, mm (positive).
        norm_radius_mm: f64,
        /// Where the polynomials are centred on the surface, (x, y) mm (OpticStudio's Zernike
        /// decenter, PARM 9 and 10).
        decenter_mm: [f64; 2],
        /// False: the Zernike terms are 0 beyond the normalization radius (OpticStudio's
        /// Extrapolate = 0, PARM 0); true: the polynomials continue.
        extrapolate: bool,
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
            Shape::Even | Shape::Toroidal { .. } | Shape::Zernike { .. } => w[0] = 1.0,
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
    /// The Zernike terms `terms` (Z1 first, mm) merged for evaluation over this shape's circle
    /// ([`super::zernike::ZernikeSag`]); `None` unless the shape is [`Shape::Zernike`].
    pub fn zernike_sag<S: crate::real::Real>(
        self,
        terms: &[S],
    ) -> Option<super::zernike::ZernikeSag<S>> {
        match self {
            Shape::Zernike {
                ordering,
                norm_radius_mm,
                decenter_mm,
                extrapolate,
            } => Some(super::zernike::ZernikeSag::new(
                ordering,
                norm_radius_mm,
                decenter_mm,
                extrapolate,
                terms,
            )),
            _ => None,
        }
    }
    /// True for shapes with rotational symmetry about the surface's axis (a Zernike sag surface
    /// counts as without, whatever its terms).
    pub fn is_rotational(self) -> bool {
        !matches!(self, Shape::Toroidal { .. } | Shape::Zernike { .. })
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
    /// The Zernike coefficients A_1, A_2, ... (mm) of a [`Shape::Zernike`] surface, in its
    /// ordering (empty for other shapes).
    pub zernike: Vec<f64>,
    /// A radial diffractive phase on the surface (OpticStudio's Binary 2, on an even asphere),
    /// or `None`.
    pub phase: Option<super::phase::RadialPhase>,
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
            zernike: Vec::new(),
            phase: None,
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
    /// The paraxial (vertex) curvature in the y-z plane, 1/mm: [`Shape::paraxial_curvature`]
    /// plus, on a Zernike sag surface, twice the y² coefficient its terms add at the vertex
    /// ([`super::zernike::vertex_weights`]).
    ///
    /// ```
    /// use tolray::lens::{Material, Shape, Surface};
    /// use tolray::math::zernike::Ordering;
    /// let mut s = Surface::sphere(0.01, 5.0, 2.0, Material::Air);
    /// s.shape = Shape::Zernike {
    ///     ordering: Ordering::Fringe,
    ///     norm_radius_mm: 10.0,
    ///     decenter_mm: [0.0; 2],
    ///     extrapolate: true,
    /// };
    /// s.zernike = vec![0.0, 0.0, 0.0, 0.05]; // 0.05 (2ρ² − 1): 0.001 y² more
    /// assert!((s.paraxial_curvature() - 0.012).abs() < 1e-15);
    /// ```
    pub fn paraxial_curvature(&self) -> f64 {
        self.shape.paraxial_curvature(self.c, &self.asph)
            + 2.0
                * self
                    .zernike_vertex_weights()
                    .iter()
                    .zip(&self.zernike)
                    .map(|(w, a)| w[1] * a)
                    .sum::<f64>()
    }
    /// What each of [`Surface::zernike`]'s terms adds at the vertex per mm, `[sag, y²
    /// coefficient]` ([`super::zernike::vertex_weights`]); empty for other shapes.
    pub fn zernike_vertex_weights(&self) -> Vec<[f64; 2]> {
        super::zernike::vertex_weights(self.shape, self.zernike.len())
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
            Shape::Zernike { .. } => {
                let terms = self.shape.zernike_sag(&self.zernike)?;
                Some(even(x * x + y * y)? + terms.eval(x, y).0)
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
