//! What a tolerance analysis judges a fabricated lens by: the RMS spot radius (the paper's, the
//! default), the RMS wavefront error, the Strehl ratio, or the diffraction MTF at one frequency;
//! and the focus compensator that optimises it.
//!
//! Every wave criterion is computed per field at each wavelength by [`crate::wave`] (OPD to
//! the chief ray's reference sphere, rays through the nominal lens' paraxial entrance pupil as
//! the spot criterion launches them) and averaged over the wavelengths with equal weights:
//! - `rms-wavefront`: RMS OPD to centroid (piston and tilt removed), waves, over the default
//!   16 x 48 polar quadrature ([`crate::wave::Wavefront::rms_to_centroid_waves`]);
//! - `strehl`: the PSF's peak over the unaberrated peak by direct summation over the same rays
//!   ([`crate::wave::psf::strehl`]);
//! - `mtf@F[:t|s|mean]`: diffraction MTF at F cycles/mm, tangential, sagittal or their mean
//!   (the default), by the direct autocorrelation of [`crate::wave::mtf::direct_mtf`] over a
//!   [`MTF_GRID`]² pupil grid.
//!
//! The compensator moves the sensor along its normal. For the RMS spot it is the closed-form
//! best focus ([`crate::analysis::SpotMoments::best_focus`]); for a wave criterion it starts
//! there, scans ±3 steps of `λ N_w²` (a quarter of the diffraction depth of focus), marches on
//! with doubling steps while the scan's edge is the best, and refines the best point by Brent's
//! method (parabolic steps seeded by the scan, golden sections as the safeguard) to 5e-4 of a
//! step, maximising the field mean of a Strehl or MTF and minimising that of an RMS wavefront;
//! the answer is the best point evaluated.

use crate::error::{Error, Result};
use crate::lens::{Lens, System};
use crate::math::Vec3;
use crate::trace::{Field, TraceOptions};
use crate::wave::{self, mtf, Sampling, WaveOptions};
use serde::{Deserialize, Serialize};

/// Pupil grid side of the MTF criterion: 32 x 32 cells (812 rays per trace). The MTF it gives
/// differs from a 64-sample FFT MTF by less than 0.01 on the project's lenses
/// (`tests/optics/criterion.rs`).
pub const MTF_GRID: usize = 32;

/// Which MTF a criterion takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MtfDirection {
    /// Along the field's direction in the image plane.
    Tangential,
    /// Across it.
    Sagittal,
    /// The mean of the two.
    Mean,
}

/// A tolerance criterion: what each trial is judged by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Criterion {
    /// RMS spot radius about the centroid, µm (the paper's; lower is better).
    #[default]
    RmsSpot,
    /// RMS wavefront error to centroid, waves (lower is better).
    RmsWavefront,
    /// Strehl ratio (higher is better).
    Strehl,
    /// Diffraction MTF at one frequency (higher is better).
    Mtf {
        /// Frequency, cycles/mm.
        freq_lpmm: f64,
        /// Tangential, sagittal or their mean.
        direction: MtfDirection,
    },
}

