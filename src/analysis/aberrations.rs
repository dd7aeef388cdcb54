//! Aberration curves from real rays: field curvature, distortion (f-tan θ and f-θ), lateral
//! colour, relative illumination, ray fans and OPD fans.
//!
//! Conventions (OpticStudio's, checked against optiland where it has the analysis:
//! `tests/optics/aberrations.rs`):
//! - **Field curvature**: for each field, two parabasal rays at normalised pupil ±1e-5 about the
//!   pupil centre, in the tangential plane (the plane of the field direction and the axis) and
//!   in the sagittal plane; where they cross, measured along the image plane's normal from
//!   where the first meets the image plane, mm (positive behind the plane).
//! - **Distortion**: the chief ray's image point relative to the on-axis one, along the field
//!   direction, against the ideal `k u` with `u = tan θ` (f-tan θ) or `θ` (f-θ) and `k` the
//!   near-axis scale (the derivative at the axis, from two chief rays at ±1e-6 of the field);
//!   `100 (y_real − y_ideal) / y_ideal` %. For a finite object `u` is the object height over its
//!   distance (f-tan θ only).
//! - **Grid distortion**: the same for a grid of fields over the sensor, in two dimensions: the
//!   ideal point `k proj(|t|)` along each field's direction `t` and the real chief ray's
//!   ([`grid_distortion`]).
//! - **Lateral colour**: the chief ray's image point at each wavelength minus at the primary
//!   wavelength, along the field direction, µm.
//! - **Relative illumination**: the irradiance at the chief ray's image point over that on axis
//!   for a Lambertian object: the object-space étendue of the rays that get through over the
//!   image area the field element maps to ([`relative_illumination`]); vignetting, pupil
//!   aberrations and distortion are in it (cos⁴ θ for a thin lens without vignetting).
//! - **Ray fans**: transverse ray error against the normalised pupil coordinate along the
//!   tangential (sagittal) direction, relative to the primary wavelength's chief ray, µm, in the
//!   same direction; **OPD fans**: the OPD of the same rays ([`crate::wave`]), waves.

use crate::error::{Error, Result};
use crate::lens::paraxial::LaunchOptics;
use crate::lens::{Lens, Object, Paraxial, System};
use crate::trace::{self, Field, RaySet, TraceOptions};
use crate::wave::{self, zernike, Sampling, WaveOptions};
use serde::Serialize;

/// Normalised pupil offset of field curvature's parabasal rays (optiland's).
pub const PARABASAL: f64 = 1e-5;

/// Which projection distortion is measured against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum DistortionKind {
    /// `y = k tan θ` (rectilinear; OpticStudio's "distortion").
    FTan,
    /// `y = k θ` (OpticStudio's "F-Theta distortion"; objects at infinity).
    FTheta,
}

/// Unit vector of a field's direction in the object (and image) plane: y on axis.
fn field_direction(t: (f64, f64)) -> [f64; 2] {
    let r = t.0.hypot(t.1);
    if r > 0.0 {
        [t.0 / r, t.1 / r]
    } else {
        [0.0, 1.0]
    }
}

/// Traced rays of one field and wavelength: each pupil point's image-plane point (image frame,
/// mm) and direction (image frame), `None` where the ray did not get through; and the chief
/// ray's.
struct Traced {
    points: Vec<Option<([f64; 3], [f64; 3])>>,
    chief: Option<([f64; 3], [f64; 3])>,
}

fn trace_points(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    pts: &[[f64; 2]],
    aim: bool,
    opts: TraceOptions,
) -> Result<Traced> {
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    let set = RaySet::generate_at(lens, &para, field, pts, aim, wavelength_nm)?;
    let mut batch = set.batch::<f64>();
    batch.push(set.chief.0, set.chief.1);
    trace::trace(sys, wavelength_nm, &mut batch, opts);
    let img = &sys.image;
    let get = |i: usize| {
        let r = batch.get(i);
        if !r.status.is_alive() {
            return None;
        }
        let p = img.point_to_local(r.o);
        let d = img.rotation.apply_t(r.d);
        let v = ([p.x, p.y, p.z], [d.x, d.y, d.z]);
        (v.0.iter().chain(&v.1).all(|x| x.is_finite())).then_some(v)
    };
    Ok(Traced {
        points: (0..pts.len()).map(get).collect(),
        chief: get(pts.len()),
    })
}

