//! Ray generation: fields, pupil sampling over the paraxial entrance pupil, optional real ray
//! aiming at the stop.

use super::reference::trace_ray;
use super::{RayBatch, LANES};
use crate::error::{Error, Result};
use crate::lens::paraxial::{launch_optics, LaunchOptics};
use crate::lens::{Adjustments, Lens, Object, Param, Paraxial, System};
use crate::math::Vec3;
use crate::real::Real;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

pub use crate::lens::field::{Field, FieldPoint, Vignetting};

impl Field {
    /// The field to launch for this one: a [`Field::RealImageHeightMm`] becomes the angle
    /// (object at infinity) or object height (finite object) whose real chief ray at the primary
    /// wavelength meets the image plane at that height (in the plane's frame, to 1e-10 mm
    /// relative), through the centre of the field's vignetted paraxial pupil, or with `aim` of
    /// the real stop; other fields are returned as they are. Newton's method from the paraxial
    /// image height's field, with a finite-difference Jacobian (x and y solved together, so a
    /// decentred or tilted system is solved too).
    ///
    /// ```
    /// use tolray::trace::Field;
    /// let mut lens = tolray::Lens::load("cooke-triplet").unwrap();
    /// lens.object = tolray::Object::Infinite;
    /// let para = lens.paraxial(lens.primary_wavelength_nm).unwrap();
    /// let f = Field::RealImageHeightMm { x: 0.0, y: 15.0 }.resolved(&lens, &para, false).unwrap();
    /// let Field::AngleDeg { y, .. } = f else { panic!() };
    /// assert!(y < -15.0 && y > -25.0); // the object below the axis, image above it
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Numerical`] when no chief ray reaches the height.
    pub fn resolved(self, lens: &Lens, para: &Paraxial, aim: bool) -> Result<Field> {
        let Field::RealImageHeightMm { x, y } = self else {
            return Ok(self);
        };
        let fail =
            |why: &str| Error::numerical(format!("real image height field ({x}, {y}) mm: {why}"));
        if !(x.is_finite() && y.is_finite()) {
            return Err(fail("not finite"));
        }
        let optics = LaunchOptics::of(para);
        let field_of = |q: [f64; 2]| Field::of_tangents(lens, q);
        let sys = lens.compile();
        let wl = lens.primary_wavelength_nm;
        let n = sys.indices(wl);
        let stop = para.stop_surface;
        let r_stop = lens.surfaces[stop].semi_aperture_mm;
        let centre = lens.vignetting_of(self).apply([0.0, 0.0]);
        // The chief ray's point on the image plane, in the plane's frame.
        let image_point = |q: [f64; 2]| -> Option<[f64; 2]> {
            let beam = Beam::launch(lens, &optics, field_of(q)).ok()?;
            let (o, d) = if aim {
                let make = |px: f64, py: f64| beam.ray(px, py);
                let c0 = [centre[0] * beam.r_ep, centre[1] * beam.r_ep];
                let target = [centre[0] * r_stop, centre[1] * r_stop];
                let e = aim_ray(&sys, &n, wl, stop, &make, target, c0).ok()?;
                make(e[0], e[1])
            } else {
                beam.at_pupil(centre)
            };
            let r = trace_ray(&sys, &n, wl, o, d, false, None);
            if !r.status.is_alive() {
                return None;
            }
            let p = sys.image.point_to_local(r.o);
            (p.x.is_finite() && p.y.is_finite()).then_some([p.x, p.y])
        };
        let (tx, ty) = Field::ImageHeightMm { x, y }.tangents(lens, &optics)?;
        let mut q = [tx, ty];
        let mut f = image_point(q).ok_or_else(|| {
            fail("the chief ray of its paraxial field does not reach the image plane")
        })?;
        let tol = 1e-10 * x.abs().max(y.abs()).max(1.0);
        for _ in 0..50 {
            let r = [f[0] - x, f[1] - y];
            if r[0].abs().max(r[1].abs()) < tol {
                return Ok(field_of(q));
            }
            // Forward differences, stepping the other way when a ray misses.
            let column = |i: usize| -> Option<[f64; 2]> {
                let h = 1e-7 * (1.0 + q[i].abs());
                for step in [h, -h] {
                    let mut p = q;
                    p[i] += step;
                    if let Some(g) = image_point(p) {
                        return Some([(g[0] - f[0]) / step, (g[1] - f[1]) / step]);
                    }
                }
                None
            };
            let (Some(jx), Some(jy)) = (column(0), column(1)) else {
                return Err(fail("the chief rays next to the solution miss a surface"));
            };
            let (a, b, c, d) = (jx[0], jy[0], jx[1], jy[1]);
            let det = a * d - b * c;
            if !(det.abs() > 1e-300) {
                return Err(fail("the image height does not change with the field"));
            }
            let step = [(d * r[0] - b * r[1]) / det, (a * r[1] - c * r[0]) / det];
            // Damped: halve the step while its chief ray misses.
            let mut t = 1.0;
            loop {
                let p = [q[0] - t * step[0], q[1] - t * step[1]];
                if let Some(g) = image_point(p) {
                    (q, f) = (p, g);
                    break;
                }
                t *= 0.5;
                if t < 1e-9 {
                    return Err(fail(
                        "no chief ray reaches it (rays on the way miss a surface)",
                    ));
                }
            }
        }
        Err(fail("Newton's method did not converge in 50 steps"))
    }

    /// The field at object-side tangents `q` (as [`Field::tangents`] gives them): an angle for
    /// an object at infinity, an object height for a finite one (`q` itself for an object on
    /// the first vertex's plane).
    pub(crate) fn of_tangents(lens: &Lens, q: [f64; 2]) -> Field {
        match lens.object {
            Object::Infinite => Field::AngleDeg {
                x: q[0].atan().to_degrees(),
                y: q[1].atan().to_degrees(),
            },
            Object::Finite { distance_mm: 0.0 } => Field::HeightMm { x: q[0], y: q[1] },
            Object::Finite { distance_mm } => Field::HeightMm {
                x: q[0] * distance_mm,
                y: q[1] * distance_mm,
            },
        }
    }

    /// Field angles (tan x, tan y) seen from the first vertex for a lens with the first-order
    /// numbers `o` (the focal length turns a fraction of the field into an angle, the chief
    /// ray's image height an image height), in any number type. A real image height must be
    /// resolved first ([`Field::resolved`]). For an object on the first vertex's plane (object
    /// distance 0), which no angle about that vertex locates, the object height in mm instead.
    pub(crate) fn tangents<S: Real>(&self, lens: &Lens, o: &LaunchOptics<S>) -> Result<(S, S)> {
        let on_vertex = lens.object == (Object::Finite { distance_mm: 0.0 });
        if on_vertex && matches!(self, Field::AngleDeg { .. } | Field::Fraction { .. }) {
            return Err(Error::argument(format!(
                "field {}: the object is on the first vertex's plane (object distance 0), where a \
                 field angle about that vertex names no object point; give the field as an object \
                 height (2.5mm) or an image height (14mm@image)",
                self.label()
            )));
        }
        let (tx, ty) = match *self {
            Field::AngleDeg { x, y } => {
                // tan flips sign past 90°: a field there is not a direction toward the lens.
                if !(x.abs() < 90.0 && y.abs() < 90.0) {
                    return Err(Error::argument(format!(
                        "field angle ({x}°, {y}°): each angle must be finite and below 90° in \
                         magnitude"
                    )));
                }
                (S::cst(x.to_radians().tan()), S::cst(y.to_radians().tan()))
            }
            Field::Fraction { x, y } => {
                // An afocal lens' image is at infinity: no sensor height but the centre is a
                // field angle.
                if o.afocal {
                    if x == 0.0 && y == 0.0 {
                        return Ok((S::cst(0.0), S::cst(0.0)));
                    }
                    return Err(Error::numerical(format!(
                        "field {x},{y} (a fraction of the sensor's half-diagonal): the lens is \
                         afocal (no focal length turns a height on the sensor into a field \
                         angle); give the field as an angle (5deg) or an object height"
                    )));
                }
                let t = S::cst(lens.sensor.half_diagonal_mm()) / o.efl_mm;
                (S::cst(x) * t, S::cst(y) * t)
            }
            Field::HeightMm { x, y } => match lens.object {
                Object::Finite { distance_mm: 0.0 } => (S::cst(x), S::cst(y)),
                Object::Finite { distance_mm } => {
                    (S::cst(x / distance_mm), S::cst(y / distance_mm))
                }
                Object::Infinite => {
                    return Err(Error::argument(
                        "an object height field needs a finite object distance",
                    ))
                }
            },
            Field::ImageHeightMm { x, y } => {
                let k = o.chief_image_height_mm;
                if !(k.value().abs() > 1e-300 && k.value().is_finite()) {
                    return Err(Error::numerical(format!(
                        "image height field ({x}, {y}) mm: the paraxial chief ray does not reach \
                         the image plane at a finite height (an afocal or telecentric-in-object \
                         space lens has no image height field)"
                    )));
                }
                match lens.object {
                    // Slope u = h / k rises; tolray's tangent names the object's side: -u.
                    Object::Infinite => (S::cst(-x) / k, S::cst(-y) / k),
                    Object::Finite { distance_mm: 0.0 } => (S::cst(x) / k, S::cst(y) / k),
                    // Object height h / k, at the object distance d.
                    Object::Finite { distance_mm } => {
                        let d = S::cst(distance_mm);
                        (S::cst(x) / (k * d), S::cst(y) / (k * d))
                    }
                }
            }
            Field::RealImageHeightMm { x, y } => {
                return Err(Error::argument(format!(
                    "real image height field ({x}, {y}) mm has no launch of its own: it is solved \
                     for the field that reaches it first"
                )))
            }
        };
        if on_vertex {
            let h = tx.value().hypot(ty.value());
            if !(h <= MAX_OBJECT_HEIGHT_MM) {
                return Err(Error::argument(format!(
                    "field {}: an object height of {h:e} mm on the first vertex's plane; give at \
                     most {MAX_OBJECT_HEIGHT_MM:e} mm",
                    self.label()
                )));
            }
            return Ok((tx, ty));
        }
        // A direction toward the lens: beyond this the beam's z component (below 1e-6) leaves
        // the launch geometry to rounding, and its squares overflow long before 1e300.
        let t = tx.value().hypot(ty.value());
        if !(t <= MAX_FIELD_TANGENT) {
            return Err(Error::argument(format!(
                "field {}: its chief ray leaves the object {} from the axis (tangent {t:e}); a \
                 field is a direction toward the lens, at most {:.4}° from the axis",
                self.label(),
                if t.is_finite() {
                    format!("{:.6}°", t.atan().to_degrees())
                } else {
                    "at 90°".into()
                },
                MAX_FIELD_TANGENT.atan().to_degrees()
            )));
        }
        Ok((tx, ty))
    }
}

/// Largest tangent of a field's chief ray to the axis that is launched (89.99994°).
pub(crate) const MAX_FIELD_TANGENT: f64 = 1e6;

/// Largest object height launched from the first vertex's plane (object distance 0), mm: as
/// [`MAX_FIELD_TANGENT`] bounds a tangent, so that the launch's squares stay far from overflow.
const MAX_OBJECT_HEIGHT_MM: f64 = 1e6;

/// How the entrance pupil is sampled.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum PupilPattern {
    /// Cell-centred `n x n` square grid, points kept inside the disk.
    Grid(usize),
    /// Hexapolar: the centre plus rings 1..=n, ring k holding 6k points.
    Hex(usize),
    /// `n` uniform random points over the disk area, seeded.
    Random {
        /// Number of points.
        n: usize,
        /// Seed.
        seed: u64,
    },
}

/// Pupil sampling: a pattern over a disk of `scale` times the paraxial entrance-pupil radius,
/// optionally with real ray aiming at the stop.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pupil {
    /// Point pattern.
    pub pattern: PupilPattern,
    /// Radius of the sampled disk relative to the paraxial entrance pupil.
    pub scale: f64,
    /// Aim each ray so that it crosses the real stop at the pattern point scaled to the stop
    /// radius (instead of aiming at the paraxial entrance pupil).
    pub aim: bool,
}

/// Most rays a pupil pattern may hold (2^22 ≈ 4.2 M): a field's ray set then takes about 200 MB
/// in f64, so a typo such as `grid:100000` (10^10 rays) is refused instead of aborting the
/// process on allocation.
pub const MAX_PUPIL_RAYS: usize = 1 << 22;

impl PupilPattern {
    /// Number of points the pattern generates, at most (saturating; the grid keeps only the
    /// points inside the disk, about π/4 of n²).
    pub fn max_points(&self) -> usize {
        match *self {
            PupilPattern::Grid(n) => n.saturating_mul(n),
            PupilPattern::Hex(r) => r
                .saturating_mul(r.saturating_add(1))
                .saturating_mul(3)
                .saturating_add(1),
            PupilPattern::Random { n, .. } => n,
        }
    }

    /// Checks that the pattern is not empty and holds at most [`MAX_PUPIL_RAYS`] rays.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] saying the count and the limit.
    pub fn check(&self) -> Result<()> {
        let n = self.max_points();
        let zero = match *self {
            PupilPattern::Grid(k) | PupilPattern::Hex(k) => k == 0,
            PupilPattern::Random { n, .. } => n == 0,
        };
        if zero {
            return Err(Error::argument(format!(
                "pupil pattern {self:?} has no rays"
            )));
        }
        if n > MAX_PUPIL_RAYS {
            return Err(Error::argument(format!(
                "pupil pattern {self:?} would trace {n} rays per field; at most {MAX_PUPIL_RAYS} are allowed"
            )));
        }
        Ok(())
    }
}

impl Pupil {
    /// A `n x n` grid over the paraxial entrance pupil, no aiming.
    pub fn grid(n: usize) -> Pupil {
        Pupil {
            pattern: PupilPattern::Grid(n),
            scale: 1.0,
            aim: false,
        }
    }
    /// Parses `grid:64`, `hex:8` or `random:1000` (seeded by `seed`).
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] naming the text.
    pub fn parse(s: &str, seed: u64) -> Result<Pupil> {
        let bad = || Error::argument(format!("pupil \"{s}\": expected grid:N, hex:N or random:N"));
        let (kind, n) = s.split_once(':').ok_or_else(bad)?;
        let n: usize = n.trim().parse().map_err(|_| bad())?;
        let pattern = match kind.trim() {
            "grid" => PupilPattern::Grid(n),
            "hex" => PupilPattern::Hex(n),
            "random" => PupilPattern::Random { n, seed },
            _ => return Err(bad()),
        };
        pattern
            .check()
            .map_err(|e| e.context(format!("pupil \"{s}\"")))?;
        Ok(Pupil {
            pattern,
            scale: 1.0,
            aim: false,
        })
    }

    /// Normalized pupil points (unit disk times `scale`).
    pub fn points(&self) -> Vec<[f64; 2]> {
        let s = self.scale;
        match self.pattern {
            PupilPattern::Grid(n) => {
                let mut pts = Vec::with_capacity(n * n);
                for j in 0..n {
                    for i in 0..n {
                        let x = (2 * i + 1) as f64 / n as f64 - 1.0;
                        let y = (2 * j + 1) as f64 / n as f64 - 1.0;
                        if x * x + y * y <= 1.0 {
                            pts.push([x * s, y * s]);
                        }
                    }
                }
                pts
            }
            PupilPattern::Hex(rings) => {
                let mut pts = vec![[0.0, 0.0]];
                for k in 1..=rings {
                    let r = k as f64 / rings as f64 * s;
                    for m in 0..6 * k {
                        let a = std::f64::consts::TAU * m as f64 / (6 * k) as f64;
                        pts.push([r * a.cos(), r * a.sin()]);
                    }
                }
                pts
            }
            PupilPattern::Random { n, seed } => {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                (0..n)
                    .map(|_| {
                        let r = rng.random::<f64>().sqrt() * s;
                        let a = std::f64::consts::TAU * rng.random::<f64>();
                        [r * a.cos(), r * a.sin()]
                    })
                    .collect()
            }
        }
    }
}

impl Pupil {
    /// The number of chunks [`Pupil::chunk_points`] splits the pattern into: rows of a grid, runs
    /// of [`super::CHUNK_RAYS`] points otherwise. A function of the pattern alone, so work spread
    /// over chunks gives the same results at any thread count.
    pub fn chunks(&self) -> usize {
        match self.pattern {
            PupilPattern::Grid(n) => n.div_ceil(grid_rows_per_chunk(n)),
            _ => self.pattern.max_points().div_ceil(super::CHUNK_RAYS),
        }
    }

    /// Writes the points of chunk `k` (of [`Pupil::chunks`]) into `out` (cleared first): chunk
    /// after chunk, the points of [`Pupil::points`] in their order and with their numbers.
    ///
    /// # Examples
    /// ```
    /// use tolray::trace::Pupil;
    /// for text in ["grid:300", "hex:60", "random:9000"] {
    ///     let pupil = Pupil::parse(text, 7)?;
    ///     let mut all = Vec::new();
    ///     let mut chunk = Vec::new();
    ///     for k in 0..pupil.chunks() {
    ///         pupil.chunk_points(k, &mut chunk);
    ///         all.extend_from_slice(&chunk);
    ///     }
    ///     assert_eq!(all, pupil.points());
    /// }
    /// # Ok::<(), tolray::Error>(())
    /// ```
    pub fn chunk_points(&self, k: usize, out: &mut Vec<[f64; 2]>) {
        out.clear();
        let s = self.scale;
        match self.pattern {
            PupilPattern::Grid(n) => {
                let rows = grid_rows_per_chunk(n);
                for j in (k * rows).min(n)..((k + 1) * rows).min(n) {
                    for i in 0..n {
                        let x = (2 * i + 1) as f64 / n as f64 - 1.0;
                        let y = (2 * j + 1) as f64 / n as f64 - 1.0;
                        if x * x + y * y <= 1.0 {
                            out.push([x * s, y * s]);
                        }
                    }
                }
            }
            PupilPattern::Hex(rings) => {
                let total = self.pattern.max_points();
                let start = (k * super::CHUNK_RAYS).min(total);
                let end = ((k + 1) * super::CHUNK_RAYS).min(total);
                for idx in start..end {
                    if idx == 0 {
                        out.push([0.0, 0.0]);
                        continue;
                    }
                    // Ring k holds the points 3k(k-1)+1 .. 3k(k+1).
                    let mut ring = ((idx as f64 / 3.0).sqrt() as usize).max(1);
                    while 3 * ring * (ring + 1) < idx {
                        ring += 1;
                    }
                    while ring > 1 && 3 * ring * (ring - 1) >= idx {
                        ring -= 1;
                    }
                    let m = idx - (3 * ring * (ring - 1) + 1);
                    let r = ring as f64 / rings as f64 * s;
                    let a = std::f64::consts::TAU * m as f64 / (6 * ring) as f64;
                    out.push([r * a.cos(), r * a.sin()]);
                }
            }
            PupilPattern::Random { n, seed } => {
                let start = (k * super::CHUNK_RAYS).min(n);
                let end = ((k + 1) * super::CHUNK_RAYS).min(n);
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                // Each point takes two f64 draws of two 32-bit words each.
                rng.set_word_pos(4 * start as u128);
                for _ in start..end {
                    let r = rng.random::<f64>().sqrt() * s;
                    let a = std::f64::consts::TAU * rng.random::<f64>();
                    out.push([r * a.cos(), r * a.sin()]);
                }
            }
        }
    }
}

