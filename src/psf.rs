//! Geometric point-spread functions: rays splatted bilinearly onto the sensor pixel grid (so the
//! PSF is differentiable in the ray positions), normalized to unit sum; PSF maps over a grid of
//! fields; and the paper's PSF similarity (maximum normalized cross-correlation over shifts).
//!
//! Layout: a PSF is `ks x ks`, row-major, row 0 at the top (+y on the sensor), column 0 at the
//! left (-x); the centre pixel `(ks/2, ks/2)` holds the reference point (the chief ray or the
//! centroid).

use crate::error::{Error, Result};
use crate::lens::paraxial::LaunchOptics;
use crate::lens::{Lens, System};
use crate::math::Vec3;
use crate::real::Real;
use crate::trace::rays::Beam;
use crate::trace::{
    trace_serial, Block, Bundles, Field, Pupil, RayBatch, RayStream, TraceOptions, Traceable, LANES,
};
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use serde::{Deserialize, Serialize};

/// Which point sits in the centre pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PsfCentre {
    /// The chief ray (through the pupil centre) of the PSF's own field and wavelength (so a
    /// PSF holds no lateral colour); the centroid if that ray is lost.
    #[default]
    Chief,
    /// The centroid of the arriving rays.
    Centroid,
}

/// How the PSFs of an image simulation are computed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PsfModel {
    /// Rays splatted on the pixels ([`psf_map`]; the paper's, and what training differentiates).
    #[default]
    Geometric,
    /// The pupil function's FFT deposited on the same pixels
    /// (`wave::psf::diffraction_psf_map`): the Airy disk and the diffraction of an
    /// aberrated wavefront, which a geometric PSF lacks.
    Diffraction,
}

impl PsfModel {
    /// True for the geometric model (the default, left out of saved settings).
    pub fn is_geometric(&self) -> bool {
        *self == PsfModel::Geometric
    }

    /// The model's name (`geometric` or `diffraction`).
    pub fn name(&self) -> &'static str {
        match self {
            PsfModel::Geometric => "geometric",
            PsfModel::Diffraction => "diffraction",
        }
    }
}

/// PSF settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PsfOptions {
    /// Kernel size in pixels (odd; default 51, as in the paper).
    pub ks: usize,
    /// Pixel pitch, mm (default: the sensor's).
    pub pitch_mm: f64,
    /// Centre.
    pub centre: PsfCentre,
    /// Pupil sampling (default: 8192 uniform random rays).
    pub pupil: Pupil,
}

impl PsfOptions {
    /// The defaults for `lens`: 51 x 51 pixels at the sensor pitch, chief-ray centred, 8192 random
    /// rays seeded with 0.
    pub fn for_lens(lens: &Lens) -> PsfOptions {
        PsfOptions {
            ks: 51,
            pitch_mm: lens.sensor.pixel_pitch_mm(),
            centre: PsfCentre::Chief,
            pupil: Pupil {
                pattern: crate::trace::PupilPattern::Random { n: 8192, seed: 0 },
                scale: 1.0,
                aim: false,
            },
        }
    }
}

/// Splats `pts` (sensor mm) bilinearly into a `ks x ks` grid of pitch `pitch_mm` centred on
/// `centre`, and normalizes it to unit sum. Points whose footprint leaves the window are dropped.
/// Returns all zeros when nothing lands.
pub fn splat<S: Real>(pts: &[[S; 2]], centre: [S; 2], ks: usize, pitch_mm: f64) -> Vec<S> {
    let mut acc = Splat::new(centre, ks, pitch_mm);
    for p in pts {
        acc.add(*p);
    }
    acc.finish()
}

/// A PSF being accumulated by bilinear splatting (see [`splat`]).
struct Splat<S> {
    img: Vec<S>,
    ks: usize,
    centre: [S; 2],
    inv_pitch: S,
    half: S,
    count: usize,
}

