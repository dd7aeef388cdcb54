//! Spot analysis per field and wavelength, and polychromatic.

use crate::error::{Error, Result};
use crate::lens::{Lens, System};
use crate::real::{sqrt_or_zero, Real};
use crate::trace::{Field, Pupil, RayStream, TraceOptions};
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
    SpotSummary::of_points(points, |_| true).stats(n_launched, chief)
}

/// Points shown per spot in a picture, about at most: a spot of more rays shows a pseudo-random
/// sample of them, chosen by each ray's pupil coordinates (a regular thinning of a grid would
/// draw moiré); the statistics use every ray.
pub const SHOWN_POINTS: usize = 1 << 16;

/// A spot reduced to what its statistics need, so that it can be accumulated a chunk of rays at
/// a time: the count, centroid and sum of squared distances to it (merged chunk after chunk by
/// Chan's formula), the convex hull's vertices of each chunk (the point farthest from any centre
/// is a hull vertex, so the geometric radius is exact) and the points kept for a picture.
#[derive(Clone, Debug, Default)]
struct SpotSummary {
    n: usize,
    mean: [f64; 2],
    m2: f64,
    hull: Vec<[f64; 2]>,
    /// The length of `hull` when it was last reduced to the hull of its points.
    hull_kept: usize,
    shown: Vec<[f64; 2]>,
}

/// Hull points gathered from chunks before they are reduced to their own hull.
const HULL_SLACK: usize = 4096;

impl SpotSummary {
    /// The summary of `points`, keeping for a picture the points whose index `keep` accepts.
    fn of_points(points: &[[f64; 2]], keep: impl Fn(usize) -> bool) -> SpotSummary {
        let Some(mean) = SpotMoments::centroid_of(points) else {
            return SpotSummary::default();
        };
        // As `SpotMoments::of_points` sums them, so that one chunk's statistics are its numbers.
        let m2 = points.iter().fold(0.0, |a, q| {
            let (px, py) = (q[0] - mean[0], q[1] - mean[1]);
            a + (px * px + py * py)
        });
        SpotSummary {
            n: points.len(),
            mean,
            m2,
            hull: convex_hull(points),
            hull_kept: 0,
            shown: (points.iter().enumerate())
                .filter(|(i, _)| keep(*i))
                .map(|(_, p)| *p)
                .collect(),
        }
    }

    /// Adds `other`'s points (Chan et al.'s pairwise update of the centred sum of squares).
    fn merge(&mut self, other: SpotSummary) {
        if other.n == 0 {
            return;
        }
        if self.n == 0 {
            *self = other;
            return;
        }
        let (na, nb) = (self.n as f64, other.n as f64);
        let n = na + nb;
        let d = [other.mean[0] - self.mean[0], other.mean[1] - self.mean[1]];
        self.mean = [
            self.mean[0] + d[0] * (nb / n),
            self.mean[1] + d[1] * (nb / n),
        ];
        self.m2 += other.m2 + (d[0] * d[0] + d[1] * d[1]) * (na * nb / n);
        self.n += other.n;
        self.hull.extend(other.hull);
        // The chunks' hulls are kept as the hull of their union once they outgrow it (a chunk of
        // rays on a convex arc is all hull), so the memory stays that of the spot's outline.
        if self.hull.len() > 2 * self.hull_kept.max(HULL_SLACK) {
            self.hull = convex_hull(&self.hull);
            self.hull_kept = self.hull.len();
        }
        self.shown.extend(other.shown);
    }

