//! Ray tracing: structure-of-arrays ray batches, the generic kernel, the parallel driver and a
//! plain scalar reference tracer.
//!
//! Rays live in blocks of [`LANES`] rays, each block a structure of arrays. The kernel loops over
//! surfaces outside and lanes inside, so that LLVM turns the lane loop into SIMD code; the `f32`
//! and `f64` instantiations are compiled for several instruction sets and picked at run time.
//! A ray never becomes NaN silently: it carries a [`RayStatus`].

mod bundles;
mod gradient;
mod kernel;
pub mod raw;
pub mod rays;
pub mod reference;
pub mod simd;
mod stream;

pub use bundles::{Bundle, Bundles};
pub use kernel::Traceable;
pub use rays::{Field, FieldPoint, LaunchSource, Pupil, PupilPattern, RaySet, Vignetting};
pub use stream::{RayStream, CHUNK_RAYS, FOLD_GROUP};

use crate::lens::System;
use crate::math::Vec3;
use crate::real::Real;
use rayon::prelude::*;

/// Rays per block (the width of the lane loop).
pub const LANES: usize = 16;

/// Blocks per parallel work item.
const CHUNK_BLOCKS: usize = 16;

/// What happened to a ray. Surfaces are counted from 0; the image plane counts as surface N.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RayStatus {
    /// Reached the image plane.
    Alive,
    /// Outside the clear aperture (or stop) of a surface.
    Vignetted(u32),
    /// Did not meet a surface at all.
    Missed(u32),
    /// Total internal reflection at a surface.
    Tir(u32),
    /// The input ray was invalid (non-finite numbers or a zero direction).
    Invalid,
    /// The surface lies behind the ray: reaching it would take travel against the ray's
    /// direction, which is refused unless the gap before the surface is negative (a lens that
    /// asks for virtual propagation). A ray launched away from the lens, or starting behind a
    /// surface, stops here instead of landing where the forward ray would.
    Backward(u32),
}

pub(crate) const CODE_VIGNETTED: u32 = 1 << 24;
pub(crate) const CODE_MISSED: u32 = 2 << 24;
pub(crate) const CODE_TIR: u32 = 3 << 24;
pub(crate) const CODE_INVALID: u32 = 4 << 24;
pub(crate) const CODE_BACKWARD: u32 = 5 << 24;

impl RayStatus {
    /// Decodes the packed status stored in a batch.
    pub fn from_code(code: u32) -> RayStatus {
        let s = code & 0x00ff_ffff;
        match code & 0xff00_0000 {
            0 => RayStatus::Alive,
            CODE_VIGNETTED => RayStatus::Vignetted(s),
            CODE_MISSED => RayStatus::Missed(s),
            CODE_TIR => RayStatus::Tir(s),
            CODE_BACKWARD => RayStatus::Backward(s),
            _ => RayStatus::Invalid,
        }
    }
    /// The packed code.
    pub fn code(self) -> u32 {
        match self {
            RayStatus::Alive => 0,
            RayStatus::Vignetted(s) => CODE_VIGNETTED | s,
            RayStatus::Missed(s) => CODE_MISSED | s,
            RayStatus::Tir(s) => CODE_TIR | s,
            RayStatus::Invalid => CODE_INVALID,
            RayStatus::Backward(s) => CODE_BACKWARD | s,
        }
    }
    /// True if the ray reached the image plane.
    pub fn is_alive(self) -> bool {
        self == RayStatus::Alive
    }
}

impl std::fmt::Display for RayStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RayStatus::Alive => write!(f, "alive"),
            RayStatus::Vignetted(s) => write!(f, "vignetted@{s}"),
            RayStatus::Missed(s) => write!(f, "missed@{s}"),
            RayStatus::Tir(s) => write!(f, "tir@{s}"),
            RayStatus::Invalid => write!(f, "invalid"),
            RayStatus::Backward(s) => write!(f, "backward@{s}"),
        }
    }
}

/// One block of rays, structure of arrays. Positions in mm (global frame), unit directions,
/// optical path length in mm.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub struct Block<S> {
    /// Position x, y, z.
    pub o: [[S; LANES]; 3],
    /// Direction x, y, z (unit length).
    pub d: [[S; LANES]; 3],
    /// Optical path length accumulated so far, mm.
    pub opl: [S; LANES],
    /// Packed [`RayStatus`].
    pub status: [u32; LANES],
}

impl<S: Real> Block<S> {
    fn dead() -> Self {
        Block {
            o: [[S::cst(0.0); LANES]; 3],
            d: [[S::cst(0.0); LANES]; 3],
            opl: [S::cst(0.0); LANES],
            status: [CODE_INVALID; LANES],
        }
    }
}

/// One ray read back from a batch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray<S> {
    /// Position, mm.
    pub o: Vec3<S>,
    /// Unit direction.
    pub d: Vec3<S>,
    /// Optical path length, mm.
    pub opl: S,
    /// Outcome.
    pub status: RayStatus,
}

