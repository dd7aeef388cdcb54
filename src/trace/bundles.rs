//! [`Bundles`]: the rays of each field × wavelength of an analysis, generated once from a design
//! lens (with each bundle's chief ray) and traced again through any perturbed or differentiated
//! system. Spot analysis in training, the Monte Carlo, PSFs and the Embree cross-check all hold
//! their rays in this one type.

use super::rays::{Field, LaunchSource, Pupil, RaySet};
use super::{trace_serial, RayBatch, TraceOptions, Traceable};
use crate::error::Result;
use crate::lens::paraxial::LaunchOptics;
use crate::lens::{Lens, Param, System};
use crate::math::Vec3;
use crate::real::Real;
use rayon::prelude::*;

/// The rays of one field at one wavelength.
#[derive(Clone, Debug)]
pub struct Bundle {
    /// Index of the field in the list the bundles were made from ([`Bundles::new`]; the pair's
    /// index for [`Bundles::pairs`]).
    pub field_index: usize,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// The rays (their field is `rays.field`), with the chief ray.
    pub rays: RaySet,
}

/// Rays of each field × wavelength, generated once in `f64` from a design lens and aimed at its
/// paraxial entrance pupil (at the launch wavelength the constructor names). The `launched_`
/// methods launch them again from the design with a gradient's seeded variables (see
/// [`crate::optim::Objective::eval`]); the others trace the stored rays.
///
/// # Examples
/// ```
/// use tolray::trace::{Bundles, Field, Pupil, TraceOptions};
/// let lens = tolray::lens::builtin("lens1").unwrap();
/// let fields = [Field::fraction(0.0), Field::fraction(1.0)];
/// let b = Bundles::new(&lens, &fields, &[486.1, 587.6], &Pupil::grid(8)).unwrap();
/// assert_eq!(b.len(), 4); // fields × wavelengths, field-major
/// assert_eq!((b.sets[3].field_index, b.sets[3].wavelength_nm), (1, 587.6));
/// let pts = b.sensor_points(&lens.compile(), 0, TraceOptions::default());
/// assert!(!pts.is_empty());
/// ```
#[derive(Clone, Debug)]
pub struct Bundles {
    /// The bundles, in the order the constructor lists.
    pub sets: Vec<Bundle>,
    /// The design the rays were launched from.
    pub launch: LaunchSource,
}

impl Bundles {
    /// Rays for every field and wavelength (field-major), launched from `lens`'s paraxial
    /// entrance pupil at the first wavelength (the lens' primary wavelength when there is none).
    ///
    /// # Errors
    /// Paraxial and ray-generation errors (the first bundle's in order).
    pub fn new(
        lens: &Lens,
        fields: &[Field],
        wavelengths_nm: &[f64],
        pupil: &Pupil,
    ) -> Result<Bundles> {
        let launch_nm = wavelengths_nm
            .first()
            .copied()
            .unwrap_or(lens.primary_wavelength_nm);
        let items = fields
            .iter()
            .enumerate()
            .flat_map(|(f, &field)| wavelengths_nm.iter().map(move |&wl| (f, field, wl)))
            .collect::<Vec<_>>();
        Self::build(lens, launch_nm, &items, pupil)
    }

    /// Rays for every field and wavelength (field-major) through the normalised entrance-pupil
    /// points `pts` (unit disk), launched from `lens`'s paraxial entrance pupil at its primary
    /// wavelength (as the wave analyses launch them), aimed at the real stop with `aim`.
    ///
    /// ```
    /// use tolray::trace::{Bundles, Field};
    /// let lens = tolray::lens::builtin("lens1").unwrap();
    /// let pts = [[0.0, 0.0], [0.5, 0.0], [0.0, -0.9]];
    /// let b = Bundles::at_points(&lens, &[Field::fraction(0.5)], &[587.6], &pts, false).unwrap();
    /// assert_eq!(b.ray_count(), 3);
    /// ```
    ///
    /// # Errors
    /// Paraxial and ray-generation errors (the first bundle's in order).
    pub fn at_points(
        lens: &Lens,
        fields: &[Field],
        wavelengths_nm: &[f64],
        pts: &[[f64; 2]],
        aim: bool,
    ) -> Result<Bundles> {
        let items = fields
            .iter()
            .enumerate()
            .flat_map(|(f, &field)| wavelengths_nm.iter().map(move |&wl| (f, field, wl)))
            .collect::<Vec<_>>();
        Self::build_at(lens, lens.primary_wavelength_nm, &items, pts, aim)
    }

    /// Rays for each (field, wavelength) pair (a PSF each), launched from `lens`'s paraxial
    /// entrance pupil at its primary wavelength; [`Bundle::field_index`] is the pair's index.
    ///
    /// # Errors
    /// Paraxial and ray-generation errors (the first pair's in order).
    pub fn pairs(lens: &Lens, pairs: &[(Field, f64)], pupil: &Pupil) -> Result<Bundles> {
        let items = pairs
            .iter()
            .enumerate()
            .map(|(k, &(field, wl))| (k, field, wl))
            .collect::<Vec<_>>();
        Self::build(lens, lens.primary_wavelength_nm, &items, pupil)
    }

