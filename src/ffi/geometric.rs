//! The geometric-optics calls: tracing, spot statistics, geometric PSFs and gradients through
//! the C ABI (the wave-optics ones are `wave.rs`).

use super::handles::{check_wavelength, tolray_param, tolray_system};
use super::{boundary, c_slice, nonnull, tolray_status, FfiError, FfiResult};
use crate::analysis::spot::{spot_diagram, SpotOptions};
use crate::math::Vec3;
use crate::optim::{self, PsfLoss, SpotLoss, SpotMeasure};
use crate::psf::{self, PsfCentre, PsfOptions};
use crate::trace::{self, Bundles, Field, Pupil, PupilPattern, RayBatch, TraceOptions};
use rayon::prelude::*;

/// A field point. Checked (`TOLRAY_ERROR_ARGUMENT`): `kind` 0 to 4, `x` and `y` finite. How a
/// field becomes rays: "Ray bundles" in the comment at the top of tolray.h.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct tolray_field {
    /// One of the `TOLRAY_FIELD_*` values: how `x` and `y` are measured.
    pub kind: u32,
    /// Field along x (sagittal). Positive values put the object right of the axis (+x).
    pub x: f64,
    /// Field along y (meridional). Positive values put the object above the axis (+y): the
    /// rays then travel toward -y.
    pub y: f64,
}

/// `x`, `y` are fractions of the full field: the tangent of the field angle is the fraction
/// times r_sensor / EFL (the nominal lens' paraxial EFL), so 1 reaches the sensor's
/// half-diagonal paraxially for an object at infinity.
pub const TOLRAY_FIELD_FRACTION: u32 = 0;
/// `x`, `y` are field angles, degrees, in the x-z and y-z planes (tangents tan x, tan y), seen
/// from the first vertex; each must be finite and below 90 in magnitude (`TOLRAY_ERROR_ARGUMENT`).
pub const TOLRAY_FIELD_ANGLE_DEG: u32 = 1;
/// `x`, `y` are object heights, mm: the object point is (x, y, -d) for an object at distance d
/// (finite objects only; at infinity `TOLRAY_ERROR_ARGUMENT`).
pub const TOLRAY_FIELD_HEIGHT_MM: u32 = 2;
/// `x`, `y` are paraxial image heights, mm (OpticStudio's field type 2): the field whose
/// paraxial chief ray meets the image plane at (x, y); positive values put the image above/right
/// of the axis.
pub const TOLRAY_FIELD_IMAGE_HEIGHT_MM: u32 = 3;
/// `x`, `y` are real image heights, mm (OpticStudio's field type 3): the field whose real chief
/// ray at the primary wavelength meets the image plane at (x, y), solved by Newton's method
/// (`TOLRAY_ERROR_NUMERICAL` when no chief ray reaches it); positive values put the image
/// above/right of the axis.
pub const TOLRAY_FIELD_REAL_IMAGE_HEIGHT_MM: u32 = 4;

/// Pupil sampling: points (px, py) in the unit disk times `scale`, normalized coordinates of the
/// paraxial entrance pupil ("Ray bundles" at the top of tolray.h). Checked everywhere
/// (`TOLRAY_ERROR_ARGUMENT`): `pattern` 0 to 2, `n` 1 to 100000000, `scale` in (0, 10], and the
/// pattern holds at most 4194304 (2^22) points per bundle (a grid n^2, a hex pattern about
/// 3 n^2, random n), checked before any ray is allocated.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct tolray_pupil {
    /// One of the `TOLRAY_PUPIL_*` values.
    pub pattern: u32,
    /// Grid: n x n cell centres, those inside the disk kept (about 0.785 n^2 points); hex: n
    /// rings (1 + 3 n (n + 1) points); random: n points.
    pub n: u32,
    /// Seed of the random pattern (ChaCha8; ignored by the others).
    pub seed: u64,
    /// Radius of the sampled disk relative to the paraxial entrance pupil, in (0, 10]: 1 is the
    /// full pupil; above 1 overfills it (apertures then clip).
    pub scale: f64,
    /// Nonzero: aim every ray (Newton iteration on real rays of the nominal lens at the
    /// bundle's wavelength) so that it crosses the stop at the pattern point times the stop's
    /// semi-aperture, instead of passing through the paraxial entrance pupil.
    pub aim: u32,
}

/// Cell-centred square grid: point (i, j) at ((2i + 1) / n - 1, (2j + 1) / n - 1).
pub const TOLRAY_PUPIL_GRID: u32 = 0;
/// Hexapolar: the centre plus rings k = 1 to n of radius k / n, ring k holding 6 k points.
pub const TOLRAY_PUPIL_HEX: u32 = 1;
/// Uniform random points over the disk area, seeded.
pub const TOLRAY_PUPIL_RANDOM: u32 = 2;

/// Spot statistics of one field; sizes in micrometres, sensor positions in millimetres (sensor
/// frame: origin where the axis meets the image plane).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct tolray_spot_stats {
    /// Rays launched: pupil points times wavelengths (chief rays not counted).
    pub n_launched: u64,
    /// Rays that reached the image plane.
    pub n_valid: u64,
    /// Centroid of the arriving rays on the sensor, mm.
    pub centroid_mm: [f64; 2],
    /// RMS radius about the centroid, sqrt(mean |p - centroid|^2), um.
    pub rms_um: f64,
    /// RMS radius about the chief ray, um (0 when `chief_valid` is 0).
    pub rms_chief_um: f64,
    /// Largest distance from the centroid, um.
    pub geo_radius_um: f64,
    /// Fraction of the launched rays that did not arrive, 1 - `n_valid` / `n_launched`.
    pub vignetted_fraction: f64,
    /// Chief-ray position on the sensor at the first wavelength, mm (0 when lost).
    pub chief_mm: [f64; 2],
    /// 1 if the chief ray reached the sensor, else 0.
    pub chief_valid: u32,
}