/// Field curvature at `field` and `wavelength_nm`: `[tangential, sagittal]` focus positions,
/// mm along the image plane's normal from the image plane (see the module's conventions).
///
/// # Errors
/// [`crate::ErrorKind::Numerical`] when a parabasal ray does not reach the image, or the pair
/// does not cross (parallel rays: an afocal lens); ray-generation errors.
///
/// # Examples
/// ```
/// use tolray::analysis::aberrations::field_curvature;
/// use tolray::trace::Field;
/// let lens = tolray::Lens::load("cooke-triplet")?;
/// let [t, s] = field_curvature(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, false)?;
/// // On axis the tangential and sagittal foci coincide.
/// assert!((t - s).abs() < 1e-9);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn field_curvature(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    aim: bool,
) -> Result<[f64; 2]> {
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    let t = field_direction(
        field
            .resolved(lens, &para, aim)?
            .tangents_f64(lens, &para)?,
    );
    let s = [t[1], -t[0]];
    let d = PARABASAL;
    let pts = [
        [-d * t[0], -d * t[1]],
        [d * t[0], d * t[1]],
        [-d * s[0], -d * s[1]],
        [d * s[0], d * s[1]],
    ];
    let tr = trace_points(
        lens,
        sys,
        field,
        wavelength_nm,
        &pts,
        aim,
        TraceOptions::default(),
    )?;
    let what = || {
        format!(
            "field curvature at field {}, {wavelength_nm} nm",
            field.label()
        )
    };
    let focus = |a: usize, u: [f64; 2]| -> Result<f64> {
        let (Some((p1, d1)), Some((p2, d2))) = (tr.points[a], tr.points[a + 1]) else {
            return Err(Error::numerical(format!(
                "{}: a parabasal ray does not reach the image",
                what()
            )));
        };
        // In the plane of u and the normal: ray k is (x_k + t m_k, z_k + t n_k).
        let (x1, x2) = (p1[0] * u[0] + p1[1] * u[1], p2[0] * u[0] + p2[1] * u[1]);
        let (m1, m2) = (d1[0] * u[0] + d1[1] * u[1], d2[0] * u[0] + d2[1] * u[1]);
        let det = m1 * d2[2] - m2 * d1[2];
        let t1 = (m2 * (p1[2] - p2[2]) - d2[2] * (x1 - x2)) / det;
        let z = p1[2] + t1 * d1[2];
        if !z.is_finite() || det == 0.0 {
            return Err(Error::numerical(format!(
                "{}: the parabasal rays do not cross (parallel: no focus)",
                what()
            )));
        }
        Ok(z)
    };
    Ok([focus(0, t)?, focus(2, s)?])
}

/// The chief ray's image point (image frame, x and y, mm) at `field`.
fn chief_point(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    aim: bool,
) -> Result<[f64; 2]> {
    let tr = trace_points(
        lens,
        sys,
        field,
        wavelength_nm,
        &[],
        aim,
        TraceOptions::default(),
    )?;
    tr.chief.map(|(p, _)| [p[0], p[1]]).ok_or_else(|| {
        Error::numerical(format!(
            "the chief ray of field {} at {wavelength_nm} nm does not reach the image; is the \
             field beyond the lens' reach?",
            field.label()
        ))
    })
}

/// What distortion is measured with: the on-axis chief ray's image point, the paraxial data
/// of the primary wavelength, and the projection.
struct Scale<'a> {
    lens: &'a Lens,
    sys: &'a System<f64>,
    para: Paraxial,
    wavelength_nm: f64,
    kind: DistortionKind,
    aim: bool,
    origin: [f64; 2],
}

/// A chief ray's image point relative to the on-axis one, its field's direction `u`, and the
/// ideal image radius along `u` (`k proj(r)`, `k` the near-axis scale along `u`).
struct Projected {
    real: [f64; 2],
    u: [f64; 2],
    ideal: f64,
}

impl Projected {
    /// `100 (y_real − y_ideal) / y_ideal` along the field's direction.
    fn distortion_pct(&self) -> f64 {
        let real = self.real[0] * self.u[0] + self.real[1] * self.u[1];
        100.0 * (real - self.ideal) / self.ideal
    }
}

impl<'a> Scale<'a> {
    fn new(
        lens: &'a Lens,
        sys: &'a System<f64>,
        wavelength_nm: f64,
        kind: DistortionKind,
        aim: bool,
    ) -> Result<Self> {
        if kind == DistortionKind::FTheta && lens.object != Object::Infinite {
            return Err(Error::argument(
                "f-theta distortion needs an object at infinity (a field angle)",
            ));
        }
        let para = lens.paraxial(lens.primary_wavelength_nm)?;
        let origin = chief_point(lens, sys, Field::fraction(0.0), wavelength_nm, aim)?;
        Ok(Scale {
            lens,
            sys,
            para,
            wavelength_nm,
            kind,
            aim,
            origin,
        })
    }

