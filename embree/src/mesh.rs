//! Tessellation of a compiled surface into a triangle mesh whose distance from the true surface
//! is bounded by a chord error chosen by the user.
//!
//! # The mesh
//!
//! Polar: a centre vertex and `rings` rings at radii `i Δr`, all vertices on the surface
//! (`z = sag(r)` in the surface's local frame). Ring `i` holds `8 · 2^j` vertices, the fewest
//! that keep its vertex spacing `2π r_i / n_i` at most `s` (≈ Δr), so triangles stay close to
//! right isosceles from the centre to the rim (no slivers): the centre fan has 8 triangles; a
//! band between rings of equal counts splits each quad along the same diagonal; a band where
//! the count doubles has three triangles per inner segment. Counts are multiples of 8, so
//! vertices and edges lie on the x and y axes (the meridional plane). The outer ring reaches
//! `(a + s) / cos(π / n)` for a disk of radius `a`: its inscribed polygon covers the disk with
//! one spacing to spare, so every ray inside the disk meets the mesh, and the aperture test is
//! done on the hit.
//!
//! # The chord bound
//!
//! Let `f(x, y)` be the sag and `M` the largest second directional derivative of `f` over the
//! mesh's disk. For a rotationally symmetric `f` the Hessian has the eigenvalues `f_rr`
//! (radial) and `f_r / r = 2 f_u` (tangential), with `u = r²`, `f_rr = 2 f_u + 4 u f_uu`, so
//! `M = max_r max(|f_rr|, |2 f_u|)`, which includes the conic and asphere terms.
//!
//! On a triangle `T` whose smallest enclosing disk (in x, y) has centre `m` and radius `R`, the
//! linear interpolant `L` of `f` satisfies `|f - L| <= M R² / 2`: `f + (M/2)|p - m|²` is convex,
//! so it lies below its own interpolant, which gives `f - L <= (M/2)(R² - |p - m|²) <= M R² / 2`;
//! the same with `f - (M/2)|p - m|²` (concave) bounds `L - f`. The vertical gap `|f - L|` also
//! bounds the distance from a mesh point to the surface (the point straight above or below it
//! lies on the surface). So the **chord bound** of a mesh is `B = M max_T R_T² / 2`, computed
//! from the exact triangles of the mesh (all triangles of a band are congruent).
//!
//! Density: for near-square quads of spacing `s`, each half is a right triangle with
//! `R = s / √2`, so `B ≈ M s² / 4`; we start from `s = 2 √(ε / M)` for the requested `ε`,
//! compute `B` exactly over every band's triangle shapes, and shrink `s` until `B <= ε`. `M` is the maximum of the closed-form
//! second derivatives over 8192 radii, times 1.001 (the derivatives are smooth polynomials and
//! conic terms, so the sampling error is far below that margin). Odd aspheres (without the cone
//! term, whose vertex point has no bounded curvature) and Q-type aspheres are meshed the same
//! way, their `f_uu` the central difference of the closed-form slope.
//!
//! # Footprints
//!
//! A cross-check traces a few thousand rays, and on a large surface they meet a small part of
//! the disk. [`Mesh::with_footprint`] keeps only the sectors (a band's triangles between two
//! neighbouring angles) within one ring spacing of each ray's path through the mesh's slab, up
//! to just past its analytic hit: the triangles a ray can meet first. The kept triangles are
//! the whole mesh's, so the chord bound is the whole mesh's and each ray's first hit is the one
//! the whole mesh gives it.
//!
//! Vertices are stored in `f32` (what Embree takes) either in the surface's local frame (the
//! default: coordinates stay below the aperture radius, so the rounding is ~1e-6 mm) or in the
//! global frame (the perturbed placement `x = pos + R x_local`; at z = 50 mm one f32 ulp is
//! ~4e-6 mm). [`Mesh::deviation`] measures what the f32 mesh actually does.

use tolray::error::{Error, Result};
use tolray::lens::{Shape, SurfaceKind, SurfaceRow};
use tolray::math::Vec3;
use tolray::trace::reference::{intersect_local, q_sag, surface_sag, surface_sag_xy};

/// Where mesh vertices (and the rays traced against them) are expressed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Frame {
    /// The surface's own (perturbed) frame: small coordinates, small f32 rounding.
    #[default]
    Local,
    /// The global frame: the surface's vertices moved by its perturbed placement.
    Global,
}

/// Most triangles a mesh may have (a guard against absurd chord bounds).
pub const MAX_TRIANGLES: usize = 40_000_000;