impl Criterion {
    /// Parses `rms-spot`, `rms-wavefront`, `strehl` or `mtf@FREQ[:t|s|mean]` (FREQ in
    /// cycles/mm; `tangential`, `sagittal` spelled out also work; mean by default).
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] naming what is wrong.
    ///
    /// # Examples
    /// ```
    /// use tolray::tolerance::{Criterion, MtfDirection};
    /// assert_eq!(Criterion::parse("strehl")?, Criterion::Strehl);
    /// assert_eq!(
    ///     Criterion::parse("mtf@30:t")?,
    ///     Criterion::Mtf { freq_lpmm: 30.0, direction: MtfDirection::Tangential }
    /// );
    /// assert!(Criterion::parse("mtf@-5").is_err());
    /// # Ok::<(), tolray::Error>(())
    /// ```
    pub fn parse(s: &str) -> Result<Criterion> {
        let bad = |why: &str| {
            Error::argument(format!(
                "criterion \"{s}\": {why}; give rms-spot, rms-wavefront, strehl or \
                 mtf@FREQ[:t|s|mean] (FREQ in cycles/mm)"
            ))
        };
        match s.trim() {
            "rms-spot" => return Ok(Criterion::RmsSpot),
            "rms-wavefront" => return Ok(Criterion::RmsWavefront),
            "strehl" => return Ok(Criterion::Strehl),
            _ => {}
        }
        let rest = s
            .trim()
            .strip_prefix("mtf@")
            .ok_or_else(|| bad("unknown criterion"))?;
        let (f, d) = rest.split_once(':').unwrap_or((rest, "mean"));
        let freq_lpmm: f64 = f
            .trim()
            .parse()
            .map_err(|_| bad(&format!("\"{f}\" is not a frequency")))?;
        if !(freq_lpmm > 0.0 && freq_lpmm.is_finite()) {
            return Err(bad("the frequency must be positive and finite"));
        }
        let direction = match d.trim() {
            "t" | "tangential" => MtfDirection::Tangential,
            "s" | "sagittal" => MtfDirection::Sagittal,
            "mean" => MtfDirection::Mean,
            other => return Err(bad(&format!("\"{other}\" is not t, s or mean"))),
        };
        Ok(Criterion::Mtf {
            freq_lpmm,
            direction,
        })
    }

    /// True for the Strehl ratio and the MTF.
    #[must_use]
    pub fn higher_is_better(&self) -> bool {
        matches!(self, Criterion::Strehl | Criterion::Mtf { .. })
    }

    /// A label with the unit, e.g. `RMS wavefront error (waves)`, for tables and axes.
    #[must_use]
    pub fn label(&self) -> String {
        match self {
            Criterion::RmsSpot => "RMS spot (µm)".into(),
            Criterion::RmsWavefront => "RMS wavefront error (waves)".into(),
            Criterion::Strehl => "Strehl ratio".into(),
            Criterion::Mtf {
                freq_lpmm,
                direction,
            } => format!(
                "MTF at {freq_lpmm} cycles/mm{}",
                match direction {
                    MtfDirection::Tangential => ", tangential",
                    MtfDirection::Sagittal => ", sagittal",
                    MtfDirection::Mean => " (mean of T and S)",
                }
            ),
        }
    }

    /// The command-line spelling ([`Criterion::parse`] reads it back).
    #[must_use]
    pub fn spelling(&self) -> String {
        match self {
            Criterion::RmsSpot => "rms-spot".into(),
            Criterion::RmsWavefront => "rms-wavefront".into(),
            Criterion::Strehl => "strehl".into(),
            Criterion::Mtf {
                freq_lpmm,
                direction,
            } => format!(
                "mtf@{freq_lpmm}:{}",
                match direction {
                    MtfDirection::Tangential => "t",
                    MtfDirection::Sagittal => "s",
                    MtfDirection::Mean => "mean",
                }
            ),
        }
    }
}

/// Evaluates a wave criterion on compiled (possibly perturbed) systems of one nominal lens.
pub(crate) struct WaveJudge<'a> {
    lens: &'a Lens,
    criterion: Criterion,
    fields: &'a [Field],
    wavelengths_nm: &'a [f64],
    opts: WaveOptions,
    /// The compensator's scan step, mm.
    step_mm: f64,
}