/// Grid rows per chunk of an `n x n` grid: about [`super::CHUNK_RAYS`] points, at least a row.
fn grid_rows_per_chunk(n: usize) -> usize {
    (super::CHUNK_RAYS / n.max(1)).max(1)
}

/// The rays of one field: origins and directions in the global frame, plus the chief ray.
#[derive(Clone, Debug)]
pub struct RaySet {
    /// Ray origins, mm.
    pub origins: Vec<Vec3<f64>>,
    /// Ray directions (unit).
    pub directions: Vec<Vec3<f64>>,
    /// Normalized pupil coordinates of each ray.
    pub pupil: Vec<[f64; 2]>,
    /// The chief ray (through the pupil centre).
    pub chief: (Vec3<f64>, Vec3<f64>),
    /// The field the rays belong to.
    pub field: Field,
    /// With ray aiming: the stop surface and the rays that cannot reach their point of the stop
    /// (every nearby ray misses a surface before it). [`RaySet::batch`] marks them vignetted at
    /// the stop; without aiming, empty.
    pub unreachable: Option<(usize, Vec<usize>)>,
}

impl RaySet {
    /// Generates the rays of `field` through `pupil` at `wavelength_nm` (used for aiming only).
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for an object-height field at infinity or a pupil pattern
    /// with no ray or more than [`MAX_PUPIL_RAYS`] (checked before anything is allocated);
    /// [`crate::ErrorKind::Numerical`] when ray aiming fails to converge.
    pub fn generate(
        lens: &Lens,
        para: &Paraxial,
        field: Field,
        pupil: &Pupil,
        wavelength_nm: f64,
    ) -> Result<RaySet> {
        pupil.pattern.check()?;
        Self::generate_at(lens, para, field, &pupil.points(), pupil.aim, wavelength_nm)
    }