/// A tessellated surface.
#[derive(Clone, Debug)]
pub struct Mesh {
    /// Radius of the disk the mesh covers (the clear semi-aperture, or less), mm.
    pub disk_mm: f64,
    /// Surface index.
    pub surface: usize,
    /// Frame of `vertices` and `normals`.
    pub frame: Frame,
    /// Number of rings around the centre vertex.
    pub rings: usize,
    /// Vertices of the outer ring (a multiple of 8).
    pub segments: usize,
    /// Vertices of each ring, centre excluded (ring 1 first).
    pub ring_counts: Vec<usize>,
    /// First triangle of each band (the centre fan is band 0), plus the total at the end.
    pub band_starts: Vec<usize>,
    /// Radius of the outer ring, mm.
    pub radius_mm: f64,
    /// Vertices, mm.
    pub vertices: Vec<[f32; 3]>,
    /// Analytic unit normals at the vertices (+z-ish in the local frame).
    pub normals: Vec<Vec3<f64>>,
    /// Triangles (vertex indices).
    pub triangles: Vec<[u32; 3]>,
    /// Triangles of the whole disk's mesh (more than `triangles.len()` for a footprint mesh,
    /// [`Mesh::with_footprint`]).
    pub layout_triangles: usize,
    /// `M`: largest second directional derivative of the sag over the mesh's disk, 1/mm.
    pub max_second_derivative: f64,
    /// Largest slope `|∇f|` over the mesh's disk.
    pub max_slope: f64,
    /// The chord bound `B = M max R² / 2`, mm: no point of the (exact) mesh is farther than
    /// this from the surface, measured along z of the local frame (hence also along the normal).
    pub chord_bound_mm: f64,
    /// The bound that was asked for, mm (`chord_bound_mm <= requested_mm`).
    pub requested_mm: f64,
    /// Lowest and highest sag of the whole disk's vertices, local frame, mm.
    pub z_range_mm: [f64; 2],
}

/// Sag `z` and `dz/du` at `u = r²` of a rotationally symmetric surface (an even asphere, an odd
/// asphere without the cone term, a Q-type asphere), from the reference tracer's definitions.
fn radial_sag(row: &SurfaceRow<f64>, u: f64) -> Option<(f64, f64)> {
    match row.shape {
        Shape::Qbfs { .. } | Shape::Qcon { .. } => q_sag(row, u),
        Shape::Odd => {
            let r = u.sqrt();
            let (z, _, fr) = surface_sag_xy(row, 0.0, r)?;
            // dz/du = f_r / (2 r); at the vertex the limit, c/2 + β2 (no cone term here).
            let fu = if r > 0.0 {
                fr / (2.0 * r)
            } else {
                row.c / 2.0 + row.asph[1]
            };
            Some((z, fu))
        }
        _ => surface_sag(row, u),
    }
}

/// Second-derivative data of a surface's sag at `u = r²`: (`2 f_u`, `f_rr`, slope `f_r`).
/// Closed forms for the even asphere; for the other rotational shapes `f_uu` is the central
/// difference of the closed-form `f_u` (relative step 1e-5: its error, ~1e-10 of `f_uu` for
/// these smooth functions, is far inside the bound's 1.001 margin).
fn derivatives(row: &SurfaceRow<f64>, u: f64) -> Option<(f64, f64, f64)> {
    if row.shape != Shape::Even {
        let (_, fu) = radial_sag(row, u)?;
        let h = 1e-5 * (u + 1e-2);
        let fuu = if u > h {
            (radial_sag(row, u + h)?.1 - radial_sag(row, u - h)?.1) / (2.0 * h)
        } else {
            (radial_sag(row, u + h)?.1 - fu) / h
        };
        return Some((2.0 * fu, 2.0 * fu + 4.0 * u * fuu, 2.0 * u.sqrt() * fu));
    }
    let (c, k1) = (row.c, row.k1);
    let arg = 1.0 - k1 * c * c * u;
    if arg <= 0.0 {
        return None;
    }
    let q = arg.sqrt();
    let mut fu = c / (2.0 * q);
    let mut fuu = c * k1 * c * c / (4.0 * q * q * q);
    for (j, a) in row.asph[..row.n_asph].iter().enumerate() {
        let j = j as i32;
        fu += (j + 1) as f64 * a * u.powi(j);
        if j >= 1 {
            fuu += ((j + 1) * j) as f64 * a * u.powi(j - 1);
        }
    }
    Some((2.0 * fu, 2.0 * fu + 4.0 * u * fuu, 2.0 * u.sqrt() * fu))
}