impl<S: Real> Splat<S> {
    fn new(centre: [S; 2], ks: usize, pitch_mm: f64) -> Self {
        Splat {
            img: vec![S::cst(0.0); ks * ks],
            ks,
            centre,
            inv_pitch: S::cst(1.0 / pitch_mm),
            half: S::cst((ks as f64 - 1.0) / 2.0),
            count: 0,
        }
    }

    /// Adds `p` (if it lands in the window).
    #[inline(always)]
    fn add(&mut self, p: [S; 2]) {
        let (u, v) = self.coords(p);
        if self.inside(u, v) {
            self.deposit(u, v);
        }
    }

    /// Adds the rays of `blk` whose status is alive, of the first `lanes` lanes; `to_sensor`
    /// maps a global position to sensor coordinates. The coordinates are computed for the whole
    /// block first (a loop LLVM vectorizes), then only the points inside the window are added.
    #[inline(always)]
    fn add_block(&mut self, blk: &Block<S>, lanes: usize, to_sensor: impl Fn(Vec3<S>) -> [S; 2]) {
        let zero = S::cst(0.0);
        let mut uv = [[zero; 2]; LANES];
        let mut take = [false; LANES];
        for l in 0..LANES {
            let p = to_sensor(Vec3::new(blk.o[0][l], blk.o[1][l], blk.o[2][l]));
            let (u, v) = self.coords(p);
            uv[l] = [u, v];
            take[l] = (blk.status[l] == 0) & (l < lanes) & self.inside(u, v);
        }
        for l in 0..LANES {
            if take[l] {
                self.deposit(uv[l][0], uv[l][1]);
            }
        }
    }

    /// Pixel coordinates (column, row) of sensor point `p`.
    #[inline(always)]
    fn coords(&self, p: [S; 2]) -> (S, S) {
        let u = (p[0] - self.centre[0]) * self.inv_pitch + self.half;
        let v = self.half - (p[1] - self.centre[1]) * self.inv_pitch;
        (u, v)
    }

    /// True when the 2x2 footprint at `(u, v)` lies in the window (false for NaN).
    #[inline(always)]
    fn inside(&self, u: S, v: S) -> bool {
        let (zero, last) = (S::cst(0.0), S::cst((self.ks - 1) as f64));
        !u.lt(zero) & !v.lt(zero) & u.lt(last) & v.lt(last)
    }

    /// Adds the bilinear weights of a point inside the window. On `[0, ks - 1)` truncation is the
    /// floor.
    #[inline(always)]
    fn deposit(&mut self, u: S, v: S) {
        let ks = self.ks;
        let (i, j) = (u.value() as usize, v.value() as usize);
        let (fu, fv) = (u - S::cst(i as f64), v - S::cst(j as f64));
        let one = S::cst(1.0);
        let k = j * ks + i;
        let px = &mut self.img[k..k + ks + 2];
        px[0] += (one - fu) * (one - fv);
        px[1] += fu * (one - fv);
        px[ks] += (one - fu) * fv;
        px[ks + 1] += fu * fv;
        self.count += 1;
    }

    fn finish(mut self) -> Vec<S> {
        if self.count > 0 {
            let s = S::cst(1.0 / self.count as f64);
            for x in self.img.iter_mut() {
                *x *= s;
            }
        }
        self.img
    }
}

/// The PSF of ray set `k` of `rays` through `sys`, in any number type, centred as `opts` says,
/// and the chief ray's sensor point (`None` when the chief ray is lost).
pub fn psf_of<S: Traceable>(
    sys: &System<S>,
    rays: &Bundles,
    k: usize,
    opts: &PsfOptions,
    trace: TraceOptions,
) -> (Vec<S>, Option<[S; 2]>) {
    psf_of_launched(sys, rays, k, None, opts, trace)
}

/// As [`psf_of`], with the rays launched from `optics` (from [`Bundles::optics`] of
/// `rays.launch`; `None` traces the stored rays).
pub fn psf_of_launched<S: Traceable>(
    sys: &System<S>,
    rays: &Bundles,
    k: usize,
    optics: Option<&LaunchOptics<S>>,
    opts: &PsfOptions,
    trace: TraceOptions,
) -> (Vec<S>, Option<[S; 2]>) {
    let mut b: RayBatch<S> = rays.batch(k, optics, true);
    psf_of_batch(sys, rays.sets[k].wavelength_nm, &mut b, opts, trace)
}