    /// [`Projected`] of field `f`; `None` on axis.
    fn project(&self, f: Field) -> Result<Option<Projected>> {
        let (lens, sys, wl, aim, origin) = (
            self.lens,
            self.sys,
            self.wavelength_nm,
            self.aim,
            self.origin,
        );
        let proj = |u: f64| match self.kind {
            DistortionKind::FTan => u,
            DistortionKind::FTheta => u.atan(),
        };
        let q = f
            .resolved(lens, &self.para, aim)?
            .tangents_f64(lens, &self.para)?;
        let r = q.0.hypot(q.1);
        if r == 0.0 {
            return Ok(None);
        }
        let u = field_direction(q);
        let along = |p: [f64; 2]| (p[0] - origin[0]) * u[0] + (p[1] - origin[1]) * u[1];
        // The scale along this field's direction, from chief rays at ±e.
        let e = 1e-6 * r;
        let near = |sgn: f64| {
            chief_point(
                lens,
                sys,
                Field::of_tangents(lens, [sgn * e * u[0], sgn * e * u[1]]),
                wl,
                aim,
            )
            .map(along)
        };
        let k = (near(1.0)? - near(-1.0)?) / (2.0 * proj(e));
        let p = chief_point(lens, sys, f, wl, aim)?;
        let ideal = k * proj(r);
        if !(ideal.abs() > 0.0) || !ideal.is_finite() {
            return Err(Error::numerical(format!(
                "distortion at field {}: the near-axis image scale is {k} (no image to \
                 distort: an afocal lens?)",
                f.label()
            )));
        }
        Ok(Some(Projected {
            real: [p[0] - origin[0], p[1] - origin[1]],
            u,
            ideal,
        }))
    }
}

/// Distortion (%) of each of `fields` at `wavelength_nm` against `kind` (see the module's
/// conventions); 0 on axis.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for f-θ with a finite object; [`crate::ErrorKind::Numerical`]
/// when a chief ray does not reach the image or the near-axis scale is 0 (an afocal lens).
///
/// # Examples
/// ```
/// use tolray::analysis::aberrations::{distortion, DistortionKind};
/// use tolray::trace::Field;
/// let lens = tolray::Lens::load("cooke-triplet")?;
/// let d = distortion(&lens, &lens.compile(), &[Field::fraction(0.0), Field::fraction(1.0)],
///                    587.5618, DistortionKind::FTan, false)?;
/// assert_eq!(d[0], 0.0);
/// assert!(d[1].abs() < 5.0);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn distortion(
    lens: &Lens,
    sys: &System<f64>,
    fields: &[Field],
    wavelength_nm: f64,
    kind: DistortionKind,
    aim: bool,
) -> Result<Vec<f64>> {
    let scale = Scale::new(lens, sys, wavelength_nm, kind, aim)?;
    fields
        .iter()
        .map(|&f| Ok(scale.project(f)?.map_or(0.0, |p| p.distortion_pct())))
        .collect()
}

/// Grid distortion (OpticStudio's): a grid of `n` x `n` fields over the sensor (its rectangle
/// when the lens has a resolution, else the square inside the image circle), the real chief
/// rays' image points and the ideal ones, both relative to the on-axis image point.
#[derive(Clone, Debug, Serialize)]
pub struct GridDistortion {
    /// Points per side.
    pub n: usize,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// The projection of the ideal grid.
    pub kind: DistortionKind,
    /// Each point's field, fractions of the full field (row-major from the lower left, x
    /// fastest).
    pub fields: Vec<[f64; 2]>,
    /// Ideal image points, mm: `k proj(|t|)` along the field's direction (see the module's
    /// conventions).
    pub ideal_mm: Vec<[f64; 2]>,
    /// Real chief rays' image points, mm.
    pub real_mm: Vec<[f64; 2]>,
    /// Distortion of each point along its field's direction, % (0 at the centre): the value
    /// [`distortion`] gives for that field.
    pub distortion_pct: Vec<f64>,
    /// The largest distortion in magnitude, % (signed).
    pub max_distortion_pct: f64,
}