/// `M` and the largest slope over radii `[0, r]`.
fn curvature_bounds(row: &SurfaceRow<f64>, r: f64, surface: usize) -> Result<(f64, f64)> {
    const N: usize = 8192;
    let (mut m, mut slope) = (0.0f64, 0.0f64);
    for k in 0..=N {
        let rr = r * k as f64 / N as f64;
        let (t, rad, s) = derivatives(row, rr * rr).ok_or_else(|| {
            Error::invalid(format!(
                "surface {surface}: the sag is undefined at r = {rr:.4} mm, inside the \
                 tessellated disk (radius {r:.4} mm)"
            ))
        })?;
        m = m.max(t.abs()).max(rad.abs());
        slope = slope.max(s.abs());
    }
    Ok((m * 1.001, slope))
}

/// Radius of the smallest disk holding the 2-D triangle `a, b, c` (the `R` of the chord bound).
///
/// ```
/// use tolray_embree::mesh::enclosing_radius;
/// // Right triangle: half the hypotenuse.
/// let r = enclosing_radius([0.0, 0.0], [2.0, 0.0], [0.0, 2.0]);
/// assert!((r - 2f64.sqrt()).abs() < 1e-15);
/// // Equilateral with side 1: 1/sqrt(3).
/// let r = enclosing_radius([0.0, 0.0], [1.0, 0.0], [0.5, 0.75f64.sqrt()]);
/// assert!((r - 1.0 / 3f64.sqrt()).abs() < 1e-15);
/// // Obtuse: half the longest edge.
/// let r = enclosing_radius([0.0, 0.0], [4.0, 0.0], [2.0, 0.5]);
/// assert!((r - 2.0).abs() < 1e-15);
/// ```
#[must_use]
pub fn enclosing_radius(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    let d2 = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
    let mut e = [d2(b, c), d2(c, a), d2(a, b)];
    e.sort_by(f64::total_cmp);
    if e[2] >= e[0] + e[1] {
        // Right or obtuse: the longest edge is a diameter.
        return 0.5 * e[2].sqrt();
    }
    let area2 = ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])).abs();
    (e[0] * e[1] * e[2]).sqrt() / (2.0 * area2)
}

/// Vertices on a ring of radius `r` for a spacing `s`: the fewest `8 · 2^j` with
/// `2π r / n <= s`.
fn ring_count(r: f64, s: f64) -> usize {
    let mut n = 8usize;
    while std::f64::consts::TAU * r / n as f64 > s && n < 1 << 30 {
        n *= 2;
    }
    n
}

/// The rings of a layout: vertex counts of rings `1..=rings` and the outer radius.
fn layout(a: f64, s: f64) -> (Vec<usize>, f64) {
    let n_out = ring_count(a + 2.0 * s, s);
    let radius = (a + s) / (std::f64::consts::PI / n_out as f64).cos();
    let rings = ((radius / s).ceil() as usize).max(1);
    let dr = radius / rings as f64;
    let mut counts: Vec<usize> = (1..=rings).map(|i| ring_count(i as f64 * dr, s)).collect();
    if let Some(last) = counts.last_mut() {
        *last = (*last).max(n_out);
    }
    // Neighbouring rings differ by at most a doubling (which `band` triangulates).
    for i in (0..counts.len().saturating_sub(1)).rev() {
        counts[i] = counts[i].max(counts[i + 1] / 2);
    }
    (counts, radius)
}

/// Point `k` of `n` on a ring of radius `r`, with exact zeros on the axes.
fn ring_point(r: f64, k: usize, n: usize) -> [f64; 2] {
    let k = k % n;
    let (sn, cs) = if (4 * k).is_multiple_of(n) {
        let q = 4 * k / n;
        ([0.0, 1.0, 0.0, -1.0][q], [1.0, 0.0, -1.0, 0.0][q])
    } else {
        (std::f64::consts::TAU * k as f64 / n as f64).sin_cos()
    };
    [r * cs, r * sn]
}

/// Sectors of band `i` of a layout (`counts`: vertices per ring, ring 1 first): the centre fan
/// has one sector per vertex of ring 1, every other band one per vertex of its inner ring.
/// Sector `k` spans the angles `[2πk/K, 2π(k+1)/K]`, and its triangles lie inside that wedge.
fn sectors(counts: &[usize], i: usize) -> usize {
    if i == 0 {
        counts[0]
    } else {
        counts[i - 1]
    }
}