    /// As [`RaySet::generate`], through the normalized pupil points `pts` of a [`Pupil`]
    /// (computed once when many fields share one pupil).
    ///
    /// # Errors
    /// As [`RaySet::generate`].
    pub fn generate_at(
        lens: &Lens,
        para: &Paraxial,
        field: Field,
        pts: &[[f64; 2]],
        aim: bool,
        wavelength_nm: f64,
    ) -> Result<RaySet> {
        let launcher = Launcher::new(lens, para, field, aim, wavelength_nm)?;
        let pts = launcher.vignetted(pts);
        let mut set = RaySet {
            origins: Vec::with_capacity(pts.len()),
            directions: Vec::with_capacity(pts.len()),
            // Filled with `pts` at the end (one copy of the pupil points, not two).
            pupil: Vec::new(),
            chief: launcher.chief,
            field,
            unreachable: None,
        };
        let mut lost = Vec::new();
        for (i, q) in pts.iter().enumerate() {
            let ((o, d), reached) = launcher.ray(*q);
            if !reached {
                lost.push(i);
            }
            set.origins.push(o);
            set.directions.push(d);
        }
        if let Some(a) = &launcher.aiming {
            set.unreachable = Some((a.stop, lost));
        }
        set.pupil = pts;
        Ok(set)
    }