/// The PSF of the rays of `b`, the last of which is the chief ray, traced through `sys` at
/// `wavelength_nm`.
fn psf_of_batch<S: Traceable>(
    sys: &System<S>,
    wavelength_nm: f64,
    b: &mut RayBatch<S>,
    opts: &PsfOptions,
    trace: TraceOptions,
) -> (Vec<S>, Option<[S; 2]>) {
    trace_serial(sys, wavelength_nm, b, trace);
    let b = &*b;
    let n = b.len() - 1;
    let to_sensor = sensor_map(sys);
    let chief = b.get(n);
    let chief = chief.status.is_alive().then(|| to_sensor(chief.o));
    let c = match (opts.centre, chief) {
        (PsfCentre::Chief, Some(c)) => c,
        _ => {
            let (mut x, mut y, mut count) = (S::cst(0.0), S::cst(0.0), 0usize);
            for (k, blk) in b.blocks().iter().enumerate() {
                for l in 0..LANES.min(n.saturating_sub(k * LANES)) {
                    if blk.status[l] == 0 {
                        let p = to_sensor(Vec3::new(blk.o[0][l], blk.o[1][l], blk.o[2][l]));
                        x += p[0];
                        y += p[1];
                        count += 1;
                    }
                }
            }
            let inv = S::cst(1.0 / count.max(1) as f64);
            [x * inv, y * inv]
        }
    };
    let mut acc = Splat::new(c, opts.ks, opts.pitch_mm);
    for (k, blk) in b.blocks().iter().enumerate() {
        acc.add_block(blk, n.saturating_sub(k * LANES), &to_sensor);
    }
    (acc.finish(), chief)
}

/// The map from a global position to sensor coordinates (mm) of `sys`'s image plane.
fn sensor_map<S: Traceable>(sys: &System<S>) -> impl Fn(Vec3<S>) -> [S; 2] + Sync + '_ {
    let image = &sys.image;
    let rotated = sys.image_rotated;
    move |o: Vec3<S>| {
        let p = if rotated {
            image.point_to_local(o)
        } else {
            o - image.translation
        };
        [p.x, p.y]
    }
}

/// Pixel bytes the partial sums of a [`psf_streamed`] PSF may hold at once.
const STREAMED_PSF_BYTES: usize = 64 << 20;

