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
//! conic terms, so the sampling error is far below that margin).
//!
//! Vertices are stored in `f32` (what Embree takes) either in the surface's local frame (the
//! default: coordinates stay below the aperture radius, so the rounding is ~1e-6 mm) or in the
//! global frame (the perturbed placement `x = pos + R x_local`; at z = 50 mm one f32 ulp is
//! ~4e-6 mm). [`Mesh::deviation`] measures what the f32 mesh actually does.

use crate::error::{Error, Result};
use crate::lens::{SurfaceKind, SurfaceRow};
use crate::math::Vec3;
use crate::trace::reference::surface_sag;

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
    /// `M`: largest second directional derivative of the sag over the mesh's disk, 1/mm.
    pub max_second_derivative: f64,
    /// Largest slope `|∇f|` over the mesh's disk.
    pub max_slope: f64,
    /// The chord bound `B = M max R² / 2`, mm: no point of the (exact) mesh is farther than
    /// this from the surface, measured along z of the local frame (hence also along the normal).
    pub chord_bound_mm: f64,
    /// The bound that was asked for, mm (`chord_bound_mm <= requested_mm`).
    pub requested_mm: f64,
    /// Lowest and highest sag of the vertices, local frame, mm.
    pub z_range_mm: [f64; 2],
}

/// Second-derivative data of a surface's sag at `u = r²`: (`2 f_u`, `f_rr`, slope `f_r`).
fn derivatives(row: &SurfaceRow<f64>, u: f64) -> Option<(f64, f64, f64)> {
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

/// Radius of the smallest disk holding the 2-D triangle `a, b, c`.
fn enclosing_radius(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
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
    let (sn, cs) = if (4 * k) % n == 0 {
        let q = 4 * k / n;
        ([0.0, 1.0, 0.0, -1.0][q], [1.0, 0.0, -1.0, 0.0][q])
    } else {
        (std::f64::consts::TAU * k as f64 / n as f64).sin_cos()
    };
    [r * cs, r * sn]
}

/// Triangles of the band between ring `inner` (count `ni`, first vertex `oi`; ring 0 is the
/// centre vertex) and the next ring (count `no`, first vertex `oo`), as local vertex numbers
/// `(ring, k)` pairs are turned into indices by the caller.
fn band(ni: usize, no: usize) -> Vec<[(usize, usize); 3]> {
    let mut t = Vec::new();
    if ni == 0 {
        for k in 0..no {
            t.push([(0, 0), (1, k), (1, k + 1)]);
        }
    } else if ni == no {
        for k in 0..ni {
            t.push([(0, k), (1, k), (1, k + 1)]);
            t.push([(0, k), (1, k + 1), (0, k + 1)]);
        }
    } else {
        for k in 0..ni {
            t.push([(0, k), (1, 2 * k), (1, 2 * k + 1)]);
            t.push([(0, k), (1, 2 * k + 1), (0, k + 1)]);
            t.push([(0, k + 1), (1, 2 * k + 1), (1, 2 * k + 2)]);
        }
    }
    t
}

/// Largest enclosing radius over the triangles of a layout (the first one or two segments of
/// each band: the others are rotated copies).
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
        for t in band(ni, no).iter().take(3) {
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
        2 * self.counts.iter().sum::<usize>()
    }
}

impl Mesh {
    /// Tessellates surface `surface` (`row`, compiled in `f64`, possibly perturbed) so that the
    /// mesh is within `chord_mm` of the surface, in `frame`.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for a non-positive or non-finite `chord_mm` or a mesh that
    /// would exceed [`MAX_TRIANGLES`]; [`crate::ErrorKind::Invalid`] if the sag is undefined
    /// (beyond a conic's rim) inside the tessellated disk.
    pub fn new(row: &SurfaceRow<f64>, surface: usize, chord_mm: f64, frame: Frame) -> Result<Mesh> {
        Mesh::with_radius(row, surface, row.ap2.sqrt(), chord_mm, frame)
    }

    /// As [`Mesh::new`], covering the disk of radius `radius_mm` (at most the farthest a ray
    /// can pass the surface's hard aperture, and inside a conic's rim) instead of the
    /// semi-diameter's disk.
    ///
    /// # Errors
    /// As [`Mesh::new`]; also [`crate::ErrorKind::Argument`] for a radius that is not positive.
    pub fn with_radius(
        row: &SurfaceRow<f64>,
        surface: usize,
        radius_mm: f64,
        chord_mm: f64,
        frame: Frame,
    ) -> Result<Mesh> {
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
        let nv = first[rings + 1];
        let mut local = Vec::with_capacity(nv);
        let mut normals = Vec::with_capacity(nv);
        for i in 0..=rings {
            let n = if i == 0 { 1 } else { counts[i - 1] };
            for k in 0..n {
                let [x, y] = if i == 0 {
                    [0.0, 0.0]
                } else {
                    ring_point(i as f64 * dr, k, n)
                };
                let u = x * x + y * y;
                let (z, dz) = surface_sag(row, u).ok_or_else(|| {
                    Error::invalid(format!(
                        "surface {surface}: the sag is undefined at r = {:.4} mm",
                        u.sqrt()
                    ))
                })?;
                local.push(Vec3::new(x, y, z));
                normals.push(Vec3::new(-2.0 * x * dz, -2.0 * y * dz, 1.0).normalized());
            }
        }
        let mut triangles = Vec::with_capacity(2 * counts.iter().sum::<usize>());
        let mut band_starts = Vec::with_capacity(rings + 1);
        for i in 0..rings {
            band_starts.push(triangles.len());
            let ni = if i == 0 { 0 } else { counts[i - 1] };
            let no = counts[i];
            let idx = |(ring, k): (usize, usize)| {
                let (r, n) = if ring == 0 {
                    (i, ni.max(1))
                } else {
                    (i + 1, no)
                };
                (first[r] + k % n) as u32
            };
            for t in band(ni, no) {
                triangles.push([idx(t[0]), idx(t[1]), idx(t[2])]);
            }
        }
        band_starts.push(triangles.len());
        let z_lo = local.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
        let z_hi = local.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
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
            (counts, radius) = layout(a, s);
            let tri: usize = 2 * counts.iter().sum::<usize>();
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
                if let Some((z, _)) = surface_sag(row, q.x * q.x + q.y * q.y) {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enclosing_radius_of_known_triangles() {
        // Right triangle: half the hypotenuse.
        let r = enclosing_radius([0.0, 0.0], [2.0, 0.0], [0.0, 2.0]);
        assert!((r - 2f64.sqrt()).abs() < 1e-15);
        // Equilateral with side 1: 1/sqrt(3).
        let r = enclosing_radius([0.0, 0.0], [1.0, 0.0], [0.5, 0.75f64.sqrt()]);
        assert!((r - 1.0 / 3f64.sqrt()).abs() < 1e-15);
        // Obtuse: half the longest edge.
        let r = enclosing_radius([0.0, 0.0], [4.0, 0.0], [2.0, 0.5]);
        assert!((r - 2.0).abs() < 1e-15);
    }
}