/// Triangles of sector `k` of the band between an inner ring of `ni` vertices (0: the centre
/// vertex) and an outer ring of `no`, as `(ring, k)` pairs (ring 0 inner, 1 outer) that the
/// caller turns into indices: one (centre fan), two (equal counts: a quad split along the same
/// diagonal everywhere) or three (the count doubles).
fn sector(ni: usize, no: usize, k: usize) -> ([[(usize, usize); 3]; 3], usize) {
    let none = [(0, 0); 3];
    if ni == 0 {
        ([[(0, 0), (1, k), (1, k + 1)], none, none], 1)
    } else if ni == no {
        (
            [
                [(0, k), (1, k), (1, k + 1)],
                [(0, k), (1, k + 1), (0, k + 1)],
                none,
            ],
            2,
        )
    } else {
        (
            [
                [(0, k), (1, 2 * k), (1, 2 * k + 1)],
                [(0, k), (1, 2 * k + 1), (0, k + 1)],
                [(0, k + 1), (1, 2 * k + 1), (1, 2 * k + 2)],
            ],
            3,
        )
    }
}

/// Triangles of the whole layout `counts` (vertices per ring, ring 1 first).
fn layout_triangles(counts: &[usize]) -> usize {
    (0..counts.len())
        .map(|i| {
            let ni = if i == 0 { 0 } else { counts[i - 1] };
            sectors(counts, i) * sector(ni, counts[i], 0).1
        })
        .sum()
}

/// Which sectors of each band a footprint mesh keeps.
struct Marks {
    /// Per band, one flag per sector.
    bands: Vec<Vec<bool>>,
    /// Per band, the lowest and highest height of its triangles (those of its two rings, whose
    /// vertices they interpolate), widened by the vertices' f32 rounding, mm.
    heights: Vec<[f64; 2]>,
    /// Ring spacing, mm.
    dr: f64,
}

impl Marks {
    fn new(counts: &[usize], dr: f64, ring_z: &[f64]) -> Marks {
        let pad = 1e-5 + 1e-6 * ring_z.iter().fold(0.0f64, |a, z| a.max(z.abs()));
        Marks {
            bands: (0..counts.len())
                .map(|i| vec![false; sectors(counts, i)])
                .collect(),
            heights: ring_z
                .windows(2)
                .map(|w| [w[0].min(w[1]) - pad, w[0].max(w[1]) + pad])
                .collect(),
            dr,
        }
    }

    /// Marks every sector holding a point within `rad` of `(x, y)` whose band's heights meet
    /// `z` (the heights at which the ray passes within `rad`). Band `i` spans radii from
    /// `i dr cos(π/K)` (its inner ring's chords, `K >= 8`) to `(i + 1) dr`; a point within `rad`
    /// of `(x, y)`, at radius `r > rad`, lies within `asin(rad / r)` of its angle.
    fn disk(&mut self, x: f64, y: f64, rad: f64, z: [f64; 2]) {
        let r = (x * x + y * y).sqrt();
        let lo = (r - rad).max(0.0) / self.dr;
        let hi = (r + rad) / (self.dr * (std::f64::consts::PI / 8.0).cos());
        if !(lo < self.bands.len() as f64 && hi.is_finite()) {
            return;
        }
        // Both are non-negative: truncation is the floor.
        let (lo, hi) = (lo as usize, (hi as usize).min(self.bands.len() - 1));
        let mut angles = None;
        for (band, h) in self.bands[lo..=hi].iter_mut().zip(&self.heights[lo..=hi]) {
            if z[1] < h[0] || z[0] > h[1] {
                continue;
            }
            if r <= rad {
                band.fill(true);
                continue;
            }
            let (theta, alpha) = *angles.get_or_insert_with(|| (y.atan2(x), (rad / r).asin()));
            let k = band.len();
            let w = std::f64::consts::TAU / k as f64;
            let (a, b) = (((theta - alpha) / w).floor(), ((theta + alpha) / w).floor());
            let span = b - a + 1.0;
            if span >= k as f64 {
                band.fill(true);
                continue;
            }
            let mut s = (a as i64).rem_euclid(k as i64) as usize;
            for _ in 0..span as usize {
                band[s] = true;
                s += 1;
                if s == k {
                    s = 0;
                }
            }
        }
    }