    /// The rays as a batch in number type `S` (the directions are already unit vectors).
    pub fn batch<S: Real>(&self) -> RayBatch<S> {
        let mut b = RayBatch::from_unit_rays(&self.origins, &self.directions);
        if let Some((stop, lost)) = &self.unreachable {
            b.set_status(lost, super::RayStatus::Vignetted(*stop as u32));
        }
        b
    }

    /// The rays as a batch in `S`, launched again from `optics` (the first-order numbers of the
    /// design they were generated from, for `lens`, as [`LaunchSource::optics`] gives them), and,
    /// with `chief`, the chief ray appended as [`RayBatch::push`] appends it. The numbers are
    /// those of [`RaySet::batch`] (and of the chief ray), bit for bit, now with the derivatives
    /// `optics` carries: the entrance pupil's position and size and the field angle of a
    /// fraction of the field or a paraxial image height move with the design. `None`, aimed
    /// rays (whose aim is not differentiated) and a real image height (whose field solve is
    /// not) give the stored rays: the launch is then held.
    pub fn launched_batch<S: Real>(
        &self,
        lens: &Lens,
        optics: Option<&LaunchOptics<S>>,
        chief: bool,
    ) -> RayBatch<S> {
        // The beam was built from these very numbers when the set was generated, so it builds
        // again; should it not, the stored rays are the launch's values.
        let beam = match optics {
            Some(o) if self.unreachable.is_none() => Beam::launch(lens, o, self.field).ok(),
            _ => None,
        };
        let Some(beam) = beam else {
            let mut b = self.batch();
            if chief {
                b.push(self.chief.0, self.chief.1);
            }
            return b;
        };
        let mut b = RayBatch::collect_unit(self.pupil.iter().map(|q| beam.at_pupil(*q)));
        if chief {
            let (o, d) = beam.at_pupil(lens.vignetting_of(self.field).apply([0.0, 0.0]));
            b.push_in(o, d);
        }
        b
    }
}

