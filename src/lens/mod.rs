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
mod catalog_agf;
mod catalog_data;
mod catalog_extra;
pub mod field;
pub mod gradient;
pub mod json;
pub mod material;
pub mod paraxial;
pub mod phase;
pub mod qbfs;
pub mod qcon;
mod surface;
mod system;
mod text;
pub mod zemax;
pub mod zernike;

pub use builtin::{builtin, builtin_names};
pub use field::{Field, FieldPoint, Vignetting};
pub use gradient::{Gradient, GradientForm};
pub use material::{GlassCatalogs, Material};
pub use paraxial::Paraxial;
pub use surface::{Aperture, ApertureShape, Fold, Grating, Shape, Surface, SurfaceRole};
pub use system::{Adjustments, Clip, Param, SurfaceKind, SurfaceRow, System};

use crate::error::{Error, Result};
use crate::math::{Mat3, Vec3};
use std::path::Path;

/// Number of even-asphere coefficients stored per surface: a2, a4, ..., a16.
pub const N_ASPH: usize = 8;

/// The farthest finite object accepted, mm (10^9 km). A field's rays start at the object point,
/// so the launch's rounding grows with the distance (about a nanometre at 1e10 mm, a tenth of a
/// millimetre here) and its squares overflow not far beyond: a farther object is at infinity
/// (`inf`).
pub const MAX_OBJECT_DISTANCE_MM: f64 = 1e15;

/// Where the object is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Object {
    /// At infinity: every field is a bundle of parallel rays.
    Infinite,
    /// At a finite distance in front of the first vertex (the object plane is `z = -distance_mm`).
    Finite {
        /// Distance from the object plane to the first vertex, mm: positive for a real object;
        /// 0 for an object on the first vertex's plane (OpticStudio's object thickness 0: a
        /// source in contact with the first surface; its fields are object or image heights);
        /// negative for a virtual object behind the first vertex, on which the entering beam
        /// converges (OpticStudio's negative object thickness).
        distance_mm: f64,
    },
}