/// Grid distortion of `n` x `n` fields at `wavelength_nm` against `kind` ([`GridDistortion`]).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for `n` outside 2..=101 or f-θ with a finite object;
/// [`crate::ErrorKind::Numerical`] when a chief ray does not reach the image.
///
/// # Examples
/// ```
/// use tolray::analysis::aberrations::{grid_distortion, DistortionKind};
/// let lens = tolray::Lens::load("lens2")?;
/// let g = grid_distortion(&lens, &lens.compile(), 5, 587.5618, DistortionKind::FTan, false)?;
/// assert_eq!(g.real_mm.len(), 25);
/// assert_eq!(g.distortion_pct[12], 0.0); // the centre
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn grid_distortion(
    lens: &Lens,
    sys: &System<f64>,
    n: usize,
    wavelength_nm: f64,
    kind: DistortionKind,
    aim: bool,
) -> Result<GridDistortion> {
    if !(2..=101).contains(&n) {
        return Err(Error::argument(format!(
            "a distortion grid of {n} points a side: give 2 to 101"
        )));
    }
    let scale = Scale::new(lens, sys, wavelength_nm, kind, aim)?;
    let [cols, rows] = lens.sensor.resolution;
    let (hx, hy) = if cols > 0 && rows > 0 {
        let d = f64::from(cols).hypot(f64::from(rows));
        (f64::from(cols) / d, f64::from(rows) / d)
    } else {
        (
            std::f64::consts::FRAC_1_SQRT_2,
            std::f64::consts::FRAC_1_SQRT_2,
        )
    };
    let at = |k: usize, h: f64| h * (2.0 * k as f64 / (n - 1) as f64 - 1.0);
    let mut g = GridDistortion {
        n,
        wavelength_nm,
        kind,
        fields: Vec::with_capacity(n * n),
        ideal_mm: Vec::with_capacity(n * n),
        real_mm: Vec::with_capacity(n * n),
        distortion_pct: Vec::with_capacity(n * n),
        max_distortion_pct: 0.0,
    };
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (at(i, hx), at(j, hy));
            let (ideal, real, pct) = match scale.project(Field::Fraction { x, y })? {
                None => ([0.0; 2], [0.0; 2], 0.0),
                Some(p) => (
                    [p.ideal * p.u[0], p.ideal * p.u[1]],
                    p.real,
                    p.distortion_pct(),
                ),
            };
            if pct.abs() > g.max_distortion_pct.abs() {
                g.max_distortion_pct = pct;
            }
            g.fields.push([x, y]);
            g.ideal_mm.push(ideal);
            g.real_mm.push(real);
            g.distortion_pct.push(pct);
        }
    }
    Ok(g)
}

/// Lateral colour at each of `fields`: the chief ray's image point at each of
/// `wavelengths_nm` minus at the lens' primary wavelength, along the field direction, µm;
/// `[field][wavelength]`.
///
/// # Errors
/// As [`distortion`].
pub fn lateral_colour(
    lens: &Lens,
    sys: &System<f64>,
    fields: &[Field],
    wavelengths_nm: &[f64],
    aim: bool,
) -> Result<Vec<Vec<f64>>> {
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    fields
        .iter()
        .map(|&f| {
            let u = field_direction(f.resolved(lens, &para, aim)?.tangents_f64(lens, &para)?);
            let p0 = chief_point(lens, sys, f, lens.primary_wavelength_nm, aim)?;
            wavelengths_nm
                .iter()
                .map(|&wl| {
                    let p = chief_point(lens, sys, f, wl, aim)?;
                    Ok(((p[0] - p0[0]) * u[0] + (p[1] - p0[1]) * u[1]) * 1e3)
                })
                .collect()
        })
        .collect()
}

/// Pupil grid side of [`relative_illumination`].
pub const ILLUMINATION_GRID: usize = 64;