/// PSF settings, checked by every function that takes them (`TOLRAY_ERROR_ARGUMENT`): `kernel_px`
/// odd, 3 to 1025; `pitch_mm` 1e-5 to 10 mm; `centre` 0 or 1; `pupil` as [`tolray_pupil`] says,
/// with at most 4194304 (2^22) points. How a PSF is built: [`tolray_psf`].
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct tolray_psf_options {
    /// Kernel size in pixels, odd, 3 to 1025 (the PSF is `kernel_px` x `kernel_px`, row-major,
    /// row 0 at +y, column 0 at -x).
    pub kernel_px: u32,
    /// Pixel pitch, mm, 1e-5 to 10.
    pub pitch_mm: f64,
    /// `TOLRAY_PSF_CENTRE_CHIEF` or `TOLRAY_PSF_CENTRE_CENTROID`: the point placed at the centre
    /// of pixel (`kernel_px` / 2, `kernel_px` / 2).
    pub centre: u32,
    /// Pupil sampling of each PSF.
    pub pupil: tolray_pupil,
}

/// The chief ray of the PSF's own wavelength sits at the centre of the centre pixel; when the
/// chief ray is lost, the centroid does.
pub const TOLRAY_PSF_CENTRE_CHIEF: u32 = 0;
/// The centroid of all arriving rays (also those outside the window) sits at the centre of the
/// centre pixel.
pub const TOLRAY_PSF_CENTRE_CENTROID: u32 = 1;

/// Spot measure of the spot loss: the paper's mean distance from the centroid, mean |p - c|.
pub const TOLRAY_SPOT_MEAN: u32 = 0;
/// Spot measure of the spot loss: RMS radius about the centroid, sqrt(mean |p - c|^2).
pub const TOLRAY_SPOT_RMS: u32 = 1;

/// Trace flag: clip rays at clear apertures and the stop (a ray farther than a surface's clear
/// semi-aperture from its axis, in the surface's own frame, is vignetted there). Without it
/// nothing clips, not even the stop.
pub const TOLRAY_TRACE_APERTURES: u32 = 1;
/// Trace flag: return positions and directions in the sensor's own frame (origin at the sensor
/// centre, z along its normal) instead of the global frame.
pub const TOLRAY_TRACE_SENSOR_FRAME: u32 = 2;

/// Ray status value: reached the image plane. Other statuses carry a surface index (from 0; the
/// image plane is surface N, N the number of surfaces) in their low 24 bits:
/// `status & TOLRAY_RAY_SURFACE_MASK`. When several failures apply at one surface, the first of
/// missed, backward, vignetted and TIR is reported; at the image plane only missed (a ray
/// parallel to it) and backward occur.
pub const TOLRAY_RAY_ALIVE: u32 = 0;
/// Ray status kind: outside the clear aperture or stop of a surface (only with
/// `TOLRAY_TRACE_APERTURES`).
pub const TOLRAY_RAY_VIGNETTED: u32 = 1 << 24;
/// Ray status kind: did not meet a surface (passes beside a sphere, beyond a conic's rim, the
/// asphere intersection did not converge, or parallel to a flat surface or the image plane).
pub const TOLRAY_RAY_MISSED: u32 = 2 << 24;
/// Ray status kind: total internal reflection.
pub const TOLRAY_RAY_TIR: u32 = 3 << 24;
/// Ray status kind: the input ray was invalid (a non-finite number or a zero direction); it is
/// returned at position (0, 0, 0) with direction (0, 0, 1) in the global frame and `opl` 0, and
/// its surface bits are 0.
pub const TOLRAY_RAY_INVALID: u32 = 4 << 24;
/// Ray status kind: the surface lies behind the ray (reaching it would take travel against the
/// ray's direction), e.g. an origin past surface 0 or a ray launched away from the lens. The
/// tracer accepts such a step only after a negative gap, and lenses with negative gaps are
/// refused when they are read or edited, so through this API the status always means a lost ray.
pub const TOLRAY_RAY_BACKWARD: u32 = 5 << 24;
/// Mask of the kind bits of a ray status.
pub const TOLRAY_RAY_KIND_MASK: u32 = 0xff00_0000;
/// Mask of the surface-index bits of a ray status.
pub const TOLRAY_RAY_SURFACE_MASK: u32 = 0x00ff_ffff;

/// Input rays, structure of arrays: `n` origins (mm, global frame: z along the axis, the first
/// vertex at z = 0) and directions (any length but 0; normalized on input). Each ray meets
/// surface 0, 1, ... and then the image plane, in that order, so it must start in front of
/// surface 0 and travel toward +z (otherwise it stops as `TOLRAY_RAY_BACKWARD`). The medium
/// before surface 0 is air, n = 1.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct tolray_rays_in {
    /// Origin x, mm.
    pub x: *const f64,
    /// Origin y, mm.
    pub y: *const f64,
    /// Origin z, mm.
    pub z: *const f64,
    /// Direction x.
    pub dx: *const f64,
    /// Direction y.
    pub dy: *const f64,
    /// Direction z.
    pub dz: *const f64,
}

/// Output rays, structure of arrays of `n` each: positions (mm) and unit directions, in the
/// global frame or, with `TOLRAY_TRACE_SENSOR_FRAME`, the sensor's; optical path lengths from the
/// origin (mm: the sum of index times distance, n = 1 before surface 0); and statuses. A ray that
/// arrived is on the image plane; a lost ray keeps the position, direction and path length it
/// had after the last surface it passed (its input for a ray lost at surface 0). `opl` may be
/// NULL. They may be the same arrays as the input (in-place tracing).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct tolray_rays_out {
    /// Position x, mm.
    pub x: *mut f64,
    /// Position y, mm.
    pub y: *mut f64,
    /// Position z, mm.
    pub z: *mut f64,
    /// Direction x.
    pub dx: *mut f64,
    /// Direction y.
    pub dy: *mut f64,
    /// Direction z.
    pub dz: *mut f64,
    /// Optical path length, mm (NULL: not returned).
    pub opl: *mut f64,
    /// Status (`TOLRAY_RAY_*`).
    pub status: *mut u32,
}