    /// The bundles `(field index, field, wavelength)` through `pupil`, generated in parallel.
    fn build(
        lens: &Lens,
        launch_nm: f64,
        items: &[(usize, Field, f64)],
        pupil: &Pupil,
    ) -> Result<Bundles> {
        if !items.is_empty() {
            pupil.pattern.check()?;
        }
        Self::build_at(lens, launch_nm, items, &pupil.points(), pupil.aim)
    }

    /// The bundles `(field index, field, wavelength)` through the pupil points `pts`, generated
    /// in parallel.
    fn build_at(
        lens: &Lens,
        launch_nm: f64,
        items: &[(usize, Field, f64)],
        pts: &[[f64; 2]],
        aim: bool,
    ) -> Result<Bundles> {
        let para = lens.paraxial(launch_nm)?;
        let sets: Vec<Result<Bundle>> = items
            .par_iter()
            .map(|&(field_index, field, wl)| {
                let rays = RaySet::generate_at(lens, &para, field, pts, aim, wl)?;
                Ok(Bundle {
                    field_index,
                    wavelength_nm: wl,
                    rays,
                })
            })
            .collect();
        Ok(Bundles {
            sets: sets.into_iter().collect::<Result<_>>()?,
            launch: LaunchSource::new(lens, &para),
        })
    }

    /// Number of bundles.
    pub fn len(&self) -> usize {
        self.sets.len()
    }

    /// True if there is no bundle.
    pub fn is_empty(&self) -> bool {
        self.sets.is_empty()
    }

    /// Number of rays over all bundles (chief rays not counted).
    pub fn ray_count(&self) -> usize {
        self.sets.iter().map(|b| b.rays.origins.len()).sum()
    }

    /// The launch's first-order numbers with the design parameters passed through `lift`, for
    /// the `launched_` methods (`None` when nothing is differentiated).
    pub fn optics<S: Real>(&self, lift: &dyn Fn(Param, S) -> S) -> Option<LaunchOptics<S>> {
        self.launch.optics(lift)
    }

    /// Bundle `k` as a batch in `S`, launched from `optics` (`None`: the stored rays), with the
    /// chief ray appended last when `chief` (see [`RaySet::launched_batch`]).
    pub fn batch<S: Real>(
        &self,
        k: usize,
        optics: Option<&LaunchOptics<S>>,
        chief: bool,
    ) -> RayBatch<S> {
        self.sets[k]
            .rays
            .launched_batch(&self.launch.lens, optics, chief)
    }

    /// Traces bundle `k` in `S` and returns, for each ray that arrives, its sensor-plane position
    /// and slopes `[x, y, dx/dz, dy/dz]` in the sensor frame (what a refocus moves).
    pub fn sensor_rays<S: Traceable>(
        &self,
        sys: &System<S>,
        k: usize,
        trace: TraceOptions,
    ) -> Vec<[S; 4]> {
        self.launched_sensor_rays(sys, None, k, trace)
    }

    /// As [`Bundles::sensor_rays`], with the rays launched from `optics` (see
    /// [`Bundles::optics`]).
    pub fn launched_sensor_rays<S: Traceable>(
        &self,
        sys: &System<S>,
        optics: Option<&LaunchOptics<S>>,
        k: usize,
        trace: TraceOptions,
    ) -> Vec<[S; 4]> {
        self.arrived(sys, optics, k, trace, |o, d| {
            let p = sys.image.point_to_local(o);
            let d = sys.image.rotation.apply_t(d);
            [p.x, p.y, d.x / d.z, d.y / d.z]
        })
    }

    /// Traces bundle `k` in `S` and returns the sensor-plane positions of the rays that arrive.
    pub fn sensor_points<S: Traceable>(
        &self,
        sys: &System<S>,
        k: usize,
        trace: TraceOptions,
    ) -> Vec<[S; 2]> {
        self.launched_sensor_points(sys, None, k, trace)
    }

    /// As [`Bundles::sensor_points`], with the rays launched from `optics` (see
    /// [`Bundles::optics`]).
    pub fn launched_sensor_points<S: Traceable>(
        &self,
        sys: &System<S>,
        optics: Option<&LaunchOptics<S>>,
        k: usize,
        trace: TraceOptions,
    ) -> Vec<[S; 2]> {
        self.arrived(sys, optics, k, trace, |o, _| {
            let p = sys.image.point_to_local(o);
            [p.x, p.y]
        })
    }

    /// Traces bundle `k` and maps `f(position, direction)` (global frame) over the rays that
    /// arrive.
    fn arrived<S: Traceable, T>(
        &self,
        sys: &System<S>,
        optics: Option<&LaunchOptics<S>>,
        k: usize,
        trace: TraceOptions,
        f: impl Fn(Vec3<S>, Vec3<S>) -> T,
    ) -> Vec<T> {
        let mut b = self.batch(k, optics, false);
        trace_serial(sys, self.sets[k].wavelength_nm, &mut b, trace);
        b.iter()
            .filter(|r| r.status.is_alive())
            .map(|r| f(r.o, r.d))
            .collect()
    }
}