/// Relative illumination at each of `fields` at `wavelength_nm`: the irradiance at the chief
/// ray's image point over that on axis, for a Lambertian object (see the module's conventions),
/// from a [`ILLUMINATION_GRID`]² grid over the pupil with apertures clipping.
///
/// The flux a field element sends through the lens is the radiance times the object-space
/// étendue of the rays that get through: for an object at infinity their beam's cross-section
/// (normal to the beam) times the solid angle of the field element, `cos³ θ` per unit of
/// tangent-plane area; for a finite object the object area times the projected solid angle of
/// the rays (the area their direction cosines cover). Both areas come from an affine fit of the
/// rays' launch positions (or directions) to their pupil coordinates times the fraction of rays
/// that get through. The flux lands on the image area the chief rays map the field element to
/// (the Jacobian of the chief ray's image point against the field tangents, by central
/// differences): vignetting, the pupil's own aberrations (with ray aiming) and distortion are
/// all in it, and field curvature is not (the flux is the same wherever the beam focuses). A
/// thin lens without vignetting gives `cos⁴ θ`.
///
/// # Errors
/// [`crate::ErrorKind::Numerical`] when no ray of a field gets through or its chief ray misses
/// the image; ray-generation errors.
///
/// # Examples
/// ```
/// use tolray::analysis::aberrations::relative_illumination;
/// use tolray::trace::Field;
/// let lens = tolray::Lens::load("cooke-triplet")?;
/// let ri = relative_illumination(&lens, &lens.compile(), &[Field::fraction(0.0), Field::fraction(1.0)],
///                                587.5618, false)?;
/// assert!((ri[0] - 1.0).abs() < 1e-12 && ri[1] < 1.0 && ri[1] > 0.2);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn relative_illumination(
    lens: &Lens,
    sys: &System<f64>,
    fields: &[Field],
    wavelength_nm: f64,
    aim: bool,
) -> Result<Vec<f64>> {
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    let (pts, _) = Sampling::Grid(ILLUMINATION_GRID).points();
    let irradiance = |f: Field| -> Result<f64> {
        let what = || format!("relative illumination at field {}", f.label());
        let set = RaySet::generate_at(lens, &para, f, &pts, aim, wavelength_nm)?;
        let mut batch = set.batch::<f64>();
        trace::trace(sys, wavelength_nm, &mut batch, TraceOptions::default());
        let alive: Vec<usize> = (0..pts.len())
            .filter(|&i| batch.get(i).status.is_alive())
            .collect();
        if alive.len() < 3 {
            return Err(Error::numerical(format!(
                "{}: {} of {} rays get through",
                what(),
                alive.len(),
                pts.len()
            )));
        }
        let at: Vec<[f64; 2]> = alive.iter().map(|&i| set.pupil[i]).collect();
        let w = vec![1.0; alive.len()];
        // The area (in the plane of `a`, `b`) the rays cover, from affine slopes over the pupil.
        let area = |a: &dyn Fn(usize) -> f64, b: &dyn Fn(usize) -> f64| -> Result<f64> {
            let fit = |g: &dyn Fn(usize) -> f64| -> Result<[f64; 2]> {
                let v: Vec<f64> = alive.iter().map(|&i| g(i)).collect();
                let c = zernike::fit(zernike::Ordering::Standard, 3, &at, &v, &w)?.coefficients;
                Ok([2.0 * c[1], 2.0 * c[2]])
            };
            let (ga, gb) = (fit(a)?, fit(b)?);
            let det = (ga[0] * gb[1] - ga[1] * gb[0]).abs();
            Ok(det * std::f64::consts::PI * alive.len() as f64 / pts.len() as f64)
        };
        let q = f.resolved(lens, &para, aim)?.tangents_f64(lens, &para)?;
        let etendue = match lens.object {
            Object::Infinite => {
                // The beam's cross-section normal to its direction, times cos³ θ.
                let d = set.chief.1;
                let e1 = if d.x.abs() < 0.9 {
                    crate::math::Vec3::cst(1.0, 0.0, 0.0)
                } else {
                    crate::math::Vec3::cst(0.0, 1.0, 0.0)
                };
                let u = (e1 - d * e1.dot(d)).normalized();
                let v = d.cross(u);
                let o = &set.origins;
                let cos = 1.0 / (1.0 + q.0 * q.0 + q.1 * q.1).sqrt();
                area(&|i| o[i].dot(u), &|i| o[i].dot(v))? * cos.powi(3)
            }
            Object::Finite { .. } => {
                let d = &set.directions;
                area(&|i| d[i].x, &|i| d[i].y)?
            }
        };
        // The image area per unit of field tangent: the chief rays' Jacobian.
        let e = 1e-6 * (1.0 + q.0.hypot(q.1));
        let image = |dx: f64, dy: f64| {
            chief_point(
                lens,
                sys,
                Field::of_tangents(lens, [q.0 + dx, q.1 + dy]),
                wavelength_nm,
                aim,
            )
        };
        let (xp, xm, yp, ym) = (
            image(e, 0.0)?,
            image(-e, 0.0)?,
            image(0.0, e)?,
            image(0.0, -e)?,
        );
        let j = [
            [(xp[0] - xm[0]) / (2.0 * e), (yp[0] - ym[0]) / (2.0 * e)],
            [(xp[1] - xm[1]) / (2.0 * e), (yp[1] - ym[1]) / (2.0 * e)],
        ];
        let det = (j[0][0] * j[1][1] - j[0][1] * j[1][0]).abs();
        let out = etendue / det;
        if !(out > 0.0) || !out.is_finite() {
            return Err(Error::numerical(format!(
                "{}: the chief rays do not map the field to an image area (afocal?)",
                what()
            )));
        }
        Ok(out)
    };
    let axis = irradiance(Field::fraction(0.0))?;
    fields.iter().map(|&f| Ok(irradiance(f)? / axis)).collect()
}