impl tolray_field {
    pub(crate) fn to_field(self) -> FfiResult<Field> {
        let (x, y) = (self.x, self.y);
        if !x.is_finite() || !y.is_finite() {
            return Err(FfiError::argument(format!(
                "field ({x}, {y}) is not finite"
            )));
        }
        Ok(match self.kind {
            TOLRAY_FIELD_FRACTION => Field::Fraction { x, y },
            TOLRAY_FIELD_ANGLE_DEG => Field::AngleDeg { x, y },
            TOLRAY_FIELD_HEIGHT_MM => Field::HeightMm { x, y },
            TOLRAY_FIELD_IMAGE_HEIGHT_MM => Field::ImageHeightMm { x, y },
            TOLRAY_FIELD_REAL_IMAGE_HEIGHT_MM => Field::RealImageHeightMm { x, y },
            k => {
                return Err(FfiError::argument(format!(
                    "unknown field kind {k} (expected TOLRAY_FIELD_*: 0 to 4)"
                )))
            }
        })
    }
}

impl tolray_pupil {
    fn to_pupil(self) -> FfiResult<Pupil> {
        let n = self.n as usize;
        if n == 0 || n > 100_000_000 {
            return Err(FfiError::argument(format!(
                "pupil: n = {n} (give 1 to 100000000)"
            )));
        }
        if !(self.scale.is_finite() && self.scale > 0.0 && self.scale <= 10.0) {
            return Err(FfiError::argument(format!(
                "pupil: scale {} must be in (0, 10]",
                self.scale
            )));
        }
        let pattern = match self.pattern {
            TOLRAY_PUPIL_GRID => PupilPattern::Grid(n),
            TOLRAY_PUPIL_HEX => PupilPattern::Hex(n),
            TOLRAY_PUPIL_RANDOM => PupilPattern::Random { n, seed: self.seed },
            k => {
                return Err(FfiError::argument(format!(
                    "unknown pupil pattern {k} (expected TOLRAY_PUPIL_*: 0 to 2)"
                )))
            }
        };
        Ok(Pupil {
            pattern,
            scale: self.scale,
            aim: self.aim != 0,
        })
    }
}

impl tolray_psf_options {
    fn to_options(self) -> FfiResult<PsfOptions> {
        let centre = match self.centre {
            TOLRAY_PSF_CENTRE_CHIEF => PsfCentre::Chief,
            TOLRAY_PSF_CENTRE_CENTROID => PsfCentre::Centroid,
            k => {
                return Err(FfiError::argument(format!(
                    "unknown PSF centre {k} (expected TOLRAY_PSF_CENTRE_*: 0 or 1)"
                )))
            }
        };
        let opts = PsfOptions {
            ks: self.kernel_px as usize,
            pitch_mm: self.pitch_mm,
            centre,
            pupil: self.pupil.to_pupil()?,
        };
        psf::check_options(&opts)?;
        Ok(opts)
    }
}

fn wavelengths(p: *const f64, n: usize, lens: &crate::Lens) -> FfiResult<Vec<f64>> {
    // SAFETY: caller's promise of `n` readable doubles.
    let w = unsafe { c_slice(p, n, "wavelengths_nm") }?;
    if w.is_empty() {
        return Err(FfiError::size("n_wavelengths is 0"));
    }
    for &wl in w {
        check_wavelength(wl, lens)?;
    }
    Ok(w.to_vec())
}

fn fields(p: *const tolray_field, n: usize) -> FfiResult<Vec<Field>> {
    // SAFETY: caller's promise of `n` readable fields.
    let f = unsafe { c_slice(p, n, "fields") }?;
    if f.is_empty() {
        return Err(FfiError::size("n_fields is 0"));
    }
    f.iter().map(|f| f.to_field()).collect()
}

fn params(
    p: *const tolray_param,
    n: usize,
    sys: &tolray_system,
) -> FfiResult<Vec<crate::lens::Param>> {
    // SAFETY: caller's promise of `n` readable params.
    let v = unsafe { c_slice(p, n, "vars") }?;
    v.iter()
        .map(|q| {
            let p = q.to_param()?;
            optim::param_value(&sys.lens, p)?;
            Ok(p)
        })
        .collect()
}

/// Rays per chunk of [`tolray_trace`] (1.3 MB of rays in f64).
const TRACE_CHUNK: usize = 16_384;

/// The caller's arrays of [`tolray_trace`] as addresses (the closures that read and write them
/// run on the thread pool).
struct TraceColumns {
    ins: [usize; 6],
    outs: [usize; 6],
    opl: usize,
    status: usize,
}

impl TraceColumns {
    /// Whether chunks of indices can be read, traced and written independently: no two arrays
    /// overlap except doubles at the same address (a ray traced in place), which each chunk
    /// reads before writing, as the whole trace does.
    fn chunks_are_independent(&self, n: usize) -> bool {
        let mut spans: Vec<(usize, usize, usize)> = self
            .ins
            .iter()
            .chain(&self.outs)
            .map(|&p| (p, n.saturating_mul(8), 8))
            .collect();
        if self.opl != 0 {
            spans.push((self.opl, n.saturating_mul(8), 8));
        }
        spans.push((self.status, n.saturating_mul(4), 4));
        spans.iter().enumerate().all(|(i, &(p, len, size))| {
            spans[..i].iter().all(|&(q, lq, sq)| {
                let apart = p.saturating_add(len) <= q || q.saturating_add(lq) <= p;
                apart || (p == q && size == sq)
            })
        })
    }