impl<'a> WaveJudge<'a> {
    /// A judge for `criterion` (not the RMS spot) over `fields` and `wavelengths_nm`.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for the RMS spot (not a wave criterion) or an afocal lens.
    pub(crate) fn new(
        lens: &'a Lens,
        criterion: Criterion,
        fields: &'a [Field],
        wavelengths_nm: &'a [f64],
        trace: TraceOptions,
    ) -> Result<WaveJudge<'a>> {
        if criterion == Criterion::RmsSpot {
            return Err(Error::argument("the RMS spot is not a wave criterion"));
        }
        let para = lens.paraxial(lens.primary_wavelength_nm)?;
        let nw = para.working_fnum.filter(|v| v.is_finite()).ok_or_else(|| {
            Error::argument(format!(
                "criterion {}: the lens forms no finite focus (afocal), so it has no wavefront \
                 to judge",
                criterion.spelling()
            ))
        })?;
        let sampling = match criterion {
            Criterion::Mtf { .. } => Sampling::Grid(MTF_GRID),
            _ => Sampling::default(),
        };
        Ok(WaveJudge {
            lens,
            criterion,
            fields,
            wavelengths_nm,
            opts: WaveOptions {
                sampling,
                trace,
                ..WaveOptions::default()
            },
            step_mm: lens.primary_wavelength_nm * 1e-6 * nw * nw,
        })
    }

    /// The criterion per field (mean over the wavelengths) of `sys`.
    ///
    /// # Errors
    /// A field whose chief ray or whose every ray misses the image, named.
    pub(crate) fn values(&self, sys: &System<f64>) -> Result<Vec<f64>> {
        self.fields
            .iter()
            .map(|&f| {
                let mut sum = 0.0;
                for &wl in self.wavelengths_nm {
                    sum += self.one(sys, f, wl)?;
                }
                Ok(sum / self.wavelengths_nm.len() as f64)
            })
            .collect()
    }

    fn one(&self, sys: &System<f64>, field: Field, wl: f64) -> Result<f64> {
        let w = wave::wavefront(self.lens, sys, field, wl, &self.opts)?;
        match self.criterion {
            Criterion::RmsSpot => unreachable!("refused by WaveJudge::new"),
            Criterion::RmsWavefront => w.rms_to_centroid_waves(),
            Criterion::Strehl => Ok(wave::psf::strehl(&w)),
            Criterion::Mtf {
                freq_lpmm,
                direction,
            } => {
                let map = wave::psf::direction_map(&w)?;
                let (t, s) = mtf::directions(&w);
                let cut = |u| mtf::cutoff_along(&w, &map, u);
                mtf::check_freqs(&[freq_lpmm], [cut(t), cut(s)])
                    .map_err(|e| e.context(format!("field {}, {wl} nm", field.label())))?;
                let at = |u| mtf::direct_otf(self.lens, sys, &w, &map, &self.opts, freq_lpmm, u);
                Ok(match direction {
                    MtfDirection::Tangential => at(t)?.0,
                    MtfDirection::Sagittal => at(s)?.0,
                    MtfDirection::Mean => 0.5 * (at(t)?.0 + at(s)?.0),
                })
            }
        }
    }

    /// The field mean of the criterion, signed so that lower is better.
    fn cost(&self, sys: &System<f64>) -> Result<(f64, Vec<f64>)> {
        let v = self.values(sys)?;
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        Ok((
            if self.criterion.higher_is_better() {
                -mean
            } else {
                mean
            },
            v,
        ))
    }

    /// The focus compensator: the sensor shift (mm, along the image plane's normal) that
    /// optimises the field mean of the criterion, searched from `start_mm`, and the criterion
    /// per field there.
    ///
    /// # Errors
    /// As [`WaveJudge::values`] at the starting point; a shift where a field loses its rays
    /// counts as worst.
    pub(crate) fn best_focus(&self, sys: &System<f64>, start_mm: f64) -> Result<(f64, Vec<f64>)> {
        let h = self.step_mm;
        // Every evaluation goes through `score`, which keeps the best point seen with its
        // per-field values: the answer is the best evaluated point, never evaluated twice.
        let first = self.cost(&moved(sys, start_mm))?;
        let best = std::cell::RefCell::new((start_mm, first.0, first.1));
        let seen = std::cell::RefCell::new(vec![(start_mm, first.0)]);
        let score = |dz: f64| -> f64 {
            let c = self.cost(&moved(sys, dz)).map_or(f64::INFINITY, |(c, v)| {
                if c < best.borrow().1 {
                    *best.borrow_mut() = (dz, c, v);
                }
                c
            });
            seen.borrow_mut().push((dz, c));
            c
        };
        for k in [-3i32, -2, -1, 1, 2, 3] {
            score(start_mm + f64::from(k) * h);
        }
        // A best point at the scan's edge: march on, doubling the step, until it gets worse
        // (at most 2^12 steps of h further).
        let mut step = h;
        let edge = best.borrow().0;
        if (edge - start_mm).abs() > 2.5 * h {
            let dir = (edge - start_mm).signum();
            for _ in 0..12 {
                let (b_dz, b_c, _) = *best.borrow();
                if score(b_dz + dir * step) < b_c {
                    step *= 2.0;
                } else {
                    break;
                }
            }
        }
        let (x0, f0, _) = *best.borrow();
        // The two evaluated points nearest the best, inside the bracket, seed the parabola.
        let mut near: Vec<(f64, f64)> = seen
            .borrow()
            .iter()
            .copied()
            .filter(|&(z, _)| z != x0 && (z - x0).abs() <= step * (1.0 + 1e-12))
            .collect();
        near.sort_by(|a, b| (a.0 - x0).abs().total_cmp(&(b.0 - x0).abs()));
        brent(&score, (x0 - step, x0 + step), (x0, f0), &near, 5e-4 * h);
        let (dz, _, v) = best.into_inner();
        Ok((dz, v))
    }
}