/// How the rays of one field are launched: its beam through the paraxial entrance pupil, the
/// field's vignetting factors and, with ray aiming, the aim at the real stop. Shared by
/// [`RaySet`] (every ray at once) and [`super::RayStream`] (a chunk at a time), so both launch
/// the same numbers.
pub(crate) struct Launcher {
    beam: Beam,
    vig: Vignetting,
    /// The chief ray.
    pub(crate) chief: (Vec3<f64>, Vec3<f64>),
    pub(crate) aiming: Option<Aiming>,
}

/// Real ray aiming at the stop: the nominal system, its indices, the stop and the chief ray's
/// offset from its paraxial guess (the first guess of every other ray).
pub(crate) struct Aiming {
    sys: System<f64>,
    n: Vec<f64>,
    wavelength_nm: f64,
    pub(crate) stop: usize,
    r_stop: f64,
    offset: [f64; 2],
}

impl Launcher {
    /// The launch of `field` (resolved, with `aim` at the real stop).
    ///
    /// # Errors
    /// As [`RaySet::generate`].
    pub(crate) fn new(
        lens: &Lens,
        para: &Paraxial,
        field: Field,
        aim: bool,
        wavelength_nm: f64,
    ) -> Result<Launcher> {
        // Every medium needs a usable index at the traced wavelength (the lens' own wavelengths
        // are checked by `Lens::validate`; an analysis may trace others, such as F and C).
        lens.check_indices(wavelength_nm)?;
        let launched = field.resolved(lens, para, aim)?;
        let beam = Beam::launch(lens, &LaunchOptics::of(para), launched)?;
        // The field point's vignetted pupil (the whole pupil for fields the lens does not list).
        let vig = lens.vignetting_of(field);
        let centre = vig.apply([0.0, 0.0]);
        let mut launcher = Launcher {
            chief: beam.at_pupil(centre),
            beam,
            vig,
            aiming: None,
        };
        if aim {
            let sys = lens.compile();
            let stop = para.stop_surface;
            let n = sys.indices(wavelength_nm);
            let r_stop = lens.surfaces[stop].semi_aperture_mm;
            let mut a = Aiming {
                sys,
                n,
                wavelength_nm,
                stop,
                r_stop,
                offset: [0.0; 2],
            };
            let r_ep = launcher.beam.r_ep;
            let c0 = [centre[0] * r_ep, centre[1] * r_ep];
            let c = launcher.aim(&a, [centre[0] * r_stop, centre[1] * r_stop], c0)?;
            launcher.chief = launcher.beam.ray(c[0], c[1]);
            a.offset = [c[0] - c0[0], c[1] - c0[1]];
            launcher.aiming = Some(a);
        }
        Ok(launcher)
    }