    /// Rays `a..b` of the inputs.
    ///
    /// # Safety
    /// The input arrays hold at least `b` readable doubles.
    unsafe fn read(&self, a: usize, b: usize) -> RayBatch<f64> {
        let mut batch = RayBatch::with_capacity(b - a);
        let [x, y, z, dx, dy, dz] = self.ins.map(|p| p as *const f64);
        for i in a..b {
            // SAFETY: i < b, as the caller promises.
            let v = |p: *const f64| unsafe { p.add(i).read() };
            batch.push(Vec3::new(v(x), v(y), v(z)), Vec3::new(v(dx), v(dy), v(dz)));
        }
        batch
    }

    /// Writes `batch` as rays `a..` of the outputs (in the image surface's frame with `image`).
    ///
    /// # Safety
    /// The output arrays hold at least `a + batch.len()` writable elements.
    unsafe fn write(
        &self,
        batch: &RayBatch<f64>,
        a: usize,
        image: Option<&crate::math::Rigid<f64>>,
    ) {
        let [x, y, z, dx, dy, dz] = self.outs.map(|p| p as *mut f64);
        let (opl, status) = (self.opl as *mut f64, self.status as *mut u32);
        for k in 0..batch.len() {
            let r = batch.get(k);
            let (o, d) = match image {
                Some(img) => (img.point_to_local(r.o), img.rotation.apply_t(r.d)),
                None => (r.o, r.d),
            };
            let i = a + k;
            // SAFETY: i < a + batch.len(), as the caller promises.
            unsafe {
                *x.add(i) = o.x;
                *y.add(i) = o.y;
                *z.add(i) = o.z;
                *dx.add(i) = d.x;
                *dy.add(i) = d.y;
                *dz.add(i) = d.z;
                if !opl.is_null() {
                    *opl.add(i) = r.opl;
                }
                *status.add(i) = r.status.code();
            }
        }
    }
}

/// Traces `n` caller rays of one wavelength through `system` (its tolerance pattern applied), in
/// parallel (rayon; results do not depend on the thread count). `wavelength_nm` (finite, 100 nm
/// to 10 mm exclusive) sets every medium's index. `flags` combines `TOLRAY_TRACE_*` (other bits:
/// `TOLRAY_ERROR_ARGUMENT`). Every output array receives `n` values, one status per ray; rays
/// that did not arrive keep the position and direction where they stopped, and their status says
/// why and where. `n` may be 0 (nothing is read or written; the arrays may be NULL); otherwise
/// every array but `out->opl` must be non-NULL (`TOLRAY_ERROR_NULL_ARGUMENT`).
///
/// The output arrays may be the input arrays (a trace in place: `out->x == rays->x` and so on)
/// or overlap them in any way. Arrays that are apart or the same (the same doubles at the same
/// address) are traced in chunks of 16384 rays, memory independent of `n`; arrays that overlap
/// at an offset are read in full before any output is written (a copy of all `n` rays).
///
/// # Safety
/// `system`, `rays`, `out` are valid pointers; the arrays they name hold `n` doubles (`status`:
/// `n` uint32) and are readable (inputs) or writable (outputs).
#[no_mangle]
pub unsafe extern "C" fn tolray_trace(
    system: *const tolray_system,
    wavelength_nm: f64,
    flags: u32,
    n: usize,
    rays: *const tolray_rays_in,
    out: *const tolray_rays_out,
) -> tolray_status {
    boundary("tolray_trace", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: `rays` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let rin = unsafe { nonnull(rays, "rays") }?;
        // SAFETY: `out` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let rout = unsafe { nonnull(out, "out") }?;
        check_wavelength(wavelength_nm, &s.lens)?;
        if flags & !(TOLRAY_TRACE_APERTURES | TOLRAY_TRACE_SENSOR_FRAME) != 0 {
            return Err(FfiError::argument(format!(
                "unknown trace flags {flags:#x}"
            )));
        }
        let outs = [rout.x, rout.y, rout.z, rout.dx, rout.dy, rout.dz];
        let names = [
            "out->x", "out->y", "out->z", "out->dx", "out->dy", "out->dz",
        ];
        for (p, name) in outs.iter().zip(names) {
            if n > 0 && p.is_null() {
                return Err(FfiError::null(name));
            }
        }
        if n > 0 && rout.status.is_null() {
            return Err(FfiError::null("out->status"));
        }
        {
            // Checks only (NULL, size): the rays are read through the pointers below.
            // SAFETY: each column is NULL or has `n` readable elements, as # Safety says.
            let col = |p, name| unsafe { c_slice(p, n, name) }.map(|_| ());
            col(rin.x, "rays->x")?;
            col(rin.y, "rays->y")?;
            col(rin.z, "rays->z")?;
            col(rin.dx, "rays->dx")?;
            col(rin.dy, "rays->dy")?;
            col(rin.dz, "rays->dz")?;
        }
        let cols = TraceColumns {
            ins: [rin.x, rin.y, rin.z, rin.dx, rin.dy, rin.dz].map(|p| p as usize),
            outs: outs.map(|p| p as usize),
            opl: rout.opl as usize,
            status: rout.status as usize,
        };
        let opts = TraceOptions {
            apertures: flags & TOLRAY_TRACE_APERTURES != 0,
        };
        let sensor = flags & TOLRAY_TRACE_SENSOR_FRAME != 0;
        let run = |a: usize, b: usize| {
            // SAFETY: every array holds `n` elements (# Safety), `a..b` lies within `0..n`.
            let mut batch = unsafe { cols.read(a, b) };
            trace::trace(&s.sys, wavelength_nm, &mut batch, opts);
            // SAFETY: as above; the outputs are writable.
            unsafe { cols.write(&batch, a, sensor.then_some(&s.sys.image)) };
        };
        if cols.chunks_are_independent(n) {
            // Chunk by chunk on the pool: memory bounded, reads and writes in parallel.
            (0..n.div_ceil(TRACE_CHUNK))
                .into_par_iter()
                .for_each(|c| run(c * TRACE_CHUNK, ((c + 1) * TRACE_CHUNK).min(n)));
        } else {
            // Arrays that overlap at an offset: read every input before writing any output.
            run(0, n);
        }
        Ok(())
    })
}