/// The geometric PSF of `field` at `wavelength_nm` through `sys`, centred as `opts` says, with
/// the rays of `opts.pupil` (launched from `lens`'s paraxial entrance pupil at its primary
/// wavelength, as [`Bundles::pairs`] launches them) generated, traced and splatted a chunk at a
/// time on the rayon pool ([`RayStream`]): memory independent of the number of rays, the work
/// split into up to 16 runs of chunks (fewer for a small pupil or a large window). Returns the
/// PSF and the chief ray's sensor point (`None` when that ray is lost).
///
/// The numbers are [`psf_of`]'s on the same rays up to rounding: the pixels are summed in runs of
/// chunks (a number of runs fixed by `opts.ks`, so that the result does not depend on the thread
/// count) and then added in order. A centroid-centred PSF traces the rays twice (the centroid,
/// then the splat); so does a chief-centred one whose chief ray is lost.
///
/// # Errors
/// Options that [`check_options`] refuses; ray-generation errors (the paraxial entrance pupil, a
/// chief ray that cannot be aimed).
///
/// # Examples
/// ```
/// use tolray::psf::{psf_of, psf_streamed, PsfOptions};
/// use tolray::trace::{Bundles, Field, TraceOptions};
/// let lens = tolray::Lens::load("lens2")?;
/// let sys = lens.compile();
/// let opts = PsfOptions::for_lens(&lens);
/// let (psf, chief) = psf_streamed(&lens, &sys, Field::fraction(0.7), 587.5618, &opts)?;
/// assert!(chief.is_some() && (psf.iter().sum::<f64>() - 1.0).abs() < 1e-12);
/// // The rays all at once give the same PSF to rounding.
/// let rays = Bundles::pairs(&lens, &[(Field::fraction(0.7), 587.5618)], &opts.pupil)?;
/// let whole = psf_of(&sys, &rays, 0, &opts, TraceOptions::default()).0;
/// assert!(psf.iter().zip(&whole).all(|(a, b)| (a - b).abs() < 1e-15));
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn psf_streamed(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    opts: &PsfOptions,
) -> Result<(Vec<f64>, Option<[f64; 2]>)> {
    check_options(opts)?;
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    let stream = RayStream::new(lens, &para, field, &opts.pupil, wavelength_nm)?;
    let trace = TraceOptions::default();
    let to_sensor = sensor_map(sys);
    let chief = stream.traced_chief(sys, wavelength_nm, trace);
    let chief = chief.status.is_alive().then(|| to_sensor(chief.o));
    let centre = match (opts.centre, chief) {
        (PsfCentre::Chief, Some(c)) => c,
        _ => {
            let (mut x, mut y, mut count) = (0.0, 0.0, 0usize);
            stream.fold_chunks(
                sys,
                wavelength_nm,
                trace,
                |_, b| {
                    let (mut x, mut y, mut count) = (0.0, 0.0, 0usize);
                    for r in b.iter().filter(|r| r.status.is_alive()) {
                        let p = to_sensor(r.o);
                        x += p[0];
                        y += p[1];
                        count += 1;
                    }
                    (x, y, count)
                },
                |(cx, cy, c)| {
                    x += cx;
                    y += cy;
                    count += c;
                },
            );
            let inv = 1.0 / count.max(1) as f64;
            [x * inv, y * inv]
        }
    };
    let parts = (STREAMED_PSF_BYTES / (8 * opts.ks * opts.ks)).clamp(1, 16);
    let runs = stream.fold_parts(
        sys,
        wavelength_nm,
        trace,
        parts,
        || Splat::new(centre, opts.ks, opts.pitch_mm),
        |acc, _, b| {
            for (k, blk) in b.blocks().iter().enumerate() {
                acc.add_block(blk, b.len().saturating_sub(k * LANES), &to_sensor);
            }
        },
    );
    let mut runs = runs.into_iter();
    let mut psf = runs.next().expect("at least one run");
    for r in runs {
        psf.count += r.count;
        psf.img.iter_mut().zip(&r.img).for_each(|(a, b)| *a += b);
    }
    Ok((psf.finish(), chief))
}

/// A PSF map: `grid x grid` fields spread over the sensor (cell centres of a square grid over
/// the sensor's width and height), each PSF `ks x ks`, at `wavelength_nm`, value-only, in
/// parallel over fields. Row 0 of the grid is the top of the sensor (+y).
///
/// # Errors
/// Ray-generation errors.
pub fn psf_map(
    lens: &Lens,
    sys: &System<f64>,
    grid: usize,
    wavelength_nm: f64,
    opts: &PsfOptions,
) -> Result<Vec<Vec<f64>>> {
    let fields = grid_fields(lens, grid);
    let sys32: System<f32> = sys.convert();
    let to_f64 = |psf: Vec<f32>| psf.into_iter().map(f64::from).collect();
    if opts.pupil.aim {
        let pairs: Vec<(Field, f64)> = fields.iter().map(|&f| (f, wavelength_nm)).collect();
        let rays = Bundles::pairs(lens, &pairs, &opts.pupil)?;
        return Ok((0..pairs.len())
            .into_par_iter()
            .map(|k| to_f64(psf_of(&sys32, &rays, k, opts, TraceOptions::default()).0))
            .collect());
    }
    // Without aiming, each field's rays go straight into an f32 batch.
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    let pts = opts.pupil.points();
    fields
        .par_iter()
        .map(|&f| {
            let mut b = Beam::new(lens, &para, f)?.batch_f32(&pts);
            let psf = psf_of_batch(&sys32, wavelength_nm, &mut b, opts, TraceOptions::default());
            Ok(to_f64(psf.0))
        })
        .collect()
}