    /// The statistics of the spot out of `n_launched` rays, about `chief` when given.
    fn stats(&self, n_launched: usize, chief: Option<[f64; 2]>) -> Result<SpotStats> {
        if self.n == 0 {
            return Err(Error::numerical("no ray reached the image plane"));
        }
        let m = SpotMoments {
            centroid: self.mean,
            a: self.m2 * (1.0 / self.n as f64),
            b: 0.0,
            c: 0.0,
        };
        let [cx, cy] = m.centroid;
        let geo = self
            .hull
            .iter()
            .map(|p| (p[0] - cx).hypot(p[1] - cy))
            .fold(0.0, f64::max);
        Ok(SpotStats {
            n_launched,
            n_valid: self.n,
            centroid_mm: m.centroid,
            rms_um: m.rms() * 1e3,
            rms_chief_um: chief.map(|c| m.ms_about(c).sqrt() * 1e3),
            geo_radius_um: geo * 1e3,
            vignetted_fraction: 1.0 - self.n as f64 / n_launched.max(1) as f64,
        })
    }
}

/// Whether the ray through the pupil point `q` is one of the about `1/stride` shown in a picture:
/// a hash of its coordinates (SplitMix64's finaliser), so the choice is the same in every chunk
/// and at every thread count.
fn shown(q: [f64; 2], stride: usize) -> bool {
    if stride <= 1 {
        return true;
    }
    let mut z = q[0].to_bits() ^ q[1].to_bits().rotate_left(32);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    z.is_multiple_of(stride as u64)
}

/// The vertices of the convex hull of `points` (Andrew's monotone chain; points on an edge are
/// left out, which changes no distance's maximum: a point on a segment is never farther from a
/// centre than both its ends).
fn convex_hull(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut p: Vec<[f64; 2]> = points
        .iter()
        .copied()
        .filter(|q| q[0].is_finite() && q[1].is_finite())
        .collect();
    if p.len() < 3 {
        return p;
    }
    drop_interior(&mut p);
    monotone_chain(p)
}

/// The convex hull of finite points (at least 3) by Andrew's monotone chain.
fn monotone_chain(mut p: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    // A stable sort merges the runs already in order: a pupil row's rays land along a curve.
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(64);
    for pass in 0..2 {
        let start = hull.len();
        let walk = |q: [f64; 2], hull: &mut Vec<[f64; 2]>| {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        };
        if pass == 0 {
            p.iter().for_each(|&q| walk(q, &mut hull));
        } else {
            p.iter().rev().for_each(|&q| walk(q, &mut hull));
        }
        hull.pop();
    }
    if hull.is_empty() {
        // Every point the same.
        hull.push(p[0]);
    }
    hull
}

/// Removes points that lie well inside the quadrilateral of the extreme points in x and y (Akl
/// and Toussaint's filter): they are no vertex of the hull, and a dense spot keeps only its rim
/// for the sort. "Well inside": beyond 1e-9 of the points' extent from every edge, far above the
/// rounding of the side test, so no hull vertex is ever removed and the hull is unchanged.
fn drop_interior(p: &mut Vec<[f64; 2]>) {
    let pick = |better: fn(&[f64; 2], &[f64; 2]) -> bool| {
        p.iter()
            .fold(p[0], |a, q| if better(q, &a) { *q } else { a })
    };
    let quad = [
        pick(|q, a| q[0] < a[0]),
        pick(|q, a| q[1] < a[1]),
        pick(|q, a| q[0] > a[0]),
        pick(|q, a| q[1] > a[1]),
    ];
    let extent = (quad[2][0] - quad[0][0]).max(quad[3][1] - quad[1][1]);
    // Edges counter-clockwise (left, bottom, right, top extremes): inside is to the left of each.
    let margin = 1e-9 * extent;
    let edges = [0, 1, 2, 3].map(|k| {
        let (a, b) = (quad[k], quad[(k + 1) % 4]);
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let len = (ex * ex + ey * ey).sqrt();
        (a, ex, ey, margin * len)
    });
    if !(extent > 0.0) || edges.iter().any(|e| !(e.3 > 0.0)) {
        return;
    }
    p.retain(|q| {
        !edges
            .iter()
            .all(|&(a, ex, ey, m)| ex * (q[1] - a[1]) - ey * (q[0] - a[0]) > m)
    });
}