/// Spot statistics of one field over `n_wavelengths` wavelengths (at least 1, else
/// `TOLRAY_ERROR_BUFFER_SIZE`; each finite and 100 nm to 10 mm), polychromatic when more than
/// one: all arriving rays together, about the first wavelength's chief ray. The rays are
/// launched from the nominal lens' paraxial pupil at the first wavelength ("Ray bundles" at the
/// top of tolray.h) and traced through `system`; apertures clip when `apertures` is nonzero.
/// `field` and `pupil` are checked as their types say. `TOLRAY_ERROR_NUMERICAL` when no ray of
/// some wavelength reaches the image.
///
/// # Safety
/// `system`, `field`, `pupil` are valid pointers; `wavelengths_nm` holds `n_wavelengths`
/// doubles; `out` points to a writable `tolray_spot_stats`.
#[no_mangle]
pub unsafe extern "C" fn tolray_spot(
    system: *const tolray_system,
    field: *const tolray_field,
    wavelengths_nm: *const f64,
    n_wavelengths: usize,
    pupil: *const tolray_pupil,
    apertures: u32,
    out: *mut tolray_spot_stats,
) -> tolray_status {
    boundary("tolray_spot", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: `field` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let field = unsafe { nonnull(field, "field") }?.to_field()?;
        // SAFETY: `pupil` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let pupil = unsafe { nonnull(pupil, "pupil") }?.to_pupil()?;
        let wl = wavelengths(wavelengths_nm, n_wavelengths, &s.lens)?;
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        let opts = SpotOptions {
            fields: vec![field],
            wavelengths_nm: wl,
            pupil,
            trace: TraceOptions {
                apertures: apertures != 0,
            },
        };
        let res = spot_diagram(&s.nominal, &s.sys, &opts)?;
        let r = res
            .last()
            .ok_or_else(|| FfiError::new(tolray_status::TOLRAY_ERROR_NUMERICAL, "no spot"))?;
        let st = &r.stats;
        let value = tolray_spot_stats {
            n_launched: st.n_launched as u64,
            n_valid: st.n_valid as u64,
            centroid_mm: st.centroid_mm,
            rms_um: st.rms_um,
            rms_chief_um: st.rms_chief_um.unwrap_or(0.0),
            geo_radius_um: st.geo_radius_um,
            vignetted_fraction: st.vignetted_fraction,
            chief_mm: r.chief_mm.unwrap_or([0.0, 0.0]),
            chief_valid: r.chief_mm.is_some() as u32,
        };
        // SAFETY: checked non-NULL.
        unsafe { *out = value };
        Ok(())
    })
}

/// The default PSF settings for the lens of `system`: 51 x 51 pixels at the sensor's pitch
/// (2 r_sensor / hypot(columns, rows) of the lens JSON), chief-ray centred, 8192 uniform random
/// pupil rays with seed 0, scale 1, no aiming. `TOLRAY_ERROR_ARGUMENT`, and `out` untouched, when the
/// sensor's pitch lies outside the 1e-5 to 10 mm that [`tolray_psf`] accepts (fill the struct
/// yourself then): the defaults are always options `tolray_psf` takes.
///
/// # Safety
/// `system` is a live handle; `out` points to a writable `tolray_psf_options`.
#[no_mangle]
pub unsafe extern "C" fn tolray_psf_options_default(
    system: *const tolray_system,
    out: *mut tolray_psf_options,
) -> tolray_status {
    boundary("tolray_psf_options_default", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        let o = PsfOptions::for_lens(&s.nominal);
        psf::check_options(&o).map_err(|e| e.context("the lens' sensor pitch"))?;
        let (n, seed) = match o.pupil.pattern {
            PupilPattern::Random { n, seed } => (n, seed),
            _ => (8192, 0),
        };
        let value = tolray_psf_options {
            kernel_px: o.ks as u32,
            pitch_mm: o.pitch_mm,
            centre: TOLRAY_PSF_CENTRE_CHIEF,
            pupil: tolray_pupil {
                pattern: TOLRAY_PUPIL_RANDOM,
                n: n as u32,
                seed,
                scale: o.pupil.scale,
                aim: o.pupil.aim as u32,
            },
        };
        // SAFETY: checked non-NULL.
        unsafe { *out = value };
        Ok(())
    })
}