    /// Marks what the ray `p + t d` (local frame) can meet on a mesh whose vertices lie
    /// between `z_lo` and `z_hi`, out to `radius`: its path from where it enters that slab to one
    /// ring spacing past its analytic hit on `row` (through the whole slab when it has none),
    /// with a margin of one spacing, in the bands whose heights the ray passes near. A mesh
    /// keeping these sectors gives the ray the same first hit as the whole disk's mesh,
    /// whenever that hit lies on this path.
    fn ray(&mut self, row: &SurfaceRow<f64>, p: Vec3<f64>, d: Vec3<f64>, z: [f64; 2], radius: f64) {
        if d.z == 0.0 || !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return;
        }
        let dr = self.dr;
        let dxy = d.x.hypot(d.y);
        if dxy == 0.0 {
            // Along the axis of the local frame: one point, every height.
            self.disk(p.x, p.y, dr, [f64::NEG_INFINITY, f64::INFINITY]);
            return;
        }
        let (t1, t2) = ((z[0] - p.z) / d.z, (z[1] - p.z) / d.z);
        let (t_in, t_out) = (t1.min(t2), t1.max(t2));
        let t_end = match intersect_local(row, p, d) {
            Some((t, _)) => t + dr / dxy,
            None => t_out,
        };
        // Clip to the disk of radius `radius + dr` in x, y.
        let rc = radius + dr;
        let (a, b, c) = (
            dxy * dxy,
            2.0 * (p.x * d.x + p.y * d.y),
            p.x * p.x + p.y * p.y - rc * rc,
        );
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return;
        }
        let q = disc.sqrt();
        let lo = t_in.max((-b - q) / (2.0 * a));
        let hi = t_end.max(t_in).min((-b + q) / (2.0 * a));
        if !(lo <= hi) {
            return;
        }
        // Samples every `h` <= dr of x, y; each marks a disk of radius dr + h/2 in the bands
        // whose heights meet the ray's heights within that distance.
        let len = (hi - lo) * dxy;
        let n = (len / dr).ceil().max(1.0) as usize;
        let rad = dr + 0.5 * len / n as f64;
        let dz = rad * d.z.abs() / dxy;
        for j in 0..=n {
            let t = lo + (hi - lo) * j as f64 / n as f64;
            let zt = p.z + d.z * t;
            self.disk(p.x + d.x * t, p.y + d.y * t, rad, [zt - dz, zt + dz]);
        }
    }
}

/// Largest enclosing radius over the triangles of a layout (the first sector of each band: the
/// others are rotated copies).
fn max_enclosing_radius(counts: &[usize], radius: f64) -> f64 {
    let dr = radius / counts.len() as f64;
    let mut rmax = 0.0f64;
    for i in 0..counts.len() {
        let ni = if i == 0 { 0 } else { counts[i - 1] };
        let no = counts[i];
        let pt = |(ring, k): (usize, usize)| {
            let (r, n) = if ring == 0 {
                (i as f64 * dr, ni.max(1))
            } else {
                ((i + 1) as f64 * dr, no)
            };
            ring_point(r, k, n)
        };
        let (tris, n) = sector(ni, no, 0);
        for t in &tris[..n] {
            rmax = rmax.max(enclosing_radius(pt(t[0]), pt(t[1]), pt(t[2])));
        }
    }
    rmax
}

/// The layout of a mesh before it is built ([`Mesh::plan`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Radius of the tessellated disk, mm.
    pub disk_mm: f64,
    /// Points per ring, innermost first.
    pub counts: Vec<usize>,
    /// Radius of the outermost ring, mm.
    pub radius: f64,
    /// Largest second directional derivative of the sag over the disk, 1/mm.
    pub m: f64,
    /// Largest slope of the sag.
    pub slope: f64,
    /// The chord bound the layout reaches, mm.
    pub bound: f64,
}

impl Plan {
    /// Number of triangles.
    pub fn triangles(&self) -> usize {
        layout_triangles(&self.counts)
    }
}

impl Mesh {
    /// Tessellates surface `surface` (`row`, compiled in `f64`, possibly perturbed) so that the
    /// mesh is within `chord_mm` of the surface, in `frame`.
    ///
    /// # Errors
    /// [`tolray::ErrorKind::Argument`] for a non-positive or non-finite `chord_mm` or a mesh that
    /// would exceed [`MAX_TRIANGLES`]; [`tolray::ErrorKind::Invalid`] if the sag is undefined
    /// (beyond a conic's rim) inside the tessellated disk.
    pub fn new(row: &SurfaceRow<f64>, surface: usize, chord_mm: f64, frame: Frame) -> Result<Mesh> {
        Mesh::with_radius(row, surface, row.ap2.sqrt(), chord_mm, frame)
    }

    /// As [`Mesh::new`], covering the disk of radius `radius_mm` (at most the farthest a ray
    /// can pass the surface's hard aperture, and inside a conic's rim) instead of the
    /// semi-diameter's disk.
    ///
    /// # Errors
    /// As [`Mesh::new`]; also [`tolray::ErrorKind::Argument`] for a radius that is not positive.
    pub fn with_radius(
        row: &SurfaceRow<f64>,
        surface: usize,
        radius_mm: f64,
        chord_mm: f64,
        frame: Frame,
    ) -> Result<Mesh> {
        Mesh::with_footprint(row, surface, radius_mm, chord_mm, frame, None)
    }