/// The second moments of a spot, in any number type: with the rays' sensor positions `p` and
/// (for rays) slopes `s = (dx/dz, dy/dz)` in the sensor frame, each taken about its mean,
/// `a = mean |p|²`, `b = mean p·s` and `c = mean |s|²`, so that the mean-square spot radius
/// about the centroid after moving the sensor by `δ` along its normal is `a + 2 b δ + c δ²`.
///
/// The one accumulator of every spot size: the spot analysis and the Embree check
/// ([`spot_stats`]), the training losses ([`crate::optim::spot_size`], in dual numbers), the
/// Monte Carlo's focus compensator and the differentiated refocus of deep-optics training
/// ([`SpotMoments::best_focus`]), so they measure and refocus identically. Means are sums
/// scaled once by `1/n`.
///
/// # Examples
/// ```
/// use tolray::analysis::SpotMoments;
/// // Two rays crossing the axis 1 mm behind the sensor: [x, y, dx/dz, dy/dz].
/// let rays: [[f64; 4]; 2] = [[0.1, 0.0, -0.1, 0.0], [-0.1, 0.0, 0.1, 0.0]];
/// let m = SpotMoments::of_rays(&rays).unwrap();
/// assert!((m.rms() - 0.1).abs() < 1e-15);
/// let d = SpotMoments::best_focus(&[m]);
/// assert!((d - 1.0).abs() < 1e-12 && m.rms_at(d).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpotMoments<S> {
    /// Centroid on the sensor, mm.
    pub centroid: [S; 2],
    /// Mean square radius about the centroid, mm².
    pub a: S,
    /// Mean product of the centred positions and slopes, mm (0 for points).
    pub b: S,
    /// Mean square of the centred slopes (0 for points).
    pub c: S,
}

impl<S: Real> SpotMoments<S> {
    /// The moments of sensor points `[x, y]` (mm); `None` for no point.
    pub fn of_points(points: &[[S; 2]]) -> Option<SpotMoments<S>> {
        Self::of(points)
    }

    /// The moments of rays `[x, y, dx/dz, dy/dz]` in the sensor frame; `None` for no ray.
    pub fn of_rays(rays: &[[S; 4]]) -> Option<SpotMoments<S>> {
        Self::of(rays)
    }

    /// The centroid of sensor points `[x, y]` (mm), as [`SpotMoments::of_points`] computes it,
    /// without the second moments; `None` for no point.
    pub fn centroid_of(points: &[[S; 2]]) -> Option<[S; 2]> {
        (!points.is_empty()).then(|| Self::means(points))
    }

    /// Column means of `rows` (not empty): sums scaled once by 1/n.
    fn means<const K: usize>(rows: &[[S; K]]) -> [S; K] {
        let inv = S::cst(1.0 / rows.len() as f64);
        let mut m = [S::cst(0.0); K];
        for q in rows {
            for k in 0..K {
                m[k] += q[k];
            }
        }
        for v in m.iter_mut() {
            *v *= inv;
        }
        m
    }

    /// Positions in columns 0 and 1, slopes (when `K` is 4) in 2 and 3.
    fn of<const K: usize>(rows: &[[S; K]]) -> Option<SpotMoments<S>> {
        if rows.is_empty() {
            return None;
        }
        let inv = S::cst(1.0 / rows.len() as f64);
        let m = Self::means(rows);
        let (mut a, mut b, mut c) = (S::cst(0.0), S::cst(0.0), S::cst(0.0));
        for q in rows {
            let (px, py) = (q[0] - m[0], q[1] - m[1]);
            a += px * px + py * py;
            if K == 4 {
                let (sx, sy) = (q[2] - m[2], q[3] - m[3]);
                b += px * sx + py * sy;
                c += sx * sx + sy * sy;
            }
        }
        Some(SpotMoments {
            centroid: [m[0], m[1]],
            a: a * inv,
            b: b * inv,
            c: c * inv,
        })
    }

    /// RMS radius about the centroid, mm (0 for a point image, with derivative 0).
    pub fn rms(&self) -> S {
        sqrt_or_zero(self.a)
    }

