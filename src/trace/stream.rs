//! Rays generated, traced and reduced a chunk at a time: memory independent of the number of
//! rays, every core busy, results independent of the thread count.

use super::rays::Launcher;
use super::{Field, Pupil, RayBatch, RayStatus, TraceOptions, Traceable};
use crate::error::Result;
use crate::lens::{Lens, Paraxial, System};
use crate::math::Vec3;
use rayon::prelude::*;

/// Rays per chunk of a [`RayStream`] (grids: whole rows of about this many points). Small enough
/// that a chunk's rays stay in cache and a few thousand rays already keep two cores busy, large
/// enough that a chunk's trace (~0.3 ms through a ten-surface lens) outweighs its scheduling.
pub const CHUNK_RAYS: usize = 2048;

/// Chunks traced side by side before their reductions are merged ([`RayStream::fold_chunks`]).
pub const FOLD_GROUP: usize = 64;

/// The rays of one field through a [`Pupil`], generated a chunk at a time in the order of
/// [`super::RaySet::generate`] and with its numbers (the same launch, vignetting and aiming).
///
/// [`RayStream::map_chunks`] generates, traces and reduces each chunk on the rayon pool with
/// buffers reused per worker, and returns the reductions in chunk order: a caller that combines
/// them in that order gets the same numbers at any thread count, without ever holding more than
/// a chunk's rays per thread.
///
/// # Examples
/// ```
/// use tolray::trace::{Field, Pupil, RaySet, RayStream, TraceOptions};
/// let lens = tolray::Lens::load("lens2")?;
/// let para = lens.paraxial(587.5618)?;
/// let sys = lens.compile();
/// let pupil = Pupil::grid(128);
/// let stream = RayStream::new(&lens, &para, Field::fraction(0.7), &pupil, 587.5618)?;
/// // Rays reaching the image, counted chunk by chunk.
/// let alive: usize = stream
///     .map_chunks::<f64, _>(&sys, 587.5618, TraceOptions::default(), |_, rays| {
///         rays.iter().filter(|r| r.status.is_alive()).count()
///     })
///     .into_iter()
///     .sum();
/// // The same as tracing the whole set at once.
/// let set = RaySet::generate(&lens, &para, Field::fraction(0.7), &pupil, 587.5618)?;
/// let mut batch = set.batch::<f64>();
/// tolray::trace::trace(&sys, 587.5618, &mut batch, TraceOptions::default());
/// assert_eq!(alive, batch.iter().filter(|r| r.status.is_alive()).count());
/// # Ok::<(), tolray::Error>(())
/// ```
pub struct RayStream {
    launcher: Launcher,
    pupil: Pupil,
    /// The field the rays belong to.
    pub field: Field,
}

impl RayStream {
    /// The rays of `field` through `pupil` at `wavelength_nm` (used for aiming only), as
    /// [`super::RaySet::generate`] would generate them.
    ///
    /// # Errors
    /// As [`super::RaySet::generate`]: the pattern is checked and the chief ray aimed here;
    /// a ray that cannot be aimed is vignetted at the stop, as in a [`super::RaySet`].
    pub fn new(
        lens: &Lens,
        para: &Paraxial,
        field: Field,
        pupil: &Pupil,
        wavelength_nm: f64,
    ) -> Result<RayStream> {
        pupil.pattern.check()?;
        Ok(RayStream {
            launcher: Launcher::new(lens, para, field, pupil.aim, wavelength_nm)?,
            pupil: *pupil,
            field,
        })
    }

    /// The chief ray (origin, unit direction).
    pub fn chief(&self) -> (Vec3<f64>, Vec3<f64>) {
        self.launcher.chief
    }

    /// The chief ray traced in `f64` through `sys` at `wavelength_nm` (on this thread).
    pub(crate) fn traced_chief(
        &self,
        sys: &System<f64>,
        wavelength_nm: f64,
        opts: TraceOptions,
    ) -> super::Ray<f64> {
        let mut batch = RayBatch::<f64>::new();
        let (o, d) = self.chief();
        batch.push(o, d);
        super::trace_serial(sys, wavelength_nm, &mut batch, opts);
        batch.get(0)
    }

    /// The number of chunks ([`Pupil::chunks`]).
    pub fn chunks(&self) -> usize {
        self.pupil.chunks()
    }