/// Brent's minimisation (parabolic interpolation safeguarded by golden sections, as in
/// Numerical Recipes' `brent`) of `f` on the bracket `(a, b)` around `x` (value `fx`, no worse
/// than the bracket's ends), seeded with up to two further evaluated points `near`, until the
/// bracket is within `tol` (mm) of its best point. Unusable values (`inf` where a field loses
/// its rays) fall back to golden sections.
fn brent(
    f: &dyn Fn(f64) -> f64,
    (mut a, mut b): (f64, f64),
    (mut x, mut fx): (f64, f64),
    near: &[(f64, f64)],
    tol: f64,
) {
    const CGOLD: f64 = 0.381_966_011_250_105_1;
    let (mut w, mut fw) = near.first().copied().unwrap_or((x, fx));
    let (mut v, mut fv) = near.get(1).copied().unwrap_or((w, fw));
    // With two seeds the first step may be parabolic.
    let (mut d, mut e) = (0.0f64, if near.len() >= 2 { b - a } else { 0.0 });
    for _ in 0..100 {
        let xm = 0.5 * (a + b);
        let tol2 = 2.0 * tol;
        if (x - xm).abs() <= tol2 - 0.5 * (b - a) {
            return;
        }
        let mut golden = true;
        if e.abs() > tol {
            let r = (x - w) * (fx - fv);
            let mut q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            } else {
                q = -q;
            }
            let e_old = e;
            if q > 0.0
                && p.is_finite()
                && q.is_finite()
                && p.abs() < (0.5 * q * e_old).abs()
                && p > q * (a - x)
                && p < q * (b - x)
            {
                e = d;
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = tol.copysign(xm - x);
                }
                golden = false;
            }
        }
        if golden {
            e = if x >= xm { a - x } else { b - x };
            d = CGOLD * e;
        }
        let u = if d.abs() >= tol {
            x + d
        } else {
            x + tol.copysign(d)
        };
        let fu = f(u);
        if fu <= fx {
            if u >= x {
                a = x;
            } else {
                b = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
}

/// `sys` with its image plane moved by `dz_mm` along its normal.
pub(crate) fn moved(sys: &System<f64>, dz_mm: f64) -> System<f64> {
    let mut s = sys.clone();
    let n = s.image.rotation.apply(Vec3::cst(0.0, 0.0, 1.0));
    s.image.translation = s.image.translation + n * dz_mm;
    s
}