/// Fields at the cell centres of a `grid x grid` partition of the sensor, row 0 at the top.
pub fn grid_fields(lens: &Lens, grid: usize) -> Vec<Field> {
    let [w, h] = lens.sensor.size_mm();
    let r = lens.sensor.half_diagonal_mm();
    let mut out = Vec::with_capacity(grid * grid);
    for row in 0..grid {
        for col in 0..grid {
            let fx = ((2 * col + 1) as f64 / grid as f64 - 1.0) * 0.5 * w / r;
            let fy = (1.0 - (2 * row + 1) as f64 / grid as f64) * 0.5 * h / r;
            out.push(Field::Fraction { x: fx, y: fy });
        }
    }
    out
}

/// Shift `(dx, dy)` in pixels, |dx|, |dy| <= ks/2, that maximizes the cross-correlation
/// Σ a\[p\] b\[p + shift\] (zero padding), found by FFT.
pub fn best_shift(a: &[f64], b: &[f64], ks: usize) -> (isize, isize) {
    let n = 2 * ks;
    let fft2 = |img: &[f64]| {
        let mut m = vec![Complex::new(0.0, 0.0); n * n];
        for j in 0..ks {
            for i in 0..ks {
                m[j * n + i] = Complex::new(img[j * ks + i], 0.0);
            }
        }
        crate::fft::fft2(&mut m, n, n, false);
        m
    };
    let (fa, fb) = (fft2(a), fft2(b));
    // corr(s) = IFFT(conj(FA) FB)(s).
    let mut c: Vec<Complex<f64>> = fa.iter().zip(&fb).map(|(x, y)| x.conj() * y).collect();
    crate::fft::fft2(&mut c, n, n, true);
    let h = (ks / 2) as isize;
    let mut best = (0, 0);
    let mut best_v = f64::MIN;
    for dy in -h..=h {
        for dx in -h..=h {
            let v =
                c[(dy.rem_euclid(n as isize) as usize) * n + dx.rem_euclid(n as isize) as usize].re;
            // Prefer the smallest shift among (numerically) equal maxima, deterministically.
            if v > best_v + 1e-12 * best_v.abs().min(f64::MAX / 2.0) {
                best_v = v;
                best = (dx, dy);
            }
        }
    }
    best
}

/// The paper's PSF similarity: both PSFs scaled to unit L2 norm, then the maximum over shifts
/// (|shift| <= ks/2, zero padding) of their cross-correlation, in [0, 1]. `ideal` is a constant;
/// derivatives flow through `psf` at the best shift.
pub fn psf_similarity<S: Real>(ideal: &[f64], psf: &[S], ks: usize) -> S {
    let ideal: Vec<S> = ideal.iter().map(|&a| S::cst(a)).collect();
    psf_similarity_of(&ideal, psf, ks)
}

/// As [`psf_similarity`], with derivatives flowing through both PSFs (a reference that moves
/// with the design); the best shift, found on the values, is held.
pub fn psf_similarity_of<S: Real>(ideal: &[S], psf: &[S], ks: usize) -> S {
    let values: Vec<f64> = psf.iter().map(|v| v.value()).collect();
    let reference: Vec<f64> = ideal.iter().map(|v| v.value()).collect();
    let mut na2 = S::cst(0.0);
    for a in ideal {
        na2 += *a * *a;
    }
    if na2.value() == 0.0 || values.iter().all(|&v| v == 0.0) {
        return S::cst(0.0);
    }
    let (dx, dy) = best_shift(&reference, &values, ks);
    let mut dot = S::cst(0.0);
    let mut nb2 = S::cst(0.0);
    for p in psf {
        nb2 += *p * *p;
    }
    for j in 0..ks as isize {
        for i in 0..ks as isize {
            let (i2, j2) = (i + dx, j + dy);
            if i2 >= 0 && j2 >= 0 && i2 < ks as isize && j2 < ks as isize {
                let a = ideal[(j * ks as isize + i) as usize];
                if a.value() != 0.0 || !a.is_constant() {
                    dot += psf[(j2 * ks as isize + i2) as usize] * a;
                }
            }
        }
    }
    dot / (nb2.sqrt() * na2.sqrt())
}