    /// As [`Mesh::with_radius`], keeping only the part of the disk's mesh that the rays
    /// `footprint` (origin and direction in the surface's local frame, mm) can meet: every
    /// triangle within one ring spacing of a ray's path from where it enters the mesh's slab
    /// (`z_range_mm` of the whole disk's mesh) to one spacing past its analytic hit. Kept
    /// triangles are the whole mesh's own (same vertices, same order within a band), so each of
    /// these rays meets the footprint mesh where it meets the whole one whenever that hit lies
    /// on its path; `chord_bound_mm`, `z_range_mm` and the layout fields are the whole mesh's.
    /// A footprint that marks nothing keeps the centre fan's first triangle (a scene needs
    /// one). `None` builds the whole disk, as does a footprint of so many rays that their
    /// marked neighbourhoods (about `π (1.5 Δr)²` each) would add up to the disk's area: there
    /// the marking would cost more than the triangles it saves.
    ///
    /// # Errors
    /// As [`Mesh::with_radius`].
    pub fn with_footprint(
        row: &SurfaceRow<f64>,
        surface: usize,
        radius_mm: f64,
        chord_mm: f64,
        frame: Frame,
        footprint: Option<&[(Vec3<f64>, Vec3<f64>)]>,
    ) -> Result<Mesh> {
        let cone = row.shape == Shape::Odd && row.asph[0] != 0.0;
        // (An ideal thin lens is a plane: its row's sag is 0.)
        if !matches!(
            row.shape,
            Shape::Even
                | Shape::Odd
                | Shape::Qbfs { .. }
                | Shape::Qcon { .. }
                | Shape::Paraxial { .. }
        ) || cone
        {
            return Err(Error::invalid(format!(
                "surface {surface}: the Embree check tessellates rotationally symmetric surfaces with a bounded curvature (rings of equal sag); this surface is {}",
                match row.shape {
                    Shape::Odd => "an odd asphere with a cone term (r^1): a point at the vertex",
                    Shape::Zernike { .. } => "a Zernike sag surface",
                    _ => "a toroid",
                }
            )));
        }
        let Plan {
            disk_mm: a,
            counts,
            radius,
            m,
            slope,
            bound,
        } = Mesh::plan(row, surface, radius_mm, chord_mm)?;
        let rings = counts.len();
        let dr = radius / rings as f64;
        let mut first = vec![0usize, 1];
        for &n in &counts {
            first.push(first.last().copied().unwrap_or(0) + n);
        }
        // The sag depends on the radius only: once per ring (ring 0 is the centre vertex).
        let mut ring_sag = Vec::with_capacity(rings + 1);
        for i in 0..=rings {
            let r = i as f64 * dr;
            ring_sag.push(radial_sag(row, r * r).ok_or_else(|| {
                Error::invalid(format!(
                    "surface {surface}: the sag is undefined at r = {r:.4} mm"
                ))
            })?);
        }
        let z_lo = ring_sag.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let z_hi = ring_sag
            .iter()
            .map(|p| p.0)
            .fold(f64::NEG_INFINITY, f64::max);
        // Marking costs about as much per ray as building its share of the disk: a footprint
        // pays only when the rays' marked disks (radius ~1.5 spacings) cover less of the disk
        // than it has; otherwise the whole disk is built (the same hits).
        let footprint =
            footprint.filter(|rays| rays.len() as f64 * (1.5 * dr).powi(2) < radius * radius);
        let marks = footprint.map(|rays| {
            let ring_z: Vec<f64> = ring_sag.iter().map(|p| p.0).collect();
            let mut marks = Marks::new(&counts, dr, &ring_z);
            for &(p, d) in rays {
                marks.ray(row, p, d, [z_lo, z_hi], radius);
            }
            if !marks.bands.iter().flatten().any(|&m| m) {
                marks.bands[0][0] = true;
            }
            marks
        });
        let vertex = |ring: usize, k: usize| -> (Vec3<f64>, Vec3<f64>) {
            let (z, dz) = ring_sag[ring];
            let [x, y] = if ring == 0 {
                [0.0, 0.0]
            } else {
                ring_point(ring as f64 * dr, k, counts[ring - 1])
            };
            (
                Vec3::new(x, y, z),
                Vec3::new(-2.0 * x * dz, -2.0 * y * dz, 1.0).normalized(),
            )
        };
        let nv = first[rings + 1];
        let layout_triangles = layout_triangles(&counts);
        let mut local = Vec::new();
        let mut normals = Vec::new();
        // Vertex numbers: the whole mesh's, or (footprint) in order of first use.
        let mut remap = Vec::new();
        match marks {
            None => {
                local.reserve_exact(nv);
                normals.reserve_exact(nv);
                for i in 0..=rings {
                    let n = if i == 0 { 1 } else { counts[i - 1] };
                    for k in 0..n {
                        let (p, q) = vertex(i, k);
                        local.push(p);
                        normals.push(q);
                    }
                }
            }
            Some(_) => remap = vec![u32::MAX; nv],
        }
        let mut triangles = Vec::with_capacity(if marks.is_none() { layout_triangles } else { 0 });
        let mut band_starts = Vec::with_capacity(rings + 1);
        for i in 0..rings {
            band_starts.push(triangles.len());
            let ni = if i == 0 { 0 } else { counts[i - 1] };
            let no = counts[i];
            for k in 0..sectors(&counts, i) {
                if marks.as_ref().is_some_and(|m| !m.bands[i][k]) {
                    continue;
                }
                let (tris, nt) = sector(ni, no, k);
                for t in &tris[..nt] {
                    let mut idx = [0u32; 3];
                    for (slot, &(ring, kk)) in idx.iter_mut().zip(t) {
                        let (r, n) = if ring == 0 {
                            (i, ni.max(1))
                        } else {
                            (i + 1, no)
                        };
                        let whole = first[r] + kk % n;
                        *slot = if marks.is_none() {
                            whole as u32
                        } else {
                            if remap[whole] == u32::MAX {
                                remap[whole] = local.len() as u32;
                                let (p, q) = vertex(r, kk % n);
                                local.push(p);
                                normals.push(q);
                            }
                            remap[whole]
                        };
                    }
                    triangles.push(idx);
                }
            }
        }
        band_starts.push(triangles.len());
        drop(remap);
        let (vertices, normals) = match frame {
            Frame::Local => (
                local
                    .iter()
                    .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                    .collect(),
                normals,
            ),
            Frame::Global => (
                local
                    .iter()
                    .map(|&p| {
                        let g = row.rot.apply(p) + row.pos;
                        [g.x as f32, g.y as f32, g.z as f32]
                    })
                    .collect(),
                normals.into_iter().map(|n| row.rot.apply(n)).collect(),
            ),
        };
        Ok(Mesh {
            disk_mm: a,
            surface,
            frame,
            rings,
            segments: counts[rings - 1],
            ring_counts: counts,
            band_starts,
            radius_mm: radius,
            vertices,
            normals,
            triangles,
            layout_triangles,
            max_second_derivative: m,
            max_slope: slope,
            chord_bound_mm: bound,
            requested_mm: chord_mm,
            z_range_mm: [z_lo, z_hi],
        })
    }