    /// Mean square radius about the point `p` (mm), mm²: `a + |centroid − p|²`.
    pub fn ms_about(&self, p: [S; 2]) -> S {
        let (dx, dy) = (self.centroid[0] - p[0], self.centroid[1] - p[1]);
        self.a + dx * dx + dy * dy
    }

    /// RMS spot radius about the centroid with the sensor moved by `delta` mm, mm.
    pub fn rms_at(&self, delta: S) -> S {
        sqrt_or_zero(self.a + S::cst(2.0) * self.b * delta + self.c * delta * delta)
    }

    /// The sensor shift (mm, along its normal) that minimizes the sum of the mean-square radii of
    /// all `moments`: `−Σb / Σc`, and 0 when `Σc` is 0 (parallel rays: no focus to find).
    pub fn best_focus(moments: &[SpotMoments<S>]) -> S {
        let (mut sb, mut sc) = (S::cst(0.0), S::cst(0.0));
        for m in moments {
            sb += m.b;
            sc += m.c;
        }
        if sc.value() > 0.0 {
            -(sb / sc)
        } else {
            S::cst(0.0)
        }
    }
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
    /// True for an afocal image space spot ([`afocal_spot_diagram_rows`]): the "positions"
    /// are the rays' angles in mrad and the "µm" sizes are µrad.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub angular: bool,
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
    rows(lens, sys, opts, false)
}

/// As [`spot_diagram_rows`] in OpticStudio's afocal image space: each ray's "position" is its
/// direction after the last surface as two angles in the image plane's frame, (atan(dx/|dz|),
/// atan(dy/|dz|)) in mrad, so a spot's sizes (the `_um` fields of [`SpotStats`]) are angular
/// spreads in µrad, about the centroid and about the chief ray's direction (OpticStudio's
/// reference in afocal mode). For an afocal lens, whose beams leave collimated, this is the
/// measure of its aberration that the image plane's position does not change; results carry
/// [`SpotResult::angular`].
///
/// # Errors
/// As [`spot_diagram_rows`].
///
/// # Examples
/// ```
/// use tolray::analysis::{afocal_spot_diagram_rows, SpotOptions};
/// use tolray::trace::{Field, Pupil, TraceOptions};
/// // A 2x Keplerian reducer of ideal thin lenses: every beam leaves collimated.
/// let lens = tolray::lens::json::from_str(r#"{"surfaces": [
///     {"type": "ThinLens", "f": 100, "r": 10, "mat2": "air", "d_next": 150, "is_aperture": true},
///     {"type": "ThinLens", "f": 50, "r": 30, "mat2": "air", "d_next": 30}], "r_sensor": 5}"#)?;
/// let opts = SpotOptions {
///     fields: vec![Field::angle(2.0)],
///     wavelengths_nm: vec![587.5618],
///     pupil: Pupil::grid(16),
///     trace: TraceOptions { apertures: true },
/// };
/// let (rows, _) = afocal_spot_diagram_rows(&lens, &lens.compile(), &opts)?;
/// assert!(rows[0].angular && rows[0].stats.rms_um < 1e-6); // µrad
/// // The beam leaves at atan(2 tan 2°), rising (tolray's object above the axis: rays descend).
/// let want = (2.0 * 2f64.to_radians().tan()).atan() * 1e3;
/// assert!((rows[0].stats.centroid_mm[1] - want).abs() < 1e-9); // mrad
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn afocal_spot_diagram_rows(
    lens: &Lens,
    sys: &System<f64>,
    opts: &SpotOptions,
) -> Result<(Vec<SpotResult>, Vec<SpotFailure>)> {
    rows(lens, sys, opts, true)
}