impl Object {
    /// Parses `inf` / `infinity`, a distance in mm to a real object in front of the first
    /// vertex (its magnitude: DeepLens' negative `obj_depth` is accepted; 0 puts the object on
    /// the first vertex's plane), or `virtual:MM`, a virtual object MM behind the first vertex
    /// (a beam converging on it).
    ///
    /// ```
    /// use tolray::Object;
    /// assert_eq!(Object::parse("-1000").unwrap(), Object::Finite { distance_mm: 1000.0 });
    /// assert_eq!(Object::parse("virtual:50").unwrap(), Object::Finite { distance_mm: -50.0 });
    /// assert_eq!(Object::parse("inf").unwrap(), Object::Infinite);
    /// assert_eq!(Object::parse("0").unwrap(), Object::Finite { distance_mm: 0.0 });
    /// assert!(Object::parse("virtual:inf").is_err());
    /// assert!(Object::parse("1e300").is_err()); // beyond MAX_OBJECT_DISTANCE_MM: write inf
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for anything else, a distance beyond
    /// [`MAX_OBJECT_DISTANCE_MM`], or a virtual object that is not a finite positive distance.
    pub fn parse(s: &str) -> Result<Object> {
        let t = s.trim().to_ascii_lowercase();
        if matches!(t.as_str(), "inf" | "infinity" | "-inf") {
            return Ok(Object::Infinite);
        }
        if let Some(v) = t.strip_prefix("virtual:") {
            return match v.trim().parse::<f64>() {
                Ok(v) if v > 0.0 && v <= MAX_OBJECT_DISTANCE_MM => {
                    Ok(Object::Finite { distance_mm: -v })
                }
                _ => Err(Error::argument(format!(
                    "object distance \"{s}\": a virtual object needs a distance in mm behind the first vertex, greater than 0 (e.g. virtual:50)"
                ))),
            };
        }
        match t.parse::<f64>() {
            Ok(v) if v.is_infinite() => Ok(Object::Infinite),
            Ok(v) if v.abs() <= MAX_OBJECT_DISTANCE_MM => Ok(Object::Finite {
                distance_mm: v.abs(),
            }),
            _ => Err(Error::argument(format!(
                "object distance \"{s}\": give a distance in mm (e.g. 1000, at most 1e15), \"inf\", or virtual:MM for a virtual object MM behind the first vertex"
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
    /// Curvature of the image surface at its vertex, 1/mm (OpticStudio's `CURV` on the image
    /// surface; 0: a plane). A curved image surface is a conic of revolution about the plane's
    /// normal through its centre; what lands on it is reported as the x, y of each ray's
    /// crossing in the surface's frame, as OpticStudio reports it.
    pub curvature_per_mm: f64,
    /// Conic constant of a curved image surface (OpticStudio's `CONI`; 0 a sphere, -1 a
    /// paraboloid).
    pub conic: f64,
}

impl Default for ImagePlane {
    fn default() -> Self {
        ImagePlane {
            decenter_mm: [0.0; 2],
            normal: [0.0, 0.0, 1.0],
            roll_deg: 0.0,
            curvature_per_mm: 0.0,
            conic: 0.0,
        }
    }
}

impl ImagePlane {
    /// True for the plane centred on the axis and perpendicular to it, unrolled and flat.
    pub fn is_default(&self) -> bool {
        *self == ImagePlane::default()
    }

    /// True when the pose differs from the default (decentred, tilted or rolled), whatever the
    /// curvature.
    pub fn is_moved(&self) -> bool {
        ImagePlane {
            curvature_per_mm: 0.0,
            conic: 0.0,
            ..*self
        } != ImagePlane::default()
    }

    /// True for a curved image surface.
    pub fn is_curved(&self) -> bool {
        self.curvature_per_mm != 0.0
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

    /// Why the gradient-index medium `g` after surface `i` (light travelling `dir` along the
    /// axis) cannot be traced, if it cannot: a surface must end it (not the image), its gap runs
    /// forward, it follows a conic surface, neither of its surfaces is a mirror, a grating or a
    /// diffractive phase, and [`Gradient::validate`].
    fn check_gradient(&self, i: usize, g: &Gradient, dir: f64) -> std::result::Result<(), String> {
        g.validate().map_err(|e| e.full_message())?;
        let Some(next) = self.surfaces.get(i + 1) else {
            return Err("it must end at a surface before the image".into());
        };
        let s = &self.surfaces[i];
        // OpticStudio's Gradient 1 to 3 surfaces are conics: what a .zmx file can hold.
        if s.shape != Shape::Even || s.is_aspheric() {
            return Err(
                "it must follow a conic surface (OpticStudio's Gradient surfaces are conics): no asphere terms or other shape".into(),
            );
        }
        if !(s.d_next_mm * dir > 0.0) {
            return Err(format!(
                "its thickness {} mm must be positive, with the light going forward",
                s.d_next_mm
            ));
        }
        // Past 1e4 steps the integration error is rounding (the test doublet agrees with the
        // reference to 2e-14 mm at 2e3 steps) and a trace only gets slower.
        if s.d_next_mm.abs() / g.step_mm > 1e4 {
            return Err(format!(
                "step {} mm (Δt): more than 10,000 steps across its {} mm",
                g.step_mm, s.d_next_mm
            ));
        }
        for (k, t) in [(i, s), (i + 1, next)] {
            if t.role == SurfaceRole::Mirror || t.grating.is_some() || t.phase.is_some() {
                return Err(format!(
                    "surface {k}, which bounds it, is a mirror, a grating or a diffractive phase"
                ));
            }
        }
        Ok(())
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
                .chain(s.zernike.iter())
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
            if let Shape::Zernike {
                ordering,
                norm_radius_mm,
                decenter_mm,
                ..
            } = s.shape
            {
                if !(norm_radius_mm > 1e-6 && norm_radius_mm <= 1e6) {
                    return Err(at(format!(
                        "Zernike normalization radius {norm_radius_mm} mm: needs 1e-6 < radius <= 1e6"
                    )));
                }
                if !decenter_mm.iter().all(|d| d.abs() <= 1e6) {
                    return Err(at(format!(
                        "Zernike decenter {decenter_mm:?} mm is not finite or beyond ±1e6"
                    )));
                }
                let max = ordering.max_terms();
                if s.zernike.len() > max {
                    return Err(at(format!(
                        "{} Zernike {ordering:?} terms: a Zernike sag surface has at most {max}",
                        s.zernike.len()
                    )));
                }
                if let Some(a) = s.zernike.iter().find(|a| a.abs() > 1e6) {
                    return Err(at(format!("Zernike coefficient {a} mm is beyond ±1e6")));
                }
            } else if !s.zernike.is_empty() {
                return Err(at(
                    "Zernike coefficients on a surface that is not a Zernike sag surface".into(),
                ));
            }
            if let Some(ph) = &s.phase {
                if !(ph.order.abs() <= 1e3) {
                    return Err(at(format!(
                        "diffraction order {} of the phase is not finite or beyond ±1e3",
                        ph.order
                    )));
                }
                if !(ph.norm_radius_mm > 1e-6 && ph.norm_radius_mm <= 1e6) {
                    return Err(at(format!(
                        "phase normalization radius {} mm: needs 1e-6 < radius <= 1e6",
                        ph.norm_radius_mm
                    )));
                }
                if ph.coefficients.len() > phase::MAX_PHASE_TERMS {
                    return Err(at(format!(
                        "{} phase terms: a surface has at most {}",
                        ph.coefficients.len(),
                        phase::MAX_PHASE_TERMS
                    )));
                }
                if let Some(a) = ph.coefficients.iter().find(|a| !(a.abs() <= 1e12)) {
                    return Err(at(format!(
                        "phase coefficient {a} (radians) is not finite or beyond ±1e12"
                    )));
                }
                if s.shape != Shape::Even || s.grating.is_some() || s.role == SurfaceRole::Aperture
                {
                    return Err(at(
                        "a diffractive phase sits on an even asphere (OpticStudio's Binary 2), without a grating, on a refracting surface or a mirror".into(),
                    ));
                }
            }
            if s.shape != Shape::Even && s.role == SurfaceRole::Aperture {
                return Err(at(
                    "a bare aperture is flat; it cannot be an odd asphere, a toroid, a Q-type asphere or a Zernike sag surface".into(),
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
            let c_par = s.paraxial_curvature();
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
            if !turned_less_than_90_deg(s.vec_local) {
                return Err(at(format!(
                    "vec_local {:?} must be a finite direction turned less than 90 degrees from +z \
                     (a normal whose squared length overflows or underflows has no direction)",
                    s.vec_local
                )));
            }
            // Lengths beyond 1 km, as above (a decentre of 9e18 mm keeps no digit below a
            // kilometre).
            if !s.pos_xy_mm.iter().all(|v| v.abs() <= 1e6) {
                return Err(at(format!(
                    "decenter {:?} mm is not finite or beyond ±1e6",
                    s.pos_xy_mm
                )));
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
            if let Material::Gradient(g) = &s.material {
                self.check_gradient(i, g, dirs[i + 1])
                    .map_err(|m| at(format!("the gradient-index medium after it: {m}")))?;
            }
        }
        if matches!(self.object_medium, Material::Gradient(_)) {
            return Err(Error::invalid(
                "the object space cannot be a gradient-index medium (it follows a surface)",
            ));
        }
        if !(self.primary_wavelength_nm > 0.0) {
            return Err(Error::invalid("primary wavelength must be positive"));
        }
        self.check_indices(self.primary_wavelength_nm)?;
        for w in self.rgb_wavelengths_nm {
            if w > material::DEFINED_MEDIA_BEYOND_NM {
                self.check_indices(w)?;
            }
        }
        // A negative distance is a virtual object behind the first vertex (a converging beam); 0
        // the object on the first vertex's plane.
        if let Object::Finite { distance_mm } = self.object {
            if !(distance_mm.abs() <= MAX_OBJECT_DISTANCE_MM) {
                return Err(Error::invalid(format!(
                    "object distance {distance_mm} mm: it must be finite and at most 1e15 mm in \
                     magnitude (farther is an object at infinity; negative: a virtual object)"
                )));
            }
        }
        let ip = &self.image_plane;
        let n = ip.normal;
        let ok = turned_less_than_90_deg(n)
            && ip.decenter_mm.iter().all(|d| d.abs() <= 1e6)
            && ip.roll_deg.abs() <= 360.0
            && ip.curvature_per_mm.abs() <= 1000.0
            && ip.conic.abs() <= 1e6;
        if !ok {
            return Err(Error::invalid(format!(
                "image plane: normal {n:?} must be a finite direction turned less than 90 degrees from +z, decenter {:?} mm be finite, roll {} degrees within ±360, curvature {} 1/mm within ±1000 and conic {} within ±1e6",
                ip.decenter_mm, ip.roll_deg, ip.curvature_per_mm, ip.conic
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
        let media = std::iter::once(("the object medium".to_string(), &self.object_medium)).chain(
            self.surfaces
                .iter()
                .enumerate()
                .map(|(i, s)| (format!("surface {i}: the medium after it"), &s.material)),
        );
        for (what, m) in media {
            let name = m
                .catalog_name()
                .map_or_else(|| m.json_name(), str::to_string);
            if wavelength_nm > material::DEFINED_MEDIA_BEYOND_NM && !m.defined_at(wavelength_nm) {
                let range = m
                    .range_um()
                    .map(|(lo, hi)| format!(", defined from {lo} to {hi} µm"))
                    .unwrap_or_else(|| ", a law fitted to the visible".into());
                return Err(Error::invalid(format!(
                    "{what} ({name}{range}) has no index at {} µm; beyond 20 µm only media \
                     defined there are traced (air, constant indices, glasses whose range \
                     reaches it): give wavelengths in micrometres (nanometres on the command \
                     line)",
                    wavelength_nm * 1e-3
                )));
            }
            let n = m.index(wavelength_nm);
            if !material::is_usable_index(n) {
                return Err(Error::invalid(format!(
                    "{what} ({name}) has index {n} at {wavelength_nm} nm; a usable index is \
                     finite and between {} and {}",
                    material::MIN_INDEX,
                    material::MAX_INDEX
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
    /// [`crate::ErrorKind::Invalid`] if a surface or the image plane ends up on the other side of
    /// the surface before it (a gap changes its sign along the light's travel), or a surface or
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
        // Whether the next surface (or the image) is reached virtually is the sign of the gap
        // along the light's travel (`System::compile`); a motion that flips it would trace
        // otherwise once baked: the moved system's rays end there as going backward.
        let dirs = self.travel_directions();
        for i in 0..n {
            let dz = disp[i + 1] - disp[i];
            if dz != 0.0 {
                let gap = out.surfaces[i].d_next_mm;
                let moved = gap + dz;
                if (gap * dirs[i + 1] < 0.0) != (moved * dirs[i + 1] < 0.0) {
                    let next = if i + 1 == n {
                        "the image plane".to_string()
                    } else {
                        format!("surface {}", i + 1)
                    };
                    return Err(Error::invalid(format!(
                        "the adjustments move {next} to the other side of surface {i} (the gap of {gap} mm becomes {moved} mm)"
                    )));
                }
                out.surfaces[i].d_next_mm = moved;
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

/// The cosine a surface normal (or the image plane's) keeps with the axis: a lens turned further
/// (within 1e-6 of 90 degrees) would be written to a .zmx file as coordinate breaks its reader
/// refuses.
pub const MIN_AXIS_COSINE: f64 = 1e-6;

/// True when `n` is a direction (finite, with a squared length that neither overflows nor
/// underflows) whose angle to +z has a cosine above [`MIN_AXIS_COSINE`].
fn turned_less_than_90_deg(n: [f64; 3]) -> bool {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    len.is_finite() && len > 0.0 && n[2] / len > MIN_AXIS_COSINE
}