/// The ray and OPD fans of one field and wavelength.
#[derive(Clone, Debug, Serialize)]
pub struct Fan {
    /// The field.
    pub field: Field,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// Normalised pupil coordinates along the fan, −1 to 1.
    pub pupil: Vec<f64>,
    /// Transverse ray error along the tangential direction, µm (NaN where vignetted; JSON
    /// null).
    pub tangential_um: Vec<f64>,
    /// Transverse ray error along the sagittal direction, µm.
    pub sagittal_um: Vec<f64>,
    /// OPD along the tangential fan, waves.
    pub opd_tangential_waves: Vec<f64>,
    /// OPD along the sagittal fan, waves.
    pub opd_sagittal_waves: Vec<f64>,
}

/// Ray and OPD fans of `field` at `wavelength_nm` over `n` pupil points from −1 to 1, ray errors
/// relative to the chief ray of the primary wavelength (see the module's conventions).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for fewer than 3 points or more than
/// [`crate::wave::MAX_SAMPLES`]; as [`crate::wave::wavefront`].
///
/// # Examples
/// ```
/// use tolray::analysis::aberrations::fans;
/// use tolray::trace::Field;
/// let lens = tolray::Lens::load("cooke-triplet")?;
/// let f = fans(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, 21, &Default::default())?;
/// // On axis the fans are odd (ray errors) and even (OPD) in the pupil coordinate (the rim's
/// // rays, which the aperture clips, are NaN).
/// assert!((f.tangential_um[2] + f.tangential_um[18]).abs() < 1e-6);
/// assert!((f.opd_tangential_waves[2] - f.opd_tangential_waves[18]).abs() < 1e-6);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn fans(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    n: usize,
    opts: &WaveOptions,
) -> Result<Fan> {
    if !(3..=wave::MAX_SAMPLES).contains(&n) {
        return Err(Error::argument(format!(
            "{n} fan points: give 3 to {}",
            wave::MAX_SAMPLES
        )));
    }
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    let t = field_direction(
        field
            .resolved(lens, &para, opts.aim)?
            .tangents_f64(lens, &para)?,
    );
    let s = [t[1], -t[0]];
    let reference = chief_point(lens, sys, field, lens.primary_wavelength_nm, opts.aim)?;
    let pupil: Vec<f64> = (0..n)
        .map(|i| -1.0 + 2.0 * i as f64 / (n - 1) as f64)
        .collect();
    let line = |u: [f64; 2]| -> Result<(Vec<f64>, Vec<f64>)> {
        let pts: Vec<[f64; 2]> = pupil.iter().map(|&p| [p * u[0], p * u[1]]).collect();
        let w = wave::wavefront_at(lens, sys, field, wavelength_nm, &pts, &vec![1.0; n], opts)?;
        let (mut err, mut opd) = (vec![f64::NAN; n], vec![f64::NAN; n]);
        for (k, &i) in w.ray_index.iter().enumerate() {
            let p = w.image_points[k];
            err[i] = ((p[0] - reference[0]) * u[0] + (p[1] - reference[1]) * u[1]) * 1e3;
            opd[i] = w.opd_waves[k];
        }
        Ok((err, opd))
    };
    let (tangential_um, opd_tangential_waves) = line(t)?;
    let (sagittal_um, opd_sagittal_waves) = line(s)?;
    Ok(Fan {
        field,
        wavelength_nm,
        pupil,
        tangential_um,
        sagittal_um,
        opd_tangential_waves,
        opd_sagittal_waves,
    })
}

impl Field {
    /// The field's object-side tangents (as the launch uses them) in f64.
    pub(crate) fn tangents_f64(
        &self,
        lens: &Lens,
        para: &crate::lens::Paraxial,
    ) -> Result<(f64, f64)> {
        self.tangents(lens, &LaunchOptics::of(para))
    }
}