    /// The ring layout [`Mesh::with_radius`] would build, without building it: the triangle
    /// count ([`Plan::triangles`]) and the bound it reaches. Costs a few curvature samplings, so
    /// a whole check can refuse an infeasible chord bound before meshing anything.
    ///
    /// # Errors
    /// As [`Mesh::with_radius`].
    pub fn plan(
        row: &SurfaceRow<f64>,
        surface: usize,
        radius_mm: f64,
        chord_mm: f64,
    ) -> Result<Plan> {
        if !(chord_mm > 0.0 && chord_mm.is_finite()) {
            return Err(Error::argument(format!(
                "chord bound {chord_mm} mm: must be positive"
            )));
        }
        let rim2 = row.k1 * row.c * row.c;
        let rim = if rim2 > 0.0 {
            (1.0 - 1e-12) / rim2.sqrt()
        } else {
            f64::INFINITY
        };
        let a = radius_mm.min(row.clip.reach_mm).min(rim);
        if !(a > 0.0 && a.is_finite()) {
            return Err(Error::argument(format!(
                "surface {surface}: a disk of radius {a} mm cannot be tessellated"
            )));
        }
        let flat = row.kind == SurfaceKind::Plane
            || (row.c == 0.0 && row.asph[..row.n_asph].iter().all(|&x| x == 0.0));
        // Curvature over a generous disk first, to size the spacing.
        let (m0, _) = curvature_bounds(row, a * 1.05, surface).or_else(|_| {
            curvature_bounds(row, a, surface) // a conic rim just outside the aperture
        })?;
        let mut s = if flat || m0 == 0.0 {
            a / 4.0
        } else {
            2.0 * (chord_mm / m0).sqrt() * 0.98
        };
        s = s.min(a / 4.0);
        let (mut counts, mut radius, mut m, mut slope, mut bound);
        let mut tries = 0;
        loop {
            // About 2 triangles per s² of the disk: refuse before allocating the rings.
            let estimate = 2.0 * std::f64::consts::PI * ((a + 2.0 * s) / s).powi(2);
            if !(estimate <= 2.0 * MAX_TRIANGLES as f64) {
                let why = if a >= rim * (1.0 - 1e-9) {
                    format!(
                        " (the disk reaches the conic's rim at r = {rim:.4} mm, where the \
                         surface turns vertical: no bound can mesh it; give the surface a hard \
                         aperture or trace a smaller pupil)"
                    )
                } else {
                    "; choose a larger bound".to_string()
                };
                return Err(Error::argument(format!(
                    "surface {surface}: a chord bound of {chord_mm:e} mm needs about {estimate:.2e} \
                     triangles (more than {MAX_TRIANGLES}) over a disk of radius {a:.4} mm{why}"
                )));
            }
            (counts, radius) = layout(a, s);
            let tri = layout_triangles(&counts);
            if tri > MAX_TRIANGLES {
                return Err(Error::argument(format!(
                    "surface {surface}: a chord bound of {chord_mm:e} mm needs about {tri} \
                     triangles (more than {MAX_TRIANGLES}); choose a larger bound"
                )));
            }
            (m, slope) = curvature_bounds(row, radius, surface)?;
            let r = max_enclosing_radius(&counts, radius);
            bound = 0.5 * m * r * r;
            tries += 1;
            if bound <= chord_mm || tries > 20 {
                break;
            }
            s *= 0.97 * (chord_mm / bound).sqrt();
        }
        if bound > chord_mm {
            return Err(Error::numerical(format!(
                "surface {surface}: could not reach a chord bound of {chord_mm:e} mm"
            )));
        }
        Ok(Plan {
            disk_mm: a,
            counts,
            radius,
            m,
            slope,
            bound,
        })
    }