/// A batch of rays of one wavelength, padded to whole blocks with dead rays.
#[derive(Clone, Debug)]
pub struct RayBatch<S> {
    blocks: Vec<Block<S>>,
    len: usize,
}

impl<S: Real> Default for RayBatch<S> {
    fn default() -> Self {
        RayBatch::new()
    }
}

impl<S: Real> RayBatch<S> {
    /// Gives the rays at `indices` the status `status` (a dead status keeps them out of every
    /// later pass). Indices past the end are ignored.
    pub fn set_status(&mut self, indices: &[usize], status: RayStatus) {
        for &i in indices {
            if i < self.len {
                self.blocks[i / LANES].status[i % LANES] = status.code();
            }
        }
    }

    /// An empty batch.
    pub fn new() -> Self {
        RayBatch {
            blocks: Vec::new(),
            len: 0,
        }
    }
    /// An empty batch with room for `n` rays.
    pub fn with_capacity(n: usize) -> Self {
        RayBatch {
            blocks: Vec::with_capacity(n.div_ceil(LANES)),
            len: 0,
        }
    }
    /// Number of rays.
    pub fn len(&self) -> usize {
        self.len
    }
    /// True if there are no rays.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Appends a ray at `o` (mm) with direction `d` (need not be normalized). A ray with
    /// non-finite numbers or a zero direction is stored as [`RayStatus::Invalid`].
    pub fn push(&mut self, o: Vec3<f64>, d: Vec3<f64>) {
        // Normalized in f64, then rounded to S (an f32 batch gets the f64 ray's nearest numbers).
        let norm = d.norm();
        let ok = [o.x, o.y, o.z, d.x, d.y, d.z].iter().all(|v| v.is_finite()) && norm > 0.0;
        let d = if ok { d * (1.0 / norm) } else { d };
        self.store(o.map_value(), d.map_value(), ok);
    }

    /// As [`RayBatch::push`], with the ray given and normalized in `S` (derivatives kept; for
    /// `f64` the same numbers).
    pub fn push_in(&mut self, o: Vec3<S>, d: Vec3<S>) {
        let norm = d.norm();
        let ok = [o.x, o.y, o.z, d.x, d.y, d.z]
            .iter()
            .all(|v| v.value().is_finite())
            && norm.value() > 0.0;
        let d = if ok { d * (S::cst(1.0) / norm) } else { d };
        self.store(o, d, ok);
    }

    /// Appends a ray (unit direction) as it is when `ok`, else an invalid one.
    fn store(&mut self, o: Vec3<S>, d: Vec3<S>, ok: bool) {
        let (b, l) = (self.len / LANES, self.len % LANES);
        if l == 0 {
            self.blocks.push(Block::dead());
        }
        let (zero, one) = (S::cst(0.0), S::cst(1.0));
        let d = if ok { d } else { Vec3::new(zero, zero, one) };
        let o = if ok { o } else { Vec3::new(zero, zero, zero) };
        let blk = &mut self.blocks[b];
        for (k, v) in [o.x, o.y, o.z].into_iter().enumerate() {
            blk.o[k][l] = v;
        }
        for (k, v) in [d.x, d.y, d.z].into_iter().enumerate() {
            blk.d[k][l] = v;
        }
        blk.opl[l] = zero;
        blk.status[l] = if ok { 0 } else { CODE_INVALID };
        self.len += 1;
    }

    /// A batch of the rays `origins[i]`, `directions[i]` (mm; unit directions, taken as they are).
    /// A ray with non-finite numbers is stored as [`RayStatus::Invalid`], as by [`RayBatch::push`].
    ///
    /// # Panics
    /// If the two slices differ in length.
    pub fn from_unit_rays(origins: &[Vec3<f64>], directions: &[Vec3<f64>]) -> Self {
        assert_eq!(origins.len(), directions.len(), "one direction per origin");
        Self::collect_unit(
            origins
                .iter()
                .zip(directions)
                .map(|(o, d)| (o.map_value(), d.map_value())),
        )
    }

    /// A batch of the rays (origin mm, unit direction) in `S`, taken as they are (derivatives
    /// kept); a ray with non-finite numbers is stored as [`RayStatus::Invalid`], as by
    /// [`RayBatch::from_unit_rays`].
    pub fn collect_unit(rays: impl IntoIterator<Item = (Vec3<S>, Vec3<S>)>) -> Self {
        let mut b = RayBatch::new();
        for (o, d) in rays {
            b.push_unit(o, d);
        }
        b
    }