    /// The entrance-pupil point (mm) whose ray crosses the stop at `target` (mm).
    fn aim(&self, a: &Aiming, target: [f64; 2], guess: [f64; 2]) -> Result<[f64; 2]> {
        let make = |px: f64, py: f64| self.beam.ray(px, py);
        aim_ray(&a.sys, &a.n, a.wavelength_nm, a.stop, &make, target, guess)
    }

    /// The normalized pupil points `pts` moved into the field's vignetted pupil.
    pub(crate) fn vignetted(&self, pts: &[[f64; 2]]) -> Vec<[f64; 2]> {
        if self.vig.is_none() {
            pts.to_vec()
        } else {
            pts.iter().map(|&q| self.vig.apply(q)).collect()
        }
    }

    /// True when the field has no vignetting factors ([`Launcher::vignette`] is the identity).
    pub(crate) fn vignetted_is_none(&self) -> bool {
        self.vig.is_none()
    }

    /// The normalized pupil point `q` moved into the field's vignetted pupil.
    pub(crate) fn vignette(&self, q: [f64; 2]) -> [f64; 2] {
        self.vig.apply(q)
    }

    /// The ray through the (vignetted) normalized pupil point `q`, and whether it reaches its
    /// point of the stop: with aiming, a stop point no real ray reaches (those near it miss a
    /// surface first) gives the ray of its first guess, to be marked vignetted at the stop.
    pub(crate) fn ray(&self, q: [f64; 2]) -> ((Vec3<f64>, Vec3<f64>), bool) {
        let Some(a) = &self.aiming else {
            return (self.beam.at_pupil(q), true);
        };
        let r_ep = self.beam.r_ep;
        let guess = [a.offset[0] + q[0] * r_ep, a.offset[1] + q[1] * r_ep];
        match self.aim(a, [q[0] * a.r_stop, q[1] * a.r_stop], guess) {
            Ok(e) => (self.beam.ray(e[0], e[1]), true),
            Err(_) => (self.beam.ray(guess[0], guess[1]), false),
        }
    }
}

/// The design a set of rays was launched from, kept so that its rays can be launched again with
/// a design variable's effect on the launch (see [`RaySet::launched_batch`]): the exact
/// gradient of a loss whose rays are launched from the design being optimized.
#[derive(Clone, Debug)]
pub struct LaunchSource {
    /// The lens the rays were launched from.
    pub lens: Arc<Lens>,
    /// Wavelength of its paraxial data, nm.
    pub wavelength_nm: f64,
    /// Its aperture stop (held: which surface limits the beam is a discrete choice).
    pub stop: usize,
}

impl LaunchSource {
    /// The source of rays launched from `lens` with its paraxial analysis `para`.
    pub fn new(lens: &Lens, para: &Paraxial) -> LaunchSource {
        LaunchSource {
            lens: Arc::new(lens.clone()),
            wavelength_nm: para.wavelength_nm,
            stop: para.stop_surface,
        }
    }

    /// The launch's first-order numbers with each design parameter passed through `lift` (as
    /// [`System::compile`] passes them), or `None` when they carry no derivative (the stored
    /// rays are then the launch, exactly).
    pub fn optics<S: Real>(&self, lift: &dyn Fn(Param, S) -> S) -> Option<LaunchOptics<S>> {
        let o = launch_optics(&self.lens, self.wavelength_nm, self.stop, lift);
        (!o.is_constant()).then_some(o)
    }

    /// The design itself compiled with `lift` and no adjustment (the reference of a PSF
    /// similarity, which moves with the design too).
    pub fn design<S: Real>(&self, lift: &dyn Fn(Param, S) -> S) -> System<S> {
        System::compile(
            &self.lens,
            &Adjustments::none(self.lens.surfaces.len()),
            lift,
        )
    }
}

/// The rays of one field as a function of the point where they cross the paraxial entrance-pupil
/// plane, in number type `S` (`f64` to generate rays; dual numbers to carry the launch's
/// derivatives).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Beam<S = f64> {
    source: Source<S>,
    z_ep: S,
    /// Paraxial entrance-pupil radius, mm.
    pub(crate) r_ep: S,
}

#[derive(Clone, Copy, Debug)]
enum Source<S> {
    /// A finite object point.
    Point(Vec3<S>),
    /// A virtual object point behind the entrance pupil (a converging beam), and the start
    /// plane in front of the lens.
    Toward { q: Vec3<S>, z0: S },
    /// An object at infinity: the direction, and the distance back along it from the pupil
    /// plane to the start plane.
    Direction { d: Vec3<S>, back: S },
}

impl Beam {
    /// The beam of `field` (a real image height's chief ray through the paraxial pupil centre).
    ///
    /// # Errors
    /// As [`RaySet::generate`].
    pub(crate) fn new(lens: &Lens, para: &Paraxial, field: Field) -> Result<Beam> {
        let field = field.resolved(lens, para, false)?;
        Beam::launch(lens, &LaunchOptics::of(para), field)
    }

