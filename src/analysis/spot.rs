//! Spot analysis per field and wavelength, and polychromatic.

use crate::error::{Error, Result};
use crate::lens::{Lens, System};
use crate::trace::{self, Field, Pupil, RaySet, TraceOptions};
use serde::Serialize;

/// Spot statistics. Sizes in micrometres, positions on the sensor in millimetres.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SpotStats {
    /// Rays launched.
    pub n_launched: usize,
    /// Rays that reached the image plane.
    pub n_valid: usize,
    /// Centroid of the valid rays on the sensor, mm.
    pub centroid_mm: [f64; 2],
    /// RMS radius about the centroid, µm: sqrt(mean(|p - centroid|²)).
    pub rms_um: f64,
    /// RMS radius about the chief ray, µm (None if the chief ray was lost).
    pub rms_chief_um: Option<f64>,
    /// Geometric radius: largest distance from the centroid, µm.
    pub geo_radius_um: f64,
    /// Fraction of launched rays that did not reach the image plane.
    pub vignetted_fraction: f64,
}

/// Statistics of `points` (sensor mm) out of `n_launched` rays, about their centroid and about
/// `chief` when given.
///
/// # Errors
/// [`crate::ErrorKind::Numerical`] if no ray reached the image.
pub fn spot_stats(
    points: &[[f64; 2]],
    n_launched: usize,
    chief: Option<[f64; 2]>,
) -> Result<SpotStats> {
    if points.is_empty() {
        return Err(Error::numerical("no ray reached the image plane"));
    }
    let inv = 1.0 / points.len() as f64;
    let cx = points.iter().map(|p| p[0]).sum::<f64>() * inv;
    let cy = points.iter().map(|p| p[1]).sum::<f64>() * inv;
    let ms_about = |c: [f64; 2]| {
        points
            .iter()
            .map(|p| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2))
            .sum::<f64>()
            * inv
    };
    let geo = points
        .iter()
        .map(|p| (p[0] - cx).hypot(p[1] - cy))
        .fold(0.0, f64::max);
    Ok(SpotStats {
        n_launched,
        n_valid: points.len(),
        centroid_mm: [cx, cy],
        rms_um: ms_about([cx, cy]).sqrt() * 1e3,
        rms_chief_um: chief.map(|c| ms_about(c).sqrt() * 1e3),
        geo_radius_um: geo * 1e3,
        vignetted_fraction: 1.0 - points.len() as f64 / n_launched.max(1) as f64,
    })
}

/// What to trace for a spot analysis.
#[derive(Clone, Debug, PartialEq)]
pub struct SpotOptions {
    /// Fields.
    pub fields: Vec<Field>,
    /// Wavelengths, nm (the first is the reference for the polychromatic chief ray).
    pub wavelengths_nm: Vec<f64>,
    /// Pupil sampling.
    pub pupil: Pupil,
    /// Trace options (apertures on or off).
    pub trace: TraceOptions,
}

/// The spot of one field at one wavelength (or all wavelengths together).
#[derive(Clone, Debug, Serialize)]
pub struct SpotResult {
    /// Field.
    pub field: Field,
    /// Wavelength, nm; `None` for the polychromatic spot.
    pub wavelength_nm: Option<f64>,
    /// Statistics.
    pub stats: SpotStats,
    /// Chief-ray position on the sensor, mm.
    pub chief_mm: Option<[f64; 2]>,
    /// Ray positions on the sensor, mm.
    #[serde(skip)]
    pub points: Vec<[f64; 2]>,
}

/// A row of a spot analysis that has no result: no ray of that field and wavelength reached the
/// image, or its rays could not be generated (e.g. ray aiming found no ray through the stop).
#[derive(Clone, Debug, Serialize)]
pub struct SpotFailure {
    /// Field.
    pub field: Field,
    /// Wavelength, nm; `None` for the polychromatic row (missing when any wavelength failed).
    pub wavelength_nm: Option<f64>,
    /// What went wrong.
    pub reason: String,
}

/// Traces `sys` (a compiled, possibly perturbed form of `lens`) for every field and wavelength of
/// `opts` with the fast `f64` kernel. Per field, one result per wavelength, then the
/// polychromatic result when there is more than one wavelength.
///
/// Rays are aimed at `lens`'s nominal paraxial entrance pupil.
///
/// # Errors
/// Paraxial or ray-generation errors, and [`crate::ErrorKind::Numerical`] when no ray of a field
/// reaches the image plane (the first such row; [`spot_diagram_rows`] reports every row).
pub fn spot_diagram(lens: &Lens, sys: &System<f64>, opts: &SpotOptions) -> Result<Vec<SpotResult>> {
    let (results, failures) = spot_diagram_rows(lens, sys, opts)?;
    if let Some(f) = failures.first() {
        return Err(Error::numerical(f.reason.clone()));
    }
    Ok(results)
}