    /// Vertex `i` as an `f64` point in the surface's local frame (undoing the global placement
    /// for [`Frame::Global`] meshes, so that their f32 rounding shows).
    pub fn local_vertex(&self, row: &SurfaceRow<f64>, i: usize) -> Vec3<f64> {
        let v = self.vertices[i];
        let p = Vec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
        match self.frame {
            Frame::Local => p,
            Frame::Global => row.rot.apply_t(p - row.pos),
        }
    }

    /// The mesh's actual largest vertical distance from the surface (local z, mm), measured on
    /// sample points of the `f32` mesh: 45 barycentric grid points per triangle plus the
    /// circumcentre when it lies inside, on every triangle shape of every band at eight angles.
    pub fn deviation(&self, row: &SurfaceRow<f64>) -> f64 {
        let mut worst = 0.0f64;
        let mut tri_ids = Vec::new();
        for w in self.band_starts.windows(2) {
            let (start, len) = (w[0], w[1] - w[0]);
            if len == 0 {
                continue; // a band a footprint mesh leaves out
            }
            // Every triangle shape of the band (its first three) at eight angles.
            for q in 0..8 {
                for j in 0..3 {
                    tri_ids.push(start + (q * len / 8 + j) % len);
                }
            }
        }
        for t in tri_ids {
            let [i0, i1, i2] = self.triangles[t];
            let p = [
                self.local_vertex(row, i0 as usize),
                self.local_vertex(row, i1 as usize),
                self.local_vertex(row, i2 as usize),
            ];
            let mut check = |w: [f64; 3]| {
                let q = p[0] * w[0] + p[1] * w[1] + p[2] * w[2];
                if let Some((z, _)) = radial_sag(row, q.x * q.x + q.y * q.y) {
                    worst = worst.max((q.z - z).abs());
                }
            };
            const N: usize = 8;
            for i in 0..=N {
                for j in 0..=N - i {
                    let (a, b) = (i as f64 / N as f64, j as f64 / N as f64);
                    check([1.0 - a - b, a, b]);
                }
            }
            if let Some(w) = circumcentre_weights(p) {
                check(w);
            }
        }
        worst
    }
}

/// Barycentric weights of the (x, y) circumcentre of a triangle, if it lies inside.
fn circumcentre_weights(p: [Vec3<f64>; 3]) -> Option<[f64; 3]> {
    let (ax, ay) = (p[0].x, p[0].y);
    let (bx, by) = (p[1].x - ax, p[1].y - ay);
    let (cx, cy) = (p[2].x - ax, p[2].y - ay);
    let d = 2.0 * (bx * cy - by * cx);
    if d == 0.0 {
        return None;
    }
    let (b2, c2) = (bx * bx + by * by, cx * cx + cy * cy);
    let ux = (cy * b2 - by * c2) / d;
    let uy = (bx * c2 - cx * b2) / d;
    // Solve u = s b + t c.
    let det = bx * cy - by * cx;
    let s = (ux * cy - uy * cx) / det;
    let t = (bx * uy - by * ux) / det;
    (s >= 0.0 && t >= 0.0 && s + t <= 1.0).then_some([1.0 - s - t, s, t])
}