    /// Writes chunk `k`'s normalized (vignetted) pupil points into `pts` and its rays, in `S`,
    /// into `batch` (both cleared first).
    pub fn fill<S: Traceable>(&self, k: usize, pts: &mut Vec<[f64; 2]>, batch: &mut RayBatch<S>) {
        self.pupil.chunk_points(k, pts);
        if !self.launcher.vignetted_is_none() {
            for q in pts.iter_mut() {
                *q = self.launcher.vignette(*q);
            }
        }
        batch.clear();
        let mut lost = Vec::new();
        for (i, q) in pts.iter().enumerate() {
            let ((o, d), reached) = self.launcher.ray(*q);
            if !reached {
                lost.push(i);
            }
            batch.push_unit(o.map_value(), d.map_value());
        }
        if let Some(a) = &self.launcher.aiming {
            batch.set_status(&lost, RayStatus::Vignetted(a.stop as u32));
        }
    }

    /// Generates and traces every chunk through `sys` at `wavelength_nm` on the rayon pool and
    /// applies `reduce` to each chunk's (vignetted, normalized) pupil points and traced rays;
    /// returns the reductions in chunk order.
    pub fn map_chunks<S: Traceable, A: Send>(
        &self,
        sys: &System<S>,
        wavelength_nm: f64,
        opts: TraceOptions,
        reduce: impl Fn(&[[f64; 2]], &RayBatch<S>) -> A + Sync,
    ) -> Vec<A> {
        let mut all = Vec::with_capacity(self.chunks());
        self.fold_chunks(sys, wavelength_nm, opts, reduce, |a| all.push(a));
        all
    }

    /// Splits the chunks into `parts` contiguous runs (a number the caller fixes, so that the
    /// result does not depend on the thread count), generates and traces each run's chunks in
    /// order on the rayon pool and adds them with `add` to an accumulator of the run's own
    /// (made by `init`); returns the accumulators in run order. For reductions too large to hold
    /// one per chunk (a PSF's pixels): at most `parts` accumulators exist at once.
    ///
    /// # Examples
    /// ```
    /// use tolray::trace::{Field, Pupil, RayStream, TraceOptions};
    /// let lens = tolray::Lens::load("lens2")?;
    /// let para = lens.paraxial(587.5618)?;
    /// let pupil = Pupil::grid(128);
    /// let stream = RayStream::new(&lens, &para, Field::fraction(0.7), &pupil, 587.5618)?;
    /// let sys = lens.compile();
    /// let count = |parts| {
    ///     let runs = stream.fold_parts::<f64, usize>(
    ///         &sys, 587.5618, TraceOptions::default(), parts, || 0,
    ///         |n, _, rays| *n += rays.iter().filter(|r| r.status.is_alive()).count(),
    ///     );
    ///     assert_eq!(runs.len(), parts);
    ///     runs.iter().sum::<usize>()
    /// };
    /// assert_eq!(count(1), count(5));
    /// # Ok::<(), tolray::Error>(())
    /// ```
    pub fn fold_parts<S: Traceable, A: Send>(
        &self,
        sys: &System<S>,
        wavelength_nm: f64,
        opts: TraceOptions,
        parts: usize,
        init: impl Fn() -> A + Sync,
        add: impl Fn(&mut A, &[[f64; 2]], &RayBatch<S>) + Sync,
    ) -> Vec<A> {
        let n = sys.indices(wavelength_nm);
        let chunks = self.chunks();
        (0..parts)
            .into_par_iter()
            .map(|p| {
                let (mut pts, mut batch, mut acc) = (Vec::new(), RayBatch::new(), init());
                for k in p * chunks / parts..(p + 1) * chunks / parts {
                    self.fill(k, &mut pts, &mut batch);
                    S::trace_blocks(sys, &n, wavelength_nm, opts.apertures, batch.blocks_mut());
                    add(&mut acc, &pts, &batch);
                }
                acc
            })
            .collect()
    }

    /// As [`RayStream::map_chunks`], handing each chunk's reduction to `merge` in chunk order
    /// as soon as its group of chunks is done, so that at most [`FOLD_GROUP`] reductions are
    /// held at once.
    pub fn fold_chunks<S: Traceable, A: Send>(
        &self,
        sys: &System<S>,
        wavelength_nm: f64,
        opts: TraceOptions,
        reduce: impl Fn(&[[f64; 2]], &RayBatch<S>) -> A + Sync,
        mut merge: impl FnMut(A),
    ) {
        let n = sys.indices(wavelength_nm);
        let chunks = self.chunks();
        for first in (0..chunks).step_by(FOLD_GROUP) {
            let group: Vec<A> = (first..(first + FOLD_GROUP).min(chunks))
                .into_par_iter()
                .map_init(
                    || (Vec::new(), RayBatch::new()),
                    |(pts, batch), k| {
                        self.fill(k, pts, batch);
                        S::trace_blocks(sys, &n, wavelength_nm, opts.apertures, batch.blocks_mut());
                        reduce(pts, batch)
                    },
                )
                .collect();
            group.into_iter().for_each(&mut merge);
        }
    }
}