/// Checks PSF options.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for an even kernel size or one outside 3 to 1025, a pitch
/// outside 1e-5 to 10 mm, or an empty or oversized pupil pattern.
pub fn check_options(opts: &PsfOptions) -> Result<()> {
    // A bilinear splat needs a 2x2 footprint inside the window: with 1 pixel nothing lands.
    if opts.ks < 3 || opts.ks.is_multiple_of(2) || opts.ks > 1025 {
        return Err(Error::argument(format!(
            "PSF kernel size {} must be odd, 3 to 1025",
            opts.ks
        )));
    }
    if !(1e-5..=10.0).contains(&opts.pitch_mm) {
        return Err(Error::argument(format!(
            "PSF pixel pitch {} mm must be 1e-5 to 10 mm (0.01 to 10000 µm)",
            opts.pitch_mm
        )));
    }
    opts.pupil.pattern.check()
}

/// Checks that rays landed in a PSF's window (a PSF sums to 1 when any did, else it is all
/// zeros): an empty PSF is an error, not a result.
///
/// # Errors
/// [`crate::ErrorKind::Numerical`] naming `what` (e.g. the field and wavelength).
pub fn check_landed(psf: &[f64], what: &str) -> Result<()> {
    if psf.iter().sum::<f64>() > 0.0 {
        Ok(())
    } else {
        Err(Error::numerical(format!(
            "{what}: no ray landed in the PSF window (all rays vignetted, or the window is too \
             small for the blur: raise the kernel size or the pixel pitch)"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splat_is_bilinear_and_sums_to_one() {
        // A point a quarter pixel right of the centre: 3/4 in the centre pixel, 1/4 right of it.
        let p = splat(&[[0.25e-3, 0.0]], [0.0, 0.0], 5, 1e-3);
        assert!((p[2 * 5 + 2] - 0.75).abs() < 1e-12 && (p[2 * 5 + 3] - 0.25).abs() < 1e-12);
        let q = splat(
            &[[0.0, 0.0], [1e-3, 1e-3], [-0.3e-3, 0.7e-3]],
            [0.0, 0.0],
            5,
            1e-3,
        );
        assert!((q.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(
            (q[5 + 3] - 1.0 / 3.0).abs() < 1e-12,
            "+y is up: one pixel up and right (row 1, column 3)"
        );
    }

    #[test]
    fn similarity_is_one_for_identical_and_finds_shifts() {
        let ks = 9;
        let mut a = vec![0.0; ks * ks];
        a[4 * ks + 4] = 0.5;
        a[4 * ks + 5] = 0.3;
        a[3 * ks + 4] = 0.2;
        assert!((psf_similarity(&a, &a, ks) - 1.0).abs() < 1e-12);
        // Shifted by (+2, -1): same shape, similarity 1, shift found.
        let mut b = vec![0.0; ks * ks];
        for j in 0..ks {
            for i in 0..ks {
                if i + 2 < ks && j >= 1 {
                    b[(j - 1) * ks + i + 2] = a[j * ks + i];
                }
            }
        }
        assert_eq!(best_shift(&a, &b, ks), (2, -1));
        assert!((psf_similarity(&a, &b, ks) - 1.0).abs() < 1e-12);
        // Blurred: below 1.
        let c: Vec<f64> = (0..ks * ks)
            .map(|k| if a[k] > 0.0 { 0.2 } else { 0.01 })
            .collect();
        let s = psf_similarity(&a, &c, ks);
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!(
            (s - 0.2 / (norm(&a) * norm(&c))).abs() < 1e-12 && s < 0.91,
            "{s}"
        );
    }
}