/// The geometric PSF of one field at one wavelength (finite, 100 nm to 10 mm): `kernel_px`^2
/// values, row-major with row 0 at +y and column 0 at -x, summing to 1.
///
/// The rays of `opts->pupil` and the chief ray are launched from the nominal lens' paraxial
/// pupil at its primary wavelength ("Ray bundles" at the top of tolray.h), traced through
/// `system` at `wavelength_nm` with apertures clipping, and taken in the sensor frame. The
/// reference point (x0, y0) of `opts->centre` (the chief ray, or the centroid of the arriving
/// rays when the chief ray is lost or `TOLRAY_PSF_CENTRE_CENTROID` is asked for) goes to the
/// centre of pixel (h, h), h = (`kernel_px` - 1) / 2. A ray at (x, y) has the column
/// u = h + (x - x0) / `pitch_mm` and the row v = h - (y - y0) / `pitch_mm`, and is splatted
/// bilinearly: its weight 1 is shared among the 2 x 2 pixels around (u, v) by the fractional
/// parts of u and v. Rays whose 2 x 2 footprint leaves the window (u or v below 0, or at or
/// above `kernel_px` - 1) and rays that did not arrive are left out, and the PSF is divided by
/// the number of rays splatted, so it sums to 1 however many were lost. A PSF into whose window
/// no ray lands is an error (`TOLRAY_ERROR_NUMERICAL`), not a result. `opts` is checked as
/// [`tolray_psf_options`] says; `out_len` must equal `kernel_px * kernel_px`
/// (`TOLRAY_ERROR_BUFFER_SIZE`).
///
/// # Safety
/// `system`, `field`, `opts` are valid pointers; `out` holds `out_len` writable doubles.
#[no_mangle]
pub unsafe extern "C" fn tolray_psf(
    system: *const tolray_system,
    field: *const tolray_field,
    wavelength_nm: f64,
    opts: *const tolray_psf_options,
    out: *mut f64,
    out_len: usize,
) -> tolray_status {
    boundary("tolray_psf", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: `field` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let field = unsafe { nonnull(field, "field") }?.to_field()?;
        // SAFETY: `opts` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let opts = unsafe { nonnull(opts, "opts") }?.to_options()?;
        check_wavelength(wavelength_nm, &s.lens)?;
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        if out_len != opts.ks * opts.ks {
            return Err(FfiError::size(format!(
                "out_len is {out_len}; a {k} x {k} PSF needs {}",
                opts.ks * opts.ks,
                k = opts.ks
            )));
        }
        let (img, _) = psf::psf_streamed(&s.nominal, &s.sys, field, wavelength_nm, &opts)?;
        psf::check_landed(&img, "tolray_psf")?;
        // SAFETY: `out` holds `out_len` == img.len() writable doubles.
        unsafe { std::ptr::copy_nonoverlapping(img.as_ptr(), out, img.len()) };
        Ok(())
    })
}

fn write_gradient(
    sys: &tolray_system,
    obj: &impl optim::Objective,
    vars: &[crate::lens::Param],
    value_out: *mut f64,
    grad_out: *mut f64,
) -> FfiResult<()> {
    if value_out.is_null() {
        return Err(FfiError::null("value_out"));
    }
    if !vars.is_empty() && grad_out.is_null() {
        return Err(FfiError::null("grad_out"));
    }
    let (v, g) = optim::gradient::<_, { optim::GRAD_WIDTH }>(obj, &sys.lens, &sys.adj, vars)?;
    if !v.is_finite() || g.iter().any(|x| !x.is_finite()) {
        return Err(FfiError::new(
            tolray_status::TOLRAY_ERROR_NUMERICAL,
            "the loss or its gradient is not finite (did every bundle lose all its rays?)",
        ));
    }
    // SAFETY: both checked non-NULL; `grad_out` holds `vars.len()` writable doubles.
    unsafe {
        *value_out = v;
        std::ptr::copy_nonoverlapping(g.as_ptr(), grad_out, g.len());
    }
    Ok(())
}

/// The paper's spot loss of `system` and its exact gradient with respect to `vars`, in
/// `*value_out` and `grad_out[0..n_vars]`.
///
/// Loss: the sum over the `n_fields` x `n_wavelengths` bundles of each bundle's spot size, in mm,
/// of the rays that reach the image plane (apertures always clip), about the bundle's own
/// centroid in the sensor frame: `TOLRAY_SPOT_MEAN`, mean |p - c|, or `TOLRAY_SPOT_RMS`,
/// sqrt(mean |p - c|^2). A bundle none of whose rays arrives counts 10 mm (and adds nothing to
/// the gradient). Chief rays are not part of the bundles.
///
/// Gradient: exact derivatives (forward-mode dual numbers through the same tracer, 8 variables
/// per trace) with respect to design variables of the system's lens, at their current values,
/// with the tolerance pattern held fixed: a curvature variable c is traced as
/// c (1 + curvature_pct / 100), a gap with the pattern's gap changes added, and the pattern's
/// motions are constants. The ray launch is differentiated: the bundles are launched from the
/// nominal lens (its paraxial entrance pupil and EFL at the first wavelength, used for every
/// wavelength), and the gradient includes each variable's effect on them (the entrance pupil's
/// position and size, and the field angle of a fraction of the field), so it is the derivative
/// of this function's value as the variables move. Exception: with `pupil->aim` set, the aimed
/// rays keep their launch (the aim is not differentiated). Which rays arrive is held at the
/// current values (vignetting changes are steps, not derivatives).
///
/// Checked: `n_fields` and `n_wavelengths` at least 1 (`TOLRAY_ERROR_BUFFER_SIZE`), fields,
/// wavelengths and `pupil` as for [`tolray_spot`], `measure` 0 or 1, every variable as
/// [`tolray_param`] says on the system's lens (a glass the pattern perturbs is no longer a model
/// glass, so its glass variables are refused). `grad_out` may be NULL when `n_vars` is 0.
/// `TOLRAY_ERROR_NUMERICAL` when the loss or a derivative is not finite.
///
/// # Safety
/// Pointers valid as named; arrays hold the given counts; outputs writable.
#[no_mangle]
pub unsafe extern "C" fn tolray_spot_loss_gradient(
    system: *const tolray_system,
    fields: *const tolray_field,
    n_fields: usize,
    wavelengths_nm: *const f64,
    n_wavelengths: usize,
    pupil: *const tolray_pupil,
    measure: u32,
    vars: *const tolray_param,
    n_vars: usize,
    value_out: *mut f64,
    grad_out: *mut f64,
) -> tolray_status {
    boundary("tolray_spot_loss_gradient", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        let f = self::fields(fields, n_fields)?;
        let wl = wavelengths(wavelengths_nm, n_wavelengths, &s.lens)?;
        // SAFETY: `pupil` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let pupil = unsafe { nonnull(pupil, "pupil") }?.to_pupil()?;
        let measure = match measure {
            TOLRAY_SPOT_MEAN => SpotMeasure::Mean,
            TOLRAY_SPOT_RMS => SpotMeasure::Rms,
            m => {
                return Err(FfiError::argument(format!(
                    "unknown spot measure {m} (expected TOLRAY_SPOT_MEAN or TOLRAY_SPOT_RMS)"
                )))
            }
        };
        let vars = params(vars, n_vars, s)?;
        let bundles = Bundles::new(&s.nominal, &f, &wl, &pupil)?;
        let trace = TraceOptions::default();
        write_gradient(
            s,
            &SpotLoss {
                bundles,
                measure,
                trace,
            },
            &vars,
            value_out,
            grad_out,
        )
    })
}