    /// The rays through the normalized pupil points `pts`, followed by the chief ray, written
    /// straight into an `f32` batch: the numbers of a [`RaySet`]'s batch, computed in `f64` a
    /// block at a time in lane loops that vectorize. A ray with non-finite numbers is stored as
    /// [`super::RayStatus::Invalid`] (zeros), as by [`RayBatch::push`].
    pub(crate) fn batch_f32(&self, pts: &[[f64; 2]]) -> RayBatch<f32> {
        let n = pts.len() + 1;
        let mut blocks = vec![super::Block::dead(); n.div_ceil(LANES)];
        beam_rays(self, pts, &mut blocks);
        RayBatch { blocks, len: n }
    }
}

impl<S: Real> Beam<S> {
    /// The beam of `field` for a lens with the first-order numbers `o`.
    ///
    /// # Errors
    /// As [`RaySet::generate`].
    pub(crate) fn launch(lens: &Lens, o: &LaunchOptics<S>, field: Field) -> Result<Beam<S>> {
        let (tx, ty) = field.tangents(lens, o)?;
        let z_ep = o.entrance_pupil_z_mm;
        // Rays start on a plane in front of the lens when they do not start at an object point
        // (a constant: moving the start along the ray changes no intersection).
        let start_plane = || {
            let s = &lens.surfaces[0];
            let sag = s.sag(s.semi_aperture_mm).unwrap_or(0.0).min(0.0);
            S::cst(z_ep.value().min(sag).min(0.0) - 1.0)
        };
        let source = match lens.object {
            // The object on the first vertex's plane: (tx, ty) are its heights, mm.
            Object::Finite { distance_mm: 0.0 } => {
                if !(z_ep.value() > 0.0) {
                    return Err(Error::invalid(format!(
                        "the object is on the first vertex's plane (object distance 0) and the \
                         entrance pupil is not behind it ({} mm from the first vertex): no beam \
                         leaves the object toward the pupil",
                        z_ep.value()
                    )));
                }
                Source::Point(Vec3::new(tx, ty, S::cst(0.0)))
            }
            Object::Finite { distance_mm } => {
                let q = Vec3::new(
                    S::cst(distance_mm) * tx,
                    S::cst(distance_mm) * ty,
                    S::cst(-distance_mm),
                );
                if distance_mm > 0.0 {
                    Source::Point(q)
                } else if q.z.value() > z_ep.value() {
                    // A virtual object: the rays converge toward it through the entrance pupil.
                    Source::Toward {
                        q,
                        z0: start_plane(),
                    }
                } else {
                    return Err(Error::invalid(format!(
                        "the virtual object ({} mm behind the first vertex) lies in front of the entrance pupil ({} mm): no beam converges on it through the pupil",
                        -distance_mm,
                        z_ep.value()
                    )));
                }
            }
            Object::Infinite => {
                let z0 = start_plane();
                let d = Vec3::new(-tx, -ty, S::cst(1.0)).normalized();
                Source::Direction {
                    d,
                    back: (z_ep - z0) / d.z,
                }
            }
        };
        Ok(Beam {
            source,
            z_ep,
            r_ep: o.entrance_pupil_radius_mm,
        })
    }

    /// The ray (origin, unit direction) through `(x, y)` (mm) on the entrance-pupil plane.
    #[inline(always)]
    pub(crate) fn ray(&self, x: S, y: S) -> (Vec3<S>, Vec3<S>) {
        let p = Vec3::new(x, y, self.z_ep);
        match self.source {
            Source::Point(q) => (q, (p - q).normalized()),
            Source::Toward { q, z0 } => {
                let d = (q - p).normalized();
                (p - d * ((p.z - z0) / d.z), d)
            }
            Source::Direction { d, back } => (p - d * back, d),
        }
    }

    /// The ray through the normalized pupil point `q` (unit disk).
    #[inline(always)]
    pub(crate) fn at_pupil(&self, q: [f64; 2]) -> (Vec3<S>, Vec3<S>) {
        self.ray(S::cst(q[0]) * self.r_ep, S::cst(q[1]) * self.r_ep)
    }
}