/// As [`spot_diagram`], but a field and wavelength with no result (no ray reaches the image, or
/// no ray can be aimed through the stop) is a [`SpotFailure`] row instead of an error for the
/// whole analysis, so the other fields are still reported (a field beyond the lens' coverage
/// does not hide the rest). The polychromatic row of a field is left out, as a failure, when any
/// of its wavelengths failed.
///
/// # Errors
/// Paraxial errors, arguments (no field or wavelength, a pupil that is too large), and ray
/// generation errors other than numerical ones.
///
/// # Examples
/// ```
/// use tolray::analysis::{spot_diagram_rows, SpotOptions};
/// use tolray::trace::{Field, Pupil, TraceOptions};
/// use tolray::Lens;
/// let lens = Lens::load("lens1")?;
/// let opts = SpotOptions {
///     fields: vec![Field::fraction(0.0), Field::angle(80.0)], // 80°: far beyond lens1's field
///     wavelengths_nm: vec![587.5618],
///     pupil: Pupil::grid(16),
///     trace: TraceOptions { apertures: true },
/// };
/// let (rows, failures) = spot_diagram_rows(&lens, &lens.compile(), &opts)?;
/// assert_eq!(rows.len(), 1);
/// assert_eq!(failures.len(), 1);
/// assert!(failures[0].reason.contains("no ray reached the image"));
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn spot_diagram_rows(
    lens: &Lens,
    sys: &System<f64>,
    opts: &SpotOptions,
) -> Result<(Vec<SpotResult>, Vec<SpotFailure>)> {
    if opts.wavelengths_nm.is_empty() || opts.fields.is_empty() {
        return Err(Error::argument(
            "spot analysis needs at least one field and one wavelength",
        ));
    }
    let para = lens.paraxial(opts.wavelengths_nm[0])?;
    let mut out = Vec::new();
    let mut failures = Vec::new();
    for &field in &opts.fields {
        let mut all = Vec::new();
        let mut launched = 0;
        let mut chief0 = None;
        let mut complete = true;
        for (w, &wl) in opts.wavelengths_nm.iter().enumerate() {
            let what = format!("field {} at {wl} nm", field.label());
            let fail = |e: Error| SpotFailure {
                field,
                wavelength_nm: Some(wl),
                reason: e.context(&what).message,
            };
            let set = match RaySet::generate(lens, &para, field, &opts.pupil, wl) {
                Ok(set) => set,
                Err(e) if e.kind == crate::ErrorKind::Numerical => {
                    failures.push(fail(e));
                    complete = false;
                    continue;
                }
                Err(e) => return Err(e),
            };
            let mut batch = set.batch::<f64>();
            let (co, cd) = set.chief;
            batch.push(co, cd);
            trace::trace(sys, wl, &mut batch, opts.trace);
            let to_sensor = |o| {
                let p = sys.image.point_to_local(o);
                [p.x, p.y]
            };
            let n = set.origins.len();
            let points: Vec<[f64; 2]> = (0..n)
                .map(|i| batch.get(i))
                .filter(|r| r.status.is_alive())
                .map(|r| to_sensor(r.o))
                .collect();
            let chief_ray = batch.get(n);
            let chief = chief_ray.status.is_alive().then(|| to_sensor(chief_ray.o));
            if w == 0 {
                chief0 = chief;
            }
            let stats = match spot_stats(&points, n, chief) {
                Ok(s) => s,
                Err(e) => {
                    failures.push(fail(e));
                    complete = false;
                    continue;
                }
            };
            all.extend_from_slice(&points);
            launched += n;
            out.push(SpotResult {
                field,
                wavelength_nm: Some(wl),
                stats,
                chief_mm: chief,
                points,
            });
        }
        if opts.wavelengths_nm.len() > 1 {
            if !complete {
                failures.push(SpotFailure {
                    field,
                    wavelength_nm: None,
                    reason: format!(
                        "field {}: no polychromatic spot, a wavelength has no ray at the image",
                        field.label()
                    ),
                });
                continue;
            }
            let stats = spot_stats(&all, launched, chief0)?;
            out.push(SpotResult {
                field,
                wavelength_nm: None,
                stats,
                chief_mm: chief0,
                points: all,
            });
        }
    }
    Ok((out, failures))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_a_known_point_set() {
        // Four points on a circle of radius 1 mm around (1, 2): RMS and geo radius are 1000 µm.
        let pts = [[2.0, 2.0], [0.0, 2.0], [1.0, 3.0], [1.0, 1.0]];
        let s = spot_stats(&pts, 5, Some([1.0, 2.0])).unwrap();
        assert!((s.rms_um - 1000.0).abs() < 1e-9);
        assert!((s.geo_radius_um - 1000.0).abs() < 1e-9);
        assert!((s.rms_chief_um.unwrap() - 1000.0).abs() < 1e-9);
        assert!((s.vignetted_fraction - 0.2).abs() < 1e-15);
        let s = spot_stats(&pts, 4, Some([1.0, 1.0])).unwrap();
        assert!((s.rms_chief_um.unwrap() - 2000f64.sqrt() * 1e3f64.sqrt()).abs() < 1e-6);
        assert!(spot_stats(&[], 4, None).is_err());
    }
}