/// The paper's PSF-similarity loss of `system` and its exact gradient with respect to `vars`, in
/// `*value_out` and `grad_out[0..n_vars]`.
///
/// Loss: 1 - the mean, over the `n_fields` x `n_wavelengths` PSFs, of the similarity between the
/// system's PSF and the nominal lens' PSF at the same field and wavelength, both built as
/// [`tolray_psf`] builds a PSF with `opts` (the same rays, apertures clipping). Similarity: both
/// PSFs scaled to unit L2 norm, then the largest cross-correlation over integer pixel shifts of
/// at most `kernel_px` / 2 in x and in y (zero padding), in [0, 1]; 0 when either PSF is empty
/// (no error here, unlike [`tolray_psf`]).
///
/// Gradient: as for [`tolray_spot_loss_gradient`] (exact, pattern fixed, launch differentiated
/// unless aimed), except that the launch uses the nominal lens' paraxial data at its primary
/// wavelength. The nominal (reference) PSFs move with the variables too (the nominal lens is
/// the design being differentiated); the best shift and the pixel each ray falls in are held.
/// Derivatives flow through the ray positions, the reference point (chief ray or centroid) and
/// the bilinear weights of both PSFs.
///
/// Checked: fields, wavelengths and variables as for [`tolray_spot_loss_gradient`], `opts` as
/// [`tolray_psf_options`] says.
///
/// # Safety
/// Pointers valid as named; arrays hold the given counts; outputs writable.
#[no_mangle]
pub unsafe extern "C" fn tolray_psf_loss_gradient(
    system: *const tolray_system,
    fields: *const tolray_field,
    n_fields: usize,
    wavelengths_nm: *const f64,
    n_wavelengths: usize,
    opts: *const tolray_psf_options,
    vars: *const tolray_param,
    n_vars: usize,
    value_out: *mut f64,
    grad_out: *mut f64,
) -> tolray_status {
    boundary("tolray_psf_loss_gradient", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        let f = self::fields(fields, n_fields)?;
        let wl = wavelengths(wavelengths_nm, n_wavelengths, &s.lens)?;
        // SAFETY: `opts` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let opts = unsafe { nonnull(opts, "opts") }?.to_options()?;
        let vars = params(vars, n_vars, s)?;
        let pairs: Vec<(Field, f64)> = f
            .iter()
            .flat_map(|&f| wl.iter().map(move |&w| (f, w)))
            .collect();
        let loss = PsfLoss {
            rays: Bundles::pairs(&s.nominal, &pairs, &opts.pupil)?,
            opts,
            trace: TraceOptions::default(),
        };
        write_gradient(s, &loss, &vars, value_out, grad_out)
    })
}

/// Simulates a capture through `system` (its lens with its tolerance pattern): the image is cut
/// into `grid x grid` tiles, each blurred by the RGB PSF of the field at the centre of the
/// matching cell of a `grid x grid` partition of the sensor (the lens' "wvln_rgb" wavelengths;
/// `opts` for kernel size, pitch, centring and rays; built as [`tolray_psf`] builds a PSF, traced
/// in single precision) over the tile plus a halo from the reflect-padded image, then white
/// Gaussian noise of standard deviation `noise_sigma` (linear [0, 1] units; 0 for none; not
/// clipped) from `seed` is added. `in` and `out` are planar linear RGB, `3 * width * height`
/// floats, channel-major, row 0 at the top (+y on the sensor); `out_len` must equal that count.
///
/// Checked: `out_len` (`TOLRAY_ERROR_BUFFER_SIZE`); `grid` 1 to 64 and at most `width` and
/// `height`, `noise_sigma` finite and 0 or more, `opts` as
/// [`tolray_psf_options`] says, `kernel_px` / 2 below `width` and `height`, and the padded image,
/// (`width` + `kernel_px` - 1) x (`height` + `kernel_px` - 1), at most 2^28 pixels
/// (`TOLRAY_ERROR_ARGUMENT`). `TOLRAY_ERROR_NUMERICAL` when a PSF is empty.
///
/// # Safety
/// `system` and `opts` are valid pointers; `in` holds `3 * width * height` readable floats and
/// `out` `out_len` writable floats.
#[no_mangle]
pub unsafe extern "C" fn tolray_render(
    system: *const tolray_system,
    opts: *const tolray_psf_options,
    grid: u32,
    noise_sigma: f64,
    seed: u64,
    width: u32,
    height: u32,
    input: *const f32,
    out: *mut f32,
    out_len: usize,
) -> tolray_status {
    boundary("tolray_render", || {
        // SAFETY: `system` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: `opts` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let opts = unsafe { nonnull(opts, "opts") }?.to_options()?;
        let (w, h) = (width as usize, height as usize);
        let n = 3usize.saturating_mul(w).saturating_mul(h);
        if !(1..=64).contains(&grid) || w < grid as usize || h < grid as usize {
            return Err(FfiError::argument(format!(
                "grid {grid} must be 1 to 64 and at most the image size {width}x{height}"
            )));
        }
        if !(noise_sigma >= 0.0 && noise_sigma.is_finite()) {
            return Err(FfiError::new(
                tolray_status::TOLRAY_ERROR_ARGUMENT,
                format!("noise_sigma {noise_sigma} must be zero or positive"),
            ));
        }
        if out_len != n {
            return Err(FfiError::size(format!(
                "out_len is {out_len}; a {width}x{height} RGB image needs {n}"
            )));
        }
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        // SAFETY: `input` is NULL or has `n` readable elements, as # Safety says; NULL is refused.
        let data = unsafe { c_slice(input, n, "in") }?.to_vec();
        let img = crate::image::Image {
            width: w,
            height: h,
            data,
        };
        let psfs = crate::deep::rgb_psf_map(
            &s.nominal,
            &s.sys,
            grid as usize,
            &s.nominal.rgb_wavelengths_nm,
            &opts,
        )?;
        let map = crate::image::render::PsfMap::new(grid as usize, opts.ks, psfs)?;
        let mut y = crate::image::render::render_map(&img, &map)?;
        crate::image::render::SensorNoise::gaussian(noise_sigma).add(&mut y.data, seed, 0);
        // SAFETY: `out` holds `out_len` == y.data.len() writable floats.
        unsafe { std::ptr::copy_nonoverlapping(y.data.as_ptr(), out, n) };
        Ok(())
    })
}