    /// Appends the ray at `o` (mm) with the unit direction `d`, taken as they are (derivatives
    /// kept), as [`RayBatch::collect_unit`] stores each of its rays: one with non-finite numbers
    /// is [`RayStatus::Invalid`].
    pub fn push_unit(&mut self, o: Vec3<S>, d: Vec3<S>) {
        let l = self.len % LANES;
        if l == 0 {
            self.blocks.push(Block::dead());
        }
        let (o, d) = ([o.x, o.y, o.z], [d.x, d.y, d.z]);
        if let Some(blk) = self
            .blocks
            .last_mut()
            .filter(|_| o.iter().chain(&d).all(|v| v.value().is_finite()))
        {
            debug_assert!(
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - S::cst(1.0))
                    .value()
                    .abs()
                    < 1e-5,
                "push_unit takes unit directions"
            );
            for k in 0..3 {
                blk.o[k][l] = o[k];
                blk.d[k][l] = d[k];
            }
            blk.status[l] = 0;
        }
        self.len += 1;
    }

    /// Removes every ray, keeping the allocation (a buffer reused chunk after chunk).
    pub fn clear(&mut self) {
        self.blocks.clear();
        self.len = 0;
    }
    /// Ray `i`.
    ///
    /// # Panics
    /// If `i >= self.len()`.
    pub fn get(&self, i: usize) -> Ray<S> {
        assert!(i < self.len, "ray index {i} out of range {}", self.len);
        let (b, l) = (&self.blocks[i / LANES], i % LANES);
        Ray {
            o: Vec3::new(b.o[0][l], b.o[1][l], b.o[2][l]),
            d: Vec3::new(b.d[0][l], b.d[1][l], b.d[2][l]),
            opl: b.opl[l],
            status: RayStatus::from_code(b.status[l]),
        }
    }
    /// Iterates over all rays.
    pub fn iter(&self) -> impl Iterator<Item = Ray<S>> + '_ {
        (0..self.len).map(|i| self.get(i))
    }
    /// The blocks (padding rays are [`RayStatus::Invalid`]).
    pub fn blocks(&self) -> &[Block<S>] {
        &self.blocks
    }
    /// Mutable blocks, for custom kernels.
    pub fn blocks_mut(&mut self) -> &mut [Block<S>] {
        &mut self.blocks
    }
}

/// Options of a trace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceOptions {
    /// Clip rays at clear apertures and the stop (false: the reference's "mode A").
    pub apertures: bool,
}

impl Default for TraceOptions {
    fn default() -> Self {
        TraceOptions { apertures: true }
    }
}

/// Traces every ray of `batch` (one wavelength, `wavelength_nm`) through `sys` to the image plane,
/// in parallel over blocks on the current rayon pool. Results do not depend on the thread count.
pub fn trace<S: Traceable>(
    sys: &System<S>,
    wavelength_nm: f64,
    batch: &mut RayBatch<S>,
    opts: TraceOptions,
) {
    let n = sys.indices(wavelength_nm);
    batch
        .blocks
        .par_chunks_mut(CHUNK_BLOCKS)
        .for_each(|c| S::trace_blocks(sys, &n, wavelength_nm, opts.apertures, c));
}

/// As [`trace`], on the calling thread only.
pub fn trace_serial<S: Traceable>(
    sys: &System<S>,
    wavelength_nm: f64,
    batch: &mut RayBatch<S>,
    opts: TraceOptions,
) {
    let n = sys.indices(wavelength_nm);
    S::trace_blocks(sys, &n, wavelength_nm, opts.apertures, &mut batch.blocks);
}

/// Sag (mm) of a compiled surface at squared radius `u` (mm²): conic plus even-asphere terms,
/// in any number type (used for edge-thickness constraints).
pub fn kernel_sag<S: Real>(row: &crate::lens::SurfaceRow<S>, u: S) -> S {
    kernel::asphere_sag(row, u).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_codes_round_trip_and_print() {
        for s in [
            RayStatus::Alive,
            RayStatus::Vignetted(3),
            RayStatus::Missed(2),
            RayStatus::Tir(5),
            RayStatus::Invalid,
        ] {
            assert_eq!(RayStatus::from_code(s.code()), s);
        }
        assert_eq!(RayStatus::Tir(5).to_string(), "tir@5");
        assert_eq!(RayStatus::Vignetted(3).to_string(), "vignetted@3");
    }

    #[test]
    fn push_normalizes_and_flags_bad_rays() {
        let mut b = RayBatch::<f64>::new();
        b.push(Vec3::cst(0.0, 0.0, 0.0), Vec3::cst(0.0, 3.0, 4.0));
        b.push(Vec3::cst(f64::NAN, 0.0, 0.0), Vec3::cst(0.0, 0.0, 1.0));
        b.push(Vec3::cst(0.0, 0.0, 0.0), Vec3::cst(0.0, 0.0, 0.0));
        assert_eq!(b.len(), 3);
        assert!((b.get(0).d.y - 0.6).abs() < 1e-15);
        assert_eq!(b.get(1).status, RayStatus::Invalid);
        assert_eq!(b.get(2).status, RayStatus::Invalid);
    }
}