// Compiled for each instruction set, chosen at run time, like the kernel.
super::simd::isa_dispatch! {
    /// The rays of `beam` through the normalized pupil points `pts`, then the chief ray, into
    /// `out` (the numbers of [`Beam::ray`], rounded to `f32`); the lanes past the chief ray are
    /// dead, as in [`super::Block::dead`].
    fn beam_rays(beam: &Beam, pts: &[[f64; 2]], out: &mut [super::Block<f32>]) {
        let n = pts.len() + 1;
        for (b, blk) in out.iter_mut().enumerate() {
            // Entrance-pupil coordinates, mm; lanes past the pupil points hold the chief ray
            // (0, 0).
            let (mut px, mut py) = ([0.0f64; LANES], [0.0f64; LANES]);
            for (l, q) in pts.iter().skip(b * LANES).take(LANES).enumerate() {
                px[l] = q[0] * beam.r_ep;
                py[l] = q[1] * beam.r_ep;
            }
            let mut r = [[0.0f64; LANES]; 6];
            match beam.source {
                // As `ray`: (p - q) * (1 / |p - q|), origin q.
                Source::Point(q) => {
                    for l in 0..LANES {
                        let v = Vec3::new(px[l], py[l], beam.z_ep) - q;
                        let u = v * (1.0 / v.dot(v).sqrt());
                        (r[0][l], r[1][l], r[2][l]) = (q.x, q.y, q.z);
                        (r[3][l], r[4][l], r[5][l]) = (u.x, u.y, u.z);
                    }
                }
                // As `ray`: direction (q - p) / |q - p|, origin p - d (p.z - z0) / d.z.
                Source::Toward { q, z0 } => {
                    for l in 0..LANES {
                        let p = Vec3::new(px[l], py[l], beam.z_ep);
                        let v = q - p;
                        let u = v * (1.0 / v.dot(v).sqrt());
                        let o = p - u * ((beam.z_ep - z0) / u.z);
                        (r[0][l], r[1][l], r[2][l]) = (o.x, o.y, o.z);
                        (r[3][l], r[4][l], r[5][l]) = (u.x, u.y, u.z);
                    }
                }
                // As `ray`: origin p - d back, direction d.
                Source::Direction { d: u, back } => {
                    for l in 0..LANES {
                        let p = Vec3::new(px[l], py[l], beam.z_ep) - u * back;
                        (r[0][l], r[1][l], r[2][l]) = (p.x, p.y, p.z);
                        (r[3][l], r[4][l], r[5][l]) = (u.x, u.y, u.z);
                    }
                }
            }
            // Branch-free, so that the conversion vectorizes too. Lanes past the chief ray (l >= m)
            // and rays with non-finite numbers get zeros and the invalid status.
            let m = n.saturating_sub(b * LANES);
            for l in 0..LANES {
                let ok = r.iter().fold(l < m, |a, c| a & c[l].is_finite());
                for k in 0..3 {
                    blk.o[k][l] = if ok { r[k][l] as f32 } else { 0.0 };
                    blk.d[k][l] = if ok { r[3 + k][l] as f32 } else { 0.0 };
                }
                blk.status[l] = if ok { 0 } else { super::CODE_INVALID };
                blk.opl[l] = 0.0;
            }
        }
    }
}

/// Finds entrance-plane coordinates whose ray crosses the stop (in its own frame) at `target`,
/// by Newton's method with a finite-difference Jacobian on the reference tracer.
fn aim_ray(
    sys: &System<f64>,
    n: &[f64],
    wavelength_nm: f64,
    stop: usize,
    make: &dyn Fn(f64, f64) -> (Vec3<f64>, Vec3<f64>),
    target: [f64; 2],
    guess: [f64; 2],
) -> Result<[f64; 2]> {
    let at_stop = |e: [f64; 2]| -> Option<[f64; 2]> {
        let (o, d) = make(e[0], e[1]);
        let r = trace_ray(sys, n, wavelength_nm, o, d, false, Some(stop));
        if !r.status.is_alive() {
            return None;
        }
        let row = &sys.rows[stop];
        let p = row.rot.apply_t(r.o - row.pos);
        Some([p.x, p.y])
    };
    let mut e = guess;
    // The paraxial guess of a rim ray may miss a strongly curved surface before the stop: walk
    // in from the chief ray's guess until a ray gets through.
    let mut f = at_stop(e);
    for k in 1..=30 {
        if f.is_some() {
            break;
        }
        let s = 0.5f64.powi(k);
        e = [guess[0] * s, guess[1] * s];
        f = at_stop(e);
    }
    let mut f = f.ok_or_else(|| {
        Error::numerical("ray aiming: no ray near the paraxial pupil reaches the stop")
    })?;
    for _ in 0..40 {
        let r = [f[0] - target[0], f[1] - target[1]];
        // 0.1 nm at the stop: well above the trace's rounding (~1e-14 x 100 mm), far below any use.
        if r[0].abs().max(r[1].abs()) < 1e-10 {
            return Ok(e);
        }
        // Finite differences, stepping inwards when outwards misses.
        let diff = |i: usize| -> Option<[f64; 2]> {
            for h in [1e-6, -1e-6] {
                let mut q = e;
                q[i] += h;
                if let Some(g) = at_stop(q) {
                    return Some([(g[0] - f[0]) / h, (g[1] - f[1]) / h]);
                }
            }
            None
        };
        let (jx, jy) = match (diff(0), diff(1)) {
            (Some(x), Some(y)) => (x, y),
            _ => {
                return Err(Error::numerical(
                    "ray aiming: rays next to the aimed one miss",
                ))
            }
        };
        let (a, b, c, d) = (jx[0], jy[0], jx[1], jy[1]);
        let det = a * d - b * c;
        if det.abs() < 1e-300 {
            return Err(Error::numerical("ray aiming: singular pupil mapping"));
        }
        let step = [(d * r[0] - b * r[1]) / det, (a * r[1] - c * r[0]) / det];
        // Damped: halve the Newton step while the new ray misses a surface.
        let mut t = 1.0;
        loop {
            let q = [e[0] - t * step[0], e[1] - t * step[1]];
            if let Some(g) = at_stop(q) {
                e = q;
                f = g;
                break;
            }
            t *= 0.5;
            if t < 1e-9 {
                return Err(Error::numerical(
                    "ray aiming: the stop point cannot be reached (rays miss a surface before it)",
                ));
            }
        }
    }
    Err(Error::numerical("ray aiming did not converge"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Found by the fuzzer (examples/fuzz.rs): `hex:4294967296` overflowed the count to 0 in
    /// release builds, passed the check and generated rings for minutes.
    #[test]
    fn huge_pupil_patterns_are_refused_not_wrapped() {
        for s in [
            "hex:4294967296",
            "hex:18446744073709551615",
            "grid:4294967296",
            "hex:1182",
        ] {
            let e = Pupil::parse(s, 0).unwrap_err();
            assert!(e.message().contains("at most"), "{s}: {}", e.message());
        }
        assert!(Pupil::parse("hex:1181", 0).is_ok());
    }
}