/// [`spot_diagram_rows`] or, with `angular`, [`afocal_spot_diagram_rows`].
fn rows(
    lens: &Lens,
    sys: &System<f64>,
    opts: &SpotOptions,
    angular: bool,
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
        let mut all = SpotSummary::default();
        let mut launched = 0;
        let mut chief0 = None;
        let mut complete = true;
        for (w, &wl) in opts.wavelengths_nm.iter().enumerate() {
            let what = format!("field {} at {wl} nm", field.label());
            let fail = |e: Error| SpotFailure {
                field,
                wavelength_nm: Some(wl),
                reason: e.context(&what).full_message(),
            };
            let stream = match RayStream::new(lens, &para, field, &opts.pupil, wl) {
                Ok(s) => s,
                Err(e) if e.kind() == crate::ErrorKind::Numerical => {
                    failures.push(fail(e));
                    complete = false;
                    continue;
                }
                Err(e) => return Err(e),
            };
            let to_sensor = |r: crate::trace::Ray<f64>| {
                if angular {
                    let d = sys.image.rotation.apply_t(r.d);
                    [d.x.atan2(d.z.abs()) * 1e3, d.y.atan2(d.z.abs()) * 1e3]
                } else {
                    let p = sys.image.point_to_local(r.o);
                    [p.x, p.y]
                }
            };
            let n = opts.pupil.pattern.max_points();
            let stride = n.div_ceil(SHOWN_POINTS);
            let mut spot = SpotSummary::default();
            let mut launched_here = 0;
            stream.fold_chunks(
                sys,
                wl,
                opts.trace,
                |pts, rays| {
                    let (mut points, mut show) = (Vec::new(), Vec::new());
                    for (q, r) in pts.iter().zip(rays.iter()) {
                        if r.status.is_alive() {
                            points.push(to_sensor(r));
                            show.push(shown(*q, stride));
                        }
                    }
                    let summary = SpotSummary::of_points(&points, |i| show[i]);
                    (pts.len(), summary)
                },
                |(count, chunk)| {
                    launched_here += count;
                    spot.merge(chunk);
                },
            );
            let chief_ray = stream.traced_chief(sys, wl, opts.trace);
            let chief = chief_ray.status.is_alive().then(|| to_sensor(chief_ray));
            if w == 0 {
                chief0 = chief;
            }
            let stats = match spot.stats(launched_here, chief) {
                Ok(s) => s,
                Err(e) => {
                    failures.push(fail(e));
                    complete = false;
                    continue;
                }
            };
            launched += launched_here;
            out.push(SpotResult {
                field,
                wavelength_nm: Some(wl),
                stats,
                chief_mm: chief,
                points: spot.shown.clone(),
                angular,
            });
            all.merge(spot);
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
            let stats = all.stats(launched, chief0)?;
            out.push(SpotResult {
                field,
                wavelength_nm: None,
                stats,
                chief_mm: chief0,
                points: all.shown,
                angular,
            });
        }
    }
    Ok((out, failures))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hull without the interior filter: the filter removes no vertex, on dense discs,
    /// rings, segments, grids with collinear rims, repeated points and points near the edges of
    /// the extremes' quadrilateral.
    #[test]
    fn dropping_interior_points_keeps_the_hull() {
        let filtered = |pts: &[[f64; 2]]| {
            let mut p = pts.to_vec();
            drop_interior(&mut p);
            (convex_hull(pts), pts.len() - p.len())
        };
        let mut seed = 7u64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut dropped_any = false;
        for case in 0..40 {
            let n = 3 + case * 50;
            let pts: Vec<[f64; 2]> = (0..n)
                .map(|k| {
                    let (r, t) = (rnd().sqrt(), std::f64::consts::TAU * rnd());
                    match case % 5 {
                        0 => [1e-3 * r * t.cos(), 1e-3 * r * t.sin() + 2.0],
                        1 => [t.cos(), t.sin()],
                        2 => [(k % 7) as f64, (k / 7 % 5) as f64],
                        3 => [k as f64 * 0.1, 0.5],
                        _ => [
                            (r * 4.0).round() * 0.25,
                            (t * 2.0).round() * 0.5 - 1e-12 * r,
                        ],
                    }
                })
                .collect();
            let (with, dropped) = filtered(&pts);
            dropped_any |= dropped > 0;
            // Without the filter.
            let hull = monotone_chain(pts.clone());
            assert_eq!(with, hull, "case {case}");
        }
        assert!(dropped_any, "the filter removed points somewhere");
    }

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

    /// RMS radius about the centroid of rays propagated by `delta` along z, computed directly.
    fn direct_rms(rays: &[[f64; 4]], delta: f64) -> f64 {
        let pts: Vec<[f64; 2]> = rays
            .iter()
            .map(|q| [q[0] + q[2] * delta, q[1] + q[3] * delta])
            .collect();
        let n = pts.len() as f64;
        let cx = pts.iter().map(|p| p[0]).sum::<f64>() / n;
        let cy = pts.iter().map(|p| p[1]).sum::<f64>() / n;
        (pts.iter()
            .map(|p| (p[0] - cx).powi(2) + (p[1] - cy).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    }

    #[test]
    fn moments_match_propagated_rays_and_find_the_best_focus() {
        // A deterministic, astigmatic and decentred fan.
        let rays: Vec<[f64; 4]> = (0..97)
            .map(|i| {
                let t = i as f64 * 0.37;
                let (u, v) = (t.cos() * (1.0 + 0.1 * t.sin()), t.sin() * 0.8);
                [
                    0.3 + 0.05 * u,
                    -0.2 + 0.04 * v,
                    -0.021 * u,
                    -0.017 * v + 0.001,
                ]
            })
            .collect();
        let m = SpotMoments::of_rays(&rays).unwrap();
        for d in [-3.0, -0.5, 0.0, 1.0, 2.5] {
            let (a, b) = (m.rms_at(d), direct_rms(&rays, d));
            assert!((a - b).abs() < 1e-13, "delta {d}: {a} vs {b}");
        }
        let best = SpotMoments::best_focus(&[m]);
        let at = direct_rms(&rays, best);
        for e in [-1e-3, 1e-3] {
            assert!(direct_rms(&rays, best + e) > at, "not a minimum at {best}");
        }
        // Two bundles: the best focus minimizes the sum of their mean squares.
        let other: Vec<[f64; 4]> = rays
            .iter()
            .map(|q| [q[0], q[1], q[2] * 0.5, q[3]])
            .collect();
        let m2 = SpotMoments::of_rays(&other).unwrap();
        let both = SpotMoments::best_focus(&[m, m2]);
        let sum = |d: f64| direct_rms(&rays, d).powi(2) + direct_rms(&other, d).powi(2);
        assert!(sum(both + 1e-3) > sum(both) && sum(both - 1e-3) > sum(both));
        // No rays: no moments; parallel rays: no focus to find.
        assert!(SpotMoments::<f64>::of_rays(&[]).is_none());
        let flat = SpotMoments::of_rays(&[[0.1, 0.0, 0.0, 0.0], [0.2, 0.0, 0.0, 0.0]]).unwrap();
        assert_eq!(SpotMoments::best_focus(&[flat]), 0.0);
    }

    #[test]
    fn points_moments_are_the_rays_moments_without_slopes() {
        let rays = [
            [0.3, -0.1, 0.01, 0.02],
            [0.1, 0.2, -0.03, 0.0],
            [-0.2, 0.05, 0.0, 0.01],
        ];
        let pts: Vec<[f64; 2]> = rays.iter().map(|q| [q[0], q[1]]).collect();
        let (r, p) = (
            SpotMoments::of_rays(&rays).unwrap(),
            SpotMoments::of_points(&pts).unwrap(),
        );
        assert_eq!((r.centroid, r.a), (p.centroid, p.a));
        assert_eq!((p.b, p.c), (0.0, 0.0));
        // About another point: the parallel-axis theorem against the direct mean.
        let c = [0.05, 0.07];
        let direct = pts
            .iter()
            .map(|q| (q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2))
            .sum::<f64>()
            / 3.0;
        assert!((p.ms_about(c) - direct).abs() < 1e-16);
    }
}