/// Adds a sensor's noise to the noise-free capture `data` (`len` floats, linear [0, 1] units, 1 a
/// full well; e.g. the output of [`tolray_render`] with `noise_sigma` 0): white Gaussian noise of
/// standard deviation `noise_sigma` and, when `full_well_electrons` is not 0, photon shot noise,
/// so that a pixel of value `b` gets variance `max(b, 0) / full_well_electrons + noise_sigma²`
/// (the Poisson–Gaussian sensor model in its Gaussian form, as `tolray render
/// --full-well-electrons` and training use; read noise of `e` electrons is `noise_sigma = e /
/// full_well_electrons`). Deterministic per `seed`; with `full_well_electrons` 0 it adds exactly
/// the noise [`tolray_render`] adds for the same `noise_sigma` and `seed`. Not clipped.
///
/// Checked: `noise_sigma` finite and 0 or more, `full_well_electrons` 0 or a finite number of at
/// least 1 (`TOLRAY_ERROR_ARGUMENT`); `data` not NULL unless `len` is 0.
///
/// # Safety
/// `data` holds `len` readable and writable floats.
#[no_mangle]
pub unsafe extern "C" fn tolray_add_sensor_noise(
    data: *mut f32,
    len: usize,
    noise_sigma: f64,
    full_well_electrons: f64,
    seed: u64,
) -> tolray_status {
    boundary("tolray_add_sensor_noise", || {
        let noise = crate::image::render::SensorNoise {
            sigma: noise_sigma,
            full_well_electrons: (full_well_electrons != 0.0).then_some(full_well_electrons),
        };
        noise.validate()?;
        // SAFETY: `data` is NULL or has `len` readable elements, as # Safety says; NULL is
        // refused unless `len` is 0.
        let mut v = unsafe { c_slice(data.cast_const(), len, "data") }?.to_vec();
        noise.add(&mut v, seed, 0);
        if len > 0 {
            // SAFETY: `data` is not NULL (c_slice refused it) and holds `len` writable floats.
            unsafe { std::ptr::copy_nonoverlapping(v.as_ptr(), data, len) };
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::TraceColumns;

    /// Chunks stream for arrays apart and for doubles traced in place; arrays overlapping at an
    /// offset, or a status array on a double array's address, take the whole-set path.
    #[test]
    fn trace_chunks_stream_unless_arrays_overlap_at_an_offset() {
        let n = 100;
        let apart = |k: usize| 0x10_0000 + k * 0x1000; // column k, 4 KB apart (n doubles: 800 B)
        let cols = |ins: [usize; 6], outs: [usize; 6], opl: usize, status: usize| TraceColumns {
            ins,
            outs,
            opl,
            status,
        };
        let ins = [0, 1, 2, 3, 4, 5].map(apart);
        let outs = [6, 7, 8, 9, 10, 11].map(apart);
        assert!(cols(ins, outs, apart(12), apart(13)).chunks_are_independent(n));
        assert!(cols(ins, outs, 0, apart(13)).chunks_are_independent(n));
        // In place, and an output on another input's column at the same address.
        assert!(cols(ins, ins, apart(12), apart(13)).chunks_are_independent(n));
        let mut crossed = ins;
        crossed.swap(0, 1);
        assert!(cols(ins, crossed, ins[2], apart(13)).chunks_are_independent(n));
        // Outputs 8 bytes after their inputs; opl inside an input; status on a double array.
        assert!(!cols(ins, ins.map(|p| p + 8), apart(12), apart(13)).chunks_are_independent(n));
        assert!(!cols(ins, outs, ins[3] + 16, apart(13)).chunks_are_independent(n));
        assert!(!cols(ins, outs, apart(12), outs[0]).chunks_are_independent(n));
        // The last double of one array against the first of the next: apart when they touch.
        let tight = [0, 1, 2, 3, 4, 5].map(|k| 0x10_0000 + k * 8 * n);
        assert!(cols(tight, outs, apart(12), apart(13)).chunks_are_independent(n));
        assert!(!cols(tight, outs, apart(12), apart(13)).chunks_are_independent(n + 1));
    }
}
