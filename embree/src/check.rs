//! The cross-check: a sequential trace whose every intersection comes from Embree (on
//! tessellated, possibly perturbed surfaces), compared hit by hit with the analytic
//! intersection of the same incoming ray, and spot by spot with the analytic kernel.
//!
//! # What is checked, and against which bound
//!
//! At surface `i` an incoming ray `p + t d` (local frame, unit `d`) meets the mesh at `t_e`
//! (Embree) and the true surface at `t_a` (Newton on the sag, [`intersect_local`], the routine
//! the reference tracer uses; the fast kernel agrees with it to 1e-9 mm). Along the ray let
//! `g(t) = z(t) - f(x(t), y(t))` (height above the surface); `g(t_a) = 0` and, because the
//! Embree hit lies on the mesh, `|g(t_e)| <= B + ε32` where `B` is the mesh's chord bound
//! ([`Mesh::chord_bound_mm`]) and `ε32` an allowance for f32 rounding. With
//! `|g''| <= M |d_xy|² <= M` (the same `M` as the chord bound),
//! `|g(t_e)| >= (|g'(t_a)| - M |Δt|) |Δt|`, so each hit must satisfy
//!
//! ```text
//! (|g'(t_a)| - M |Δt|) |Δt|  <=  s B + ε32,      Δt = t_e - t_a = ± |P_embree - P_analytic|
//! ```
//!
//! with `s` = [`CheckOptions::bound_scale`] (1 for the theorem; smaller values assert a tighter
//! bound than the theorem gives, which real meshes must fail). `g'(t_a) = d_z - ∇f · d_xy`
//! equals `cos(incidence) / cos(slope)`: the distance between the hits along the ray is about
//! `B cos(slope) / cos(incidence)`, i.e. the normal-distance bound `B cos(slope)` divided by the
//! cosine of the incidence angle. The report gives `|P_embree - P_analytic|` and the ratio of the
//! left side to the right side (`<= 1` passes). `ε32 = 2⁻²² (m (1 + slope) + |t|)`, with `m`
//! the largest coordinate of the Embree ray and hit in the mesh's frame and `slope` the largest
//! `|∇f|`: at least two f32 units in the last place of every coordinate (lateral rounding moves
//! a point by `slope` times as much in height) and of `t`. Measured on lens1, lens2 and the
//! triplet, the f32 error of Embree's `t` against an exact f64 intersection with the same
//! triangle stays below 2e-6 mm in the local frame (reported per surface), against allowances
//! of 3e-6 to 7e-6 mm; the global frame roughly doubles both. The mesh's own sampled deviation
//! (f32 vertices) is checked against `s B` plus the same allowance for its largest vertex
//! coordinate.
//!
//! Refraction at the Embree hit uses either the analytic normal at that point
//! ([`NormalMode::Analytic`]) or the mesh's normal interpolated from its vertices' analytic
//! normals with Embree's barycentric coordinates ([`NormalMode::Mesh`]). Spots are compared per
//! field and wavelength over the rays that reach the image in all traces.

use super::device::{Device, Hit, Scene, SceneOptions};
use super::mesh::{Frame, Mesh};
use serde::{Deserialize, Serialize};
use std::time::Instant;
use tolray::analysis::spot_stats;
use tolray::error::{Error, Result};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{Lens, SurfaceRow, System};
use tolray::math::Vec3;
use tolray::tolerance::{Perturbation, ToleranceSpec};
use tolray::trace::reference::{
    bend, image_crossing, intersect_local, surface_sag_xy, trace_ray, unit_normal,
};
use tolray::trace::{
    trace_serial, Bundle, Bundles, Field, Pupil, RayBatch, RayStatus, TraceOptions,
};

/// Which normal refracts a ray at an Embree hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NormalMode {
    /// The analytic surface normal at the Embree hit point.
    Analytic,
    /// The mesh's normal: vertex normals interpolated with Embree's barycentric coordinates.
    Mesh,
}

/// Which part of each surface a cross-check meshes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Cover {
    /// The triangles the traced rays can meet first, within one ring spacing of their paths
    /// ([`Mesh::with_footprint`]); the same hits as the whole disk's mesh at a fraction of the
    /// scene-build cost.
    #[default]
    Footprint,
    /// The whole disk (the clear aperture, or the disk the rays reach).
    Disk,
}

/// Settings of a cross-check.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckOptions {
    /// Requested chord bound of every mesh, mm.
    pub chord_mm: f64,
    /// Frame in which meshes are built and traced.
    pub frame: Frame,
    /// Fields.
    pub fields: Vec<Field>,
    /// Wavelengths, nm.
    pub wavelengths_nm: Vec<f64>,
    /// Pupil sampling (rays generated once from the nominal lens).
    pub pupil: Pupil,
    /// Factor on the chord bound that hits and meshes must satisfy (1: the theorem).
    pub bound_scale: f64,
    /// Largest allowed RMS spot difference (analytic-normal mode), µm.
    pub spot_bound_um: f64,
    /// Which part of each surface is meshed.
    #[serde(default)]
    pub cover: Cover,
}

impl Default for CheckOptions {
    /// Chord 1e-4 mm, local frame, fields 0, 0.7, 1, the d line, a 32x32 grid, bounds as stated
    /// by the theorem, 0.1 µm for spots, footprint meshes.
    fn default() -> Self {
        CheckOptions {
            chord_mm: 1e-4,
            frame: Frame::Local,
            fields: vec![
                Field::fraction(0.0),
                Field::fraction(0.7),
                Field::fraction(1.0),
            ],
            wavelengths_nm: vec![LAMBDA_D_NM],
            pupil: Pupil::grid(32),
            bound_scale: 1.0,
            spot_bound_um: 0.1,
            cover: Cover::Footprint,
        }
    }
}

/// The rays of every field and wavelength of `opts`, generated once from the nominal lens (as
/// the Monte Carlo analysis does), so every case traces the same rays.
///
/// # Errors
/// [`tolray::ErrorKind::Argument`] without fields or wavelengths; paraxial and ray-generation
/// errors.
pub fn check_rays(lens: &Lens, opts: &CheckOptions) -> Result<Bundles> {
    if opts.fields.is_empty() || opts.wavelengths_nm.is_empty() {
        return Err(Error::argument(
            "a cross-check needs at least one field and one wavelength",
        ));
    }
    Bundles::new(lens, &opts.fields, &opts.wavelengths_nm, &opts.pupil)
}

/// A surface's check is sharp when its f32 allowance is at most this fraction of its chord
/// bound ([`SurfaceCheck::sharp`]).
pub const SHARP_FRACTION: f64 = 0.25;

/// Per-surface result of a case.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurfaceCheck {
    /// Surface index.
    pub surface: usize,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Triangles of the whole disk's mesh (more than `triangles` for a footprint mesh).
    #[serde(default)]
    pub disk_triangles: usize,
    /// Rings x segments of the polar mesh.
    pub rings: usize,
    /// Vertices per ring.
    pub segments: usize,
    /// `M`, the largest second directional derivative of the sag, 1/mm.
    pub max_second_derivative: f64,
    /// The mesh's theoretical chord bound `B`, mm.
    pub chord_bound_mm: f64,
    /// The mesh's largest vertical distance from the surface on sample points, mm.
    pub mesh_deviation_mm: f64,
    /// Embree hits compared with the analytic ones (both normal modes).
    pub hits: usize,
    /// Largest `|P_embree - P_analytic|`, mm.
    pub max_hit_distance_mm: f64,
    /// RMS of `|P_embree - P_analytic|`, mm.
    pub rms_hit_distance_mm: f64,
    /// Largest per-hit bound along the ray, `(s B + ε32) / |g'|`, mm (context for the above).
    pub max_hit_bound_mm: f64,
    /// Largest ratio of a hit's deviation to its bound (see the module docs; `<= 1` passes).
    pub max_bound_ratio: f64,
    /// Largest vertical distance of an Embree hit point from the surface, mm.
    pub max_surface_distance_mm: f64,
    /// Largest difference between Embree's `t` and an exact f64 intersection with the same
    /// triangle, mm (the f32 error).
    pub max_f32_error_mm: f64,
    /// Largest f32 allowance `ε32` used, mm.
    pub max_f32_allowance_mm: f64,
    /// Whether the check is sharp here: the f32 allowances (hits and mesh) are at most a
    /// quarter of the chord bound, so a deviation of half the bound more than asserted fails
    /// (`--bound-scale 0.5` fails wherever the mesh comes near its bound). Not sharp on a flat
    /// surface (bound 0: only rounding is checked) or where the bound is so tight, or the
    /// surface so large, that Embree's f32 rounding is comparable to it.
    pub sharp: bool,
    /// Rays that Embree and the analytic surface put on different sides of the clear aperture's
    /// rim (allowed: their hits are within the bound).
    pub rim_flips: usize,
    /// Radius of the tessellated disk, mm (the clear semi-aperture, or less; see
    /// [`check_system`]).
    pub disk_mm: f64,
    /// Clear semi-aperture, mm.
    pub semi_aperture_mm: f64,
    /// Rays Embree missed although their analytic hit is inside the tessellated disk (must
    /// be 0).
    pub leaks: usize,
    /// Rays Embree missed whose analytic hit is inside the clear aperture but outside the
    /// tessellated disk (must be 0).
    pub uncovered: usize,
    /// Rays Embree hit although the analytic surface has no intersection (must be 0).
    pub unmatched: usize,
    /// Hits too close to grazing for the bound to say anything (`|g'| <= 2 M |Δt|`).
    pub grazing: usize,
    /// Scene build time, ms.
    pub build_ms: f64,
}

/// Per field and wavelength result of a case. Spot sizes in µm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldCheck {
    /// Field.
    pub field: Field,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// Rays launched.
    pub rays: usize,
    /// Rays that reached the image in every trace (the compared set).
    pub compared: usize,
    /// Rays alive in the analytic trace but not in the Embree trace (analytic normals), or
    /// the reverse.
    pub status_mismatches: usize,
    /// RMS spot radius of the analytic kernel trace, µm.
    pub rms_analytic_um: f64,
    /// RMS spot radius of the Embree trace with analytic normals, µm.
    pub rms_embree_um: f64,
    /// `|rms_embree_um - rms_analytic_um|`, µm.
    pub rms_diff_um: f64,
    /// Largest image-point distance between the two traces, µm.
    pub max_point_diff_um: f64,
    /// RMS spot radius of the Embree trace with interpolated mesh normals, µm.
    pub rms_embree_mesh_normal_um: f64,
    /// `|rms_embree_mesh_normal_um - rms_analytic_um|`, µm.
    pub rms_diff_mesh_normal_um: f64,
    /// Largest image-point distance, mesh normals vs analytic, µm.
    pub max_point_diff_mesh_normal_um: f64,
}

/// Wall-clock time of the traces of a case, single-threaded, on the same rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    /// Launched rays times surfaces (the work unit of every figure).
    pub ray_surfaces: u64,
    /// Embree-driven trace (intersection by Embree, analytic-normal refraction), s; scene
    /// builds excluded.
    pub embree_s: f64,
    /// Scene builds, s.
    pub build_s: f64,
    /// Triangles built.
    pub triangles: u64,
    /// Triangles the whole disks' meshes would have had.
    #[serde(default)]
    pub disk_triangles: u64,
    /// The analytic `f64` kernel, one thread, s.
    pub kernel_s: f64,
    /// The scalar `f64` reference tracer, s.
    pub reference_s: f64,
}

impl Timing {
    fn add(&mut self, o: &Timing) {
        self.ray_surfaces += o.ray_surfaces;
        self.embree_s += o.embree_s;
        self.build_s += o.build_s;
        self.triangles += o.triangles;
        self.disk_triangles += o.disk_triangles;
        self.kernel_s += o.kernel_s;
        self.reference_s += o.reference_s;
    }
    /// Millions of ray-surfaces per second of the Embree trace, the kernel and the reference.
    pub fn mrs_per_s(&self) -> [f64; 3] {
        let r = self.ray_surfaces as f64 * 1e-6;
        [r / self.embree_s, r / self.kernel_s, r / self.reference_s]
    }
}

/// The result of one lens configuration (nominal or one tolerance pattern).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaseReport {
    /// Trial index (pattern k of the seed), `None` for the nominal lens.
    pub trial: Option<usize>,
    /// The pattern of the trial.
    pub pattern: Option<Perturbation>,
    /// Per surface.
    pub surfaces: Vec<SurfaceCheck>,
    /// Per field and wavelength.
    pub fields: Vec<FieldCheck>,
    /// Timing of this case.
    pub timing: Timing,
    /// What exceeded its bound (empty when the case passes).
    pub failures: Vec<String>,
}

#[derive(Clone, Copy, Debug)]
struct RayState {
    o: Vec3<f64>,
    d: Vec3<f64>,
    opl: f64,
    status: RayStatus,
}

/// One Embree query, kept for the comparison with the analytic surface.
#[derive(Clone, Copy, Debug)]
struct Query {
    p: Vec3<f64>,
    dl: Vec3<f64>,
    /// Ray origin and direction as given to Embree (mesh frame, before rounding to f32).
    org: Vec3<f64>,
    dir: Vec3<f64>,
    /// Parameter of `org` on the local ray.
    t0: f64,
    hit: Option<Hit>,
}

fn f32s(v: Vec3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

fn inf_norm(v: Vec3<f64>) -> f64 {
    v.x.abs().max(v.y.abs()).max(v.z.abs())
}

/// `t` of the f64 ray `o + t d` through the plane of triangle `prim` (f64 from the f32
/// vertices), the exact counterpart of Embree's `t`.
fn exact_t(mesh: &Mesh, prim: u32, o: Vec3<f64>, d: Vec3<f64>) -> Option<f64> {
    let tri = mesh.triangles.get(prim as usize)?;
    let v = |i: u32| {
        let p = mesh.vertices[i as usize];
        Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    };
    let (a, b, c) = (v(tri[0]), v(tri[1]), v(tri[2]));
    let n = (b - a).cross(c - a);
    let den = n.dot(d);
    (den != 0.0).then(|| n.dot(a - o) / den)
}

struct Stepper<'a> {
    row: &'a SurfaceRow<f64>,
    index: usize,
    mesh: &'a Mesh,
    scene: &'a Scene,
}

impl Stepper<'_> {
    /// Queries Embree for the ray `o + t d` (global) and returns the query record.
    fn query(&self, o: Vec3<f64>, d: Vec3<f64>) -> Query {
        let row = self.row;
        let p = row.rot.apply_t(o - row.pos);
        let dl = row.rot.apply_t(d);
        let mut q = Query {
            p,
            dl,
            org: p,
            dir: dl,
            t0: 0.0,
            hit: None,
        };
        if dl.z == 0.0 {
            return q;
        }
        // Start 1 mm before the mesh's slab, so Embree's f32 distances stay small.
        let [lo, hi] = self.mesh.z_range_mm;
        let z0 = if dl.z > 0.0 { lo - 1.0 } else { hi + 1.0 };
        q.t0 = (z0 - p.z) / dl.z;
        (q.org, q.dir) = match self.mesh.frame {
            Frame::Local => (p + dl * q.t0, dl),
            Frame::Global => (o + d * q.t0, d),
        };
        q.hit = self
            .scene
            .intersect(f32s(q.org), f32s(q.dir), 0.0, f32::INFINITY);
        q
    }

    /// Advances `s` (of `wavelength_nm`) through this surface using the Embree hit of `q`.
    fn advance(
        &self,
        s: &mut RayState,
        q: &Query,
        mode: NormalMode,
        n1: f64,
        n2: f64,
        wavelength_nm: f64,
    ) {
        let (row, i) = (self.row, self.index as u32);
        let Some(hit) = q.hit else {
            // The mesh covers the clear aperture with a spacing to spare: a miss is outside it.
            s.status = if q.dl.z == 0.0 {
                RayStatus::Missed(i)
            } else {
                RayStatus::Vignetted(i)
            };
            return;
        };
        let t = q.t0 + hit.t as f64;
        let h = q.p + q.dl * t;
        if row.clip.stops(h.x, h.y) {
            s.status = RayStatus::Vignetted(i);
            return;
        }
        let nrm = match mode {
            NormalMode::Analytic => match surface_sag_xy(row, h.x, h.y) {
                Some((_, zx, zy)) => unit_normal([zx, zy]),
                None => {
                    s.status = RayStatus::Missed(i);
                    return;
                }
            },
            NormalMode::Mesh => {
                let Some(&tri) = self.mesh.triangles.get(hit.prim as usize) else {
                    s.status = RayStatus::Missed(i);
                    return;
                };
                let (u, v) = (hit.u as f64, hit.v as f64);
                let nv = |k: usize| self.mesh.normals[tri[k] as usize];
                let n = nv(0) * (1.0 - u - v) + nv(1) * u + nv(2) * v;
                let n = match self.mesh.frame {
                    Frame::Local => n,
                    Frame::Global => row.rot.apply_t(n),
                };
                n.normalized()
            }
        };
        // Whatever turns the ray (refraction, reflection, a grating, an ideal thin lens), as the
        // reference tracer turns it; a bare aperture passes it.
        let Some((dn, phase)) = bend(row, q.dl, h, nrm, n1, n2, wavelength_nm) else {
            s.status = RayStatus::Tir(i);
            return;
        };
        s.opl += phase;
        s.opl += n1 * t;
        s.o = row.rot.apply(h) + row.pos;
        s.d = row.rot.apply(dn);
    }
}

#[derive(Default)]
struct SurfaceAcc {
    hits: usize,
    sum_sq: f64,
    max_dist: f64,
    max_hit_bound: f64,
    max_ratio: f64,
    max_surface: f64,
    max_f32: f64,
    max_eps: f64,
    rim_flips: usize,
    leaks: usize,
    uncovered: usize,
    unmatched: usize,
    grazing: usize,
}

impl SurfaceAcc {
    /// Compares one Embree query with the analytic intersection of the same incoming ray.
    fn compare(&mut self, st: &Stepper, q: &Query, opts: &CheckOptions) {
        let (row, mesh) = (st.row, st.mesh);
        let analytic = intersect_local(row, q.p, q.dl);
        match (q.hit, analytic) {
            (Some(hit), Some((ta, ga))) => {
                let te = q.t0 + hit.t as f64;
                let dt = te - ta;
                let dist = dt.abs();
                let ha = q.p + q.dl * ta;
                let he = q.p + q.dl * te;
                let gp = (q.dl.z - (ga[0] * q.dl.x + ga[1] * q.dl.y)).abs();
                let hit_frame = q.org + q.dir * hit.t as f64;
                let m = inf_norm(q.org).max(inf_norm(hit_frame));
                let eps = (m * (1.0 + mesh.max_slope) + (hit.t as f64).abs()) * 2f64.powi(-22);
                let allowed = opts.bound_scale * mesh.chord_bound_mm + eps;
                let lhs = dist * (gp - mesh.max_second_derivative * dist);
                if gp <= 2.0 * mesh.max_second_derivative * dist {
                    self.grazing += 1;
                } else {
                    self.max_ratio = self.max_ratio.max(lhs / allowed);
                }
                self.hits += 1;
                self.sum_sq += dist * dist;
                self.max_dist = self.max_dist.max(dist);
                self.max_hit_bound = self.max_hit_bound.max(allowed / gp);
                self.max_eps = self.max_eps.max(eps);
                if let Some((z, _, _)) = surface_sag_xy(row, he.x, he.y) {
                    self.max_surface = self.max_surface.max((he.z - z).abs());
                }
                if let Some(tx) = exact_t(mesh, hit.prim, q.org, q.dir) {
                    self.max_f32 = self.max_f32.max((hit.t as f64 - tx).abs());
                }
                let inside = |h: Vec3<f64>| !row.clip.stops(h.x, h.y);
                if inside(he) != inside(ha) {
                    self.rim_flips += 1;
                }
            }
            (None, Some((ta, _))) => {
                let ha = q.p + q.dl * ta;
                let r2 = ha.x * ha.x + ha.y * ha.y;
                if !row.clip.stops(ha.x, ha.y) {
                    if r2.sqrt() <= mesh.disk_mm {
                        self.leaks += 1;
                    } else {
                        self.uncovered += 1;
                    }
                }
            }
            (Some(_), None) => self.unmatched += 1,
            (None, None) => {}
        }
    }
}

/// The refractive indices after each surface at each bundle's wavelength.
fn bundle_indices(sys: &System<f64>, rays: &Bundles) -> Vec<Vec<f64>> {
    rays.sets
        .iter()
        .map(|b| sys.indices(b.wavelength_nm))
        .collect()
}

/// Radius of the disk meshed for a surface whose traced rays reach out to `used` mm: a margin
/// beyond the rays, within the aperture's reach.
fn mesh_disk(used: f64, row: &SurfaceRow<f64>) -> f64 {
    (1.02 * used + 0.05).min(row.clip.reach_mm)
}

/// Refuses surfaces the check cannot mesh: it tessellates rotationally symmetric surfaces of
/// bounded curvature (rings of equal sag), so toroids, Zernike sag surfaces and odd aspheres
/// with a cone term are
/// refused by name, as are gradient-index media. (Gratings and ideal thin lenses are meshed as their substrate, a plane for
/// the thin lens, and turn the rays as the reference tracer does: [`bend`].)
fn supported(sys: &System<f64>) -> Result<()> {
    use tolray::lens::Shape;
    for (i, row) in sys.rows.iter().enumerate() {
        if row.grin.is_some() {
            return Err(Error::invalid(format!(
                "the medium after surface {i} is a gradient-index medium, whose rays curve: the Embree check traces straight segments between meshed surfaces"
            )));
        }
        let what = match row.shape {
            Shape::Odd if row.asph[0] != 0.0 => {
                "an odd asphere with a cone term (r^1: a point at the vertex)"
            }
            Shape::Even
            | Shape::Odd
            | Shape::Qbfs { .. }
            | Shape::Qcon { .. }
            | Shape::Paraxial { .. } => continue,
            Shape::Toroidal { .. } => "a toroid",
            Shape::Zernike { .. } => "a Zernike sag surface",
        };
        return Err(Error::invalid(format!(
            "surface {i} is {what}; the Embree check covers even, odd (without r^1) and Q-type aspheres, conics, spheres, planes, mirrors, gratings on them and ideal thin lenses"
        )));
    }
    Ok(())
}

/// Refuses, before anything is meshed, a chord bound that some surface of `sys` cannot be
/// meshed to (too many triangles), as [`check_system`] would after meshing the surfaces before
/// it.
///
/// # Errors
/// [`tolray::ErrorKind::Argument`] naming the surface, the bound and the triangle count.
pub fn check_feasible(sys: &System<f64>, rays: &Bundles, opts: &CheckOptions) -> Result<()> {
    supported(sys)?;
    let indices = bundle_indices(sys, rays);
    let used = used_radii(sys, rays, &indices);
    for (i, row) in sys.rows.iter().enumerate() {
        Mesh::plan(row, i, mesh_disk(used[i], row), opts.chord_mm).map_err(|e| {
            Error::argument(format!(
                "--chord {:e} mm cannot be checked: {}",
                opts.chord_mm,
                e.message()
            ))
        })?;
    }
    Ok(())
}

/// Largest radius (local frame, mm) at which the analytic trace of `rays` meets each surface,
/// counting the surface where a ray is vignetted.
fn used_radii(sys: &System<f64>, rays: &Bundles, indices: &[Vec<f64>]) -> Vec<f64> {
    let mut used = vec![0.0f64; sys.rows.len()];
    for (b, bundle) in rays.sets.iter().enumerate() {
        let n = &indices[b];
        for (&o0, &d0) in bundle.rays.origins.iter().zip(&bundle.rays.directions) {
            let (mut o, mut d) = (o0, d0.normalized());
            for (i, row) in sys.rows.iter().enumerate() {
                let p = row.rot.apply_t(o - row.pos);
                let dl = row.rot.apply_t(d);
                let Some((t, grad)) = intersect_local(row, p, dl) else {
                    break;
                };
                let h = p + dl * t;
                let r2 = h.x * h.x + h.y * h.y;
                used[i] = used[i].max(r2.sqrt());
                if row.clip.stops(h.x, h.y) {
                    break;
                }
                let nrm = unit_normal(grad);
                let Some((dn, _)) = bend(row, dl, h, nrm, n[i], n[i + 1], bundle.wavelength_nm)
                else {
                    break;
                };
                o = row.rot.apply(h) + row.pos;
                d = row.rot.apply(dn);
            }
        }
    }
    used
}

/// Cross-checks one compiled (possibly perturbed) system on `rays`.
///
/// Each surface is tessellated over its clear aperture, or over a smaller disk that still
/// holds every analytic hit of these rays with a margin (`1.02 r + 0.05 mm`) when the clear
/// aperture is much larger than the beam (the Cooke triplet's reference file has semi-apertures
/// up to the sphere's rim, where no height-field tessellation has a finite chord bound). A ray
/// that Embree misses while its analytic hit is inside the clear aperture counts as a leak
/// (inside the tessellated disk) or as uncovered (outside it); both fail the case.
///
/// # Errors
/// Mesh and Embree errors naming the surface; [`tolray::ErrorKind::Numerical`] if no ray of a
/// field reaches the image in every trace.
pub fn check_system(
    device: &Device,
    sys: &System<f64>,
    rays: &Bundles,
    opts: &CheckOptions,
) -> Result<CaseReport> {
    supported(sys)?;
    let indices = bundle_indices(sys, rays);
    let start = |b: &Bundle| -> Vec<RayState> {
        b.rays
            .origins
            .iter()
            .zip(&b.rays.directions)
            .map(|(&o, &d)| RayState {
                o,
                d: d.normalized(),
                opl: 0.0,
                status: RayStatus::Alive,
            })
            .collect()
    };
    // One Embree trace per normal mode, all of them surface by surface.
    let mut states: Vec<Vec<Vec<RayState>>> = NORMAL_MODES
        .iter()
        .map(|_| rays.sets.iter().map(start).collect())
        .collect();
    let mut timing = Timing {
        ray_surfaces: (rays.ray_count() * sys.rows.len()) as u64,
        ..Timing::default()
    };
    let mut failures = Vec::new();
    let used = used_radii(sys, rays, &indices);
    let mut surfaces = Vec::with_capacity(sys.rows.len());
    for (i, row) in sys.rows.iter().enumerate() {
        let pass = SurfacePass {
            device,
            row,
            index: i,
            rays,
            indices: &indices,
            opts,
        };
        let (check, mesh_eps) = pass.run(used[i], &mut states, &mut timing)?;
        check.failures(opts, mesh_eps, &mut failures);
        surfaces.push(check);
    }
    cross_image(sys, &mut states);
    let mut fields = Vec::with_capacity(rays.sets.len());
    for (b, bundle) in rays.sets.iter().enumerate() {
        let fc = field_check(
            sys,
            bundle,
            &indices[b],
            [&states[0][b], &states[1][b]],
            &mut timing,
        )?;
        if fc.rms_diff_um > opts.spot_bound_um {
            failures.push(format!(
                "{}: the RMS spots differ by {:.3e} um, more than {} um",
                field_label(bundle),
                fc.rms_diff_um,
                opts.spot_bound_um
            ));
        }
        fields.push(fc);
    }
    Ok(CaseReport {
        trial: None,
        pattern: None,
        surfaces,
        fields,
        timing,
        failures,
    })
}

/// The normal modes of the Embree traces, in the order of their ray states.
const NORMAL_MODES: [NormalMode; 2] = [NormalMode::Analytic, NormalMode::Mesh];

/// One surface's step of [`check_system`]: tessellate it, trace every live ray of every mode
/// through it with Embree and compare each hit with the analytic one.
struct SurfacePass<'a> {
    device: &'a Device,
    row: &'a SurfaceRow<f64>,
    index: usize,
    rays: &'a Bundles,
    indices: &'a [Vec<f64>],
    opts: &'a CheckOptions,
}

impl SurfacePass<'_> {
    /// Meshes the surface (over a disk of at least `used_mm`, or the rays' footprint), advances
    /// `states` through it and returns its check and the mesh's f32 allowance (mm), with the
    /// build and Embree times in `timing`.
    fn run(
        &self,
        used_mm: f64,
        states: &mut [Vec<Vec<RayState>>],
        timing: &mut Timing,
    ) -> Result<(SurfaceCheck, f64)> {
        let (row, i, opts) = (self.row, self.index, self.opts);
        let t_build = Instant::now();
        let disk = mesh_disk(used_mm, row);
        let footprint: Option<Vec<(Vec3<f64>, Vec3<f64>)>> = match opts.cover {
            Cover::Disk => None,
            Cover::Footprint => Some(
                states
                    .iter()
                    .flatten()
                    .flatten()
                    .filter(|s| s.status.is_alive())
                    .map(|s| (row.rot.apply_t(s.o - row.pos), row.rot.apply_t(s.d)))
                    .collect(),
            ),
        };
        let mesh = Mesh::with_footprint(
            row,
            i,
            disk,
            opts.chord_mm,
            opts.frame,
            footprint.as_deref(),
        )?;
        let scene = Scene::new(
            self.device,
            &mesh.vertices,
            &mesh.triangles,
            SceneOptions::default(),
        )
        .map_err(|e| e.context(format!("surface {i}")))?;
        let build_s = t_build.elapsed().as_secs_f64();
        timing.build_s += build_s;
        timing.triangles += mesh.triangles.len() as u64;
        timing.disk_triangles += mesh.layout_triangles as u64;
        let st = Stepper {
            row,
            index: i,
            mesh: &mesh,
            scene: &scene,
        };
        let mut acc = SurfaceAcc::default();
        let mut queries = Vec::new();
        for (m, &mode) in NORMAL_MODES.iter().enumerate() {
            queries.clear();
            let t0 = Instant::now();
            for (b, rs) in states[m].iter_mut().enumerate() {
                let n = &self.indices[b];
                for s in rs.iter_mut().filter(|s| s.status.is_alive()) {
                    let q = st.query(s.o, s.d);
                    st.advance(s, &q, mode, n[i], n[i + 1], self.rays.sets[b].wavelength_nm);
                    queries.push(q);
                }
            }
            if mode == NormalMode::Analytic {
                timing.embree_s += t0.elapsed().as_secs_f64();
            }
            for q in &queries {
                acc.compare(&st, q, opts);
            }
        }
        let mesh_eps = mesh_f32_allowance(&mesh);
        Ok((
            surface_check(row, i, &mesh, &acc, build_s, mesh_eps),
            mesh_eps,
        ))
    }
}

/// The float allowance of a mesh's single-precision vertices (Embree's arithmetic) at its
/// largest coordinate, mm.
fn mesh_f32_allowance(mesh: &Mesh) -> f64 {
    let vmax = mesh
        .vertices
        .iter()
        .flatten()
        .fold(0.0f32, |a, x| a.max(x.abs())) as f64;
    vmax * (1.0 + mesh.max_slope) * 2f64.powi(-22)
}

/// A surface's check from its mesh and the comparison of its hits.
fn surface_check(
    row: &SurfaceRow<f64>,
    i: usize,
    mesh: &Mesh,
    acc: &SurfaceAcc,
    build_s: f64,
    mesh_eps: f64,
) -> SurfaceCheck {
    SurfaceCheck {
        surface: i,
        triangles: mesh.triangles.len(),
        disk_triangles: mesh.layout_triangles,
        rings: mesh.rings,
        segments: mesh.segments,
        max_second_derivative: mesh.max_second_derivative,
        chord_bound_mm: mesh.chord_bound_mm,
        mesh_deviation_mm: mesh.deviation(row),
        hits: acc.hits,
        max_hit_distance_mm: acc.max_dist,
        rms_hit_distance_mm: (acc.sum_sq / acc.hits.max(1) as f64).sqrt(),
        max_hit_bound_mm: acc.max_hit_bound,
        max_bound_ratio: acc.max_ratio,
        max_surface_distance_mm: acc.max_surface,
        max_f32_error_mm: acc.max_f32,
        max_f32_allowance_mm: acc.max_eps,
        sharp: acc.max_eps.max(mesh_eps) <= SHARP_FRACTION * mesh.chord_bound_mm,
        rim_flips: acc.rim_flips,
        disk_mm: mesh.disk_mm,
        semi_aperture_mm: row.ap2.sqrt(),
        leaks: acc.leaks,
        uncovered: acc.uncovered,
        unmatched: acc.unmatched,
        grazing: acc.grazing,
        build_ms: build_s * 1e3,
    }
}

impl SurfaceCheck {
    /// Appends what fails this surface's check to `failures` (`mesh_eps`: the mesh's f32
    /// allowance, mm).
    fn failures(&self, opts: &CheckOptions, mesh_eps: f64, failures: &mut Vec<String>) {
        let i = self.surface;
        if self.max_bound_ratio > 1.0 {
            failures.push(format!(
                "surface {i}: an Embree hit deviates {:.3e} mm from the analytic hit, {:.3}x its \
                 bound (chord bound {:.3e} mm x {})",
                self.max_hit_distance_mm,
                self.max_bound_ratio,
                self.chord_bound_mm,
                opts.bound_scale
            ));
        }
        let mesh_allowed = opts.bound_scale * self.chord_bound_mm + mesh_eps;
        if self.mesh_deviation_mm > mesh_allowed {
            failures.push(format!(
                "surface {i}: the mesh deviates {:.3e} mm from the surface, more than {:.3e} mm",
                self.mesh_deviation_mm, mesh_allowed
            ));
        }
        if self.leaks > 0 {
            failures.push(format!(
                "surface {i}: {} rays passed through the mesh inside the clear aperture",
                self.leaks
            ));
        }
        if self.uncovered > 0 {
            failures.push(format!(
                "surface {i}: {} rays met the clear aperture outside the tessellated disk \
                 (radius {:.3} mm)",
                self.uncovered, self.disk_mm
            ));
        }
        if self.unmatched > 0 {
            failures.push(format!(
                "surface {i}: Embree hit {} rays that miss the analytic surface",
                self.unmatched
            ));
        }
    }
}

/// Carries the Embree traces' live rays to the image plane or curved image surface, crossed
/// analytically (exactly, as the kernel does): the check is of the lens surfaces' meshes.
fn cross_image(sys: &System<f64>, states: &mut [Vec<Vec<RayState>>]) {
    let n_img = sys.rows.len() as u32;
    for st in states.iter_mut().flatten().flatten() {
        if !st.status.is_alive() {
            continue;
        }
        let p = sys.image.point_to_local(st.o);
        let dl = sys.image.rotation.apply_t(st.d);
        let (t, hit) = image_crossing(sys, p, dl);
        if !hit {
            st.status = RayStatus::Missed(n_img);
            continue;
        }
        st.o = sys.image.point_to_global(p + dl * t);
    }
}

/// "field F at W nm", naming a bundle in errors and failures.
fn field_label(bundle: &Bundle) -> String {
    format!(
        "field {} at {} nm",
        bundle.rays.field.label(),
        bundle.wavelength_nm
    )
}

/// One bundle's spots: the analytic traces of its rays, the f64 kernel (compared) and the
/// scalar reference (timed only), one thread each, against the Embree traces `embree` (analytic
/// normals, mesh normals) already at the image.
fn field_check(
    sys: &System<f64>,
    bundle: &Bundle,
    indices: &[f64],
    embree: [&[RayState]; 2],
    timing: &mut Timing,
) -> Result<FieldCheck> {
    let mut batch = RayBatch::<f64>::with_capacity(bundle.rays.origins.len());
    for (o, d) in bundle.rays.origins.iter().zip(&bundle.rays.directions) {
        batch.push(*o, *d);
    }
    let t0 = Instant::now();
    trace_serial(
        sys,
        bundle.wavelength_nm,
        &mut batch,
        TraceOptions { apertures: true },
    );
    timing.kernel_s += t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let mut alive_ref = 0usize;
    for (o, d) in bundle.rays.origins.iter().zip(&bundle.rays.directions) {
        let r = trace_ray(sys, indices, bundle.wavelength_nm, *o, *d, true, None);
        alive_ref += r.status.is_alive() as usize;
    }
    timing.reference_s += t0.elapsed().as_secs_f64();
    std::hint::black_box(alive_ref);
    let sensor = |o: Vec3<f64>| {
        let p = sys.image.point_to_local(o);
        [p.x, p.y]
    };
    let (mut pa, mut pe, mut pm) = (Vec::new(), Vec::new(), Vec::new());
    let mut mismatches = 0;
    for ((ka, se), sm) in batch.iter().zip(embree[0]).zip(embree[1]) {
        if ka.status.is_alive() != se.status.is_alive() {
            mismatches += 1;
        }
        if ka.status.is_alive() && se.status.is_alive() && sm.status.is_alive() {
            pa.push(sensor(ka.o));
            pe.push(sensor(se.o));
            pm.push(sensor(sm.o));
        }
    }
    let label = field_label(bundle);
    let n = bundle.rays.origins.len();
    let sa = spot_stats(&pa, n, None).map_err(|e| e.context(&label))?;
    let se = spot_stats(&pe, n, None).map_err(|e| e.context(&label))?;
    let sm = spot_stats(&pm, n, None).map_err(|e| e.context(&label))?;
    let max_diff = |x: &[[f64; 2]]| {
        x.iter()
            .zip(&pa)
            .map(|(p, q)| (p[0] - q[0]).hypot(p[1] - q[1]) * 1e3)
            .fold(0.0, f64::max)
    };
    Ok(FieldCheck {
        field: bundle.rays.field,
        wavelength_nm: bundle.wavelength_nm,
        rays: n,
        compared: pa.len(),
        status_mismatches: mismatches,
        rms_analytic_um: sa.rms_um,
        rms_embree_um: se.rms_um,
        rms_diff_um: (se.rms_um - sa.rms_um).abs(),
        max_point_diff_um: max_diff(&pe),
        rms_embree_mesh_normal_um: sm.rms_um,
        rms_diff_mesh_normal_um: (sm.rms_um - sa.rms_um).abs(),
        max_point_diff_mesh_normal_um: max_diff(&pm),
    })
}

/// Settings of a validation run: nominal plus `trials` tolerance patterns.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidateOptions {
    /// Cross-check settings.
    pub check: CheckOptions,
    /// Monte Carlo patterns after the nominal lens.
    pub trials: usize,
    /// Seed; trial k is pattern k of this seed (the same as `tolray tolerance`).
    pub seed: u64,
    /// The tolerance spec sampled.
    pub spec: ToleranceSpec,
}

/// Worst values of one surface over all cases.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurfaceSummary {
    /// Surface index.
    pub surface: usize,
    /// Largest chord bound over the cases, mm.
    pub chord_bound_mm: f64,
    /// Largest sampled mesh deviation, mm.
    pub mesh_deviation_mm: f64,
    /// Largest hit distance, mm.
    pub max_hit_distance_mm: f64,
    /// RMS hit distance over all hits, mm.
    pub rms_hit_distance_mm: f64,
    /// Largest deviation/bound ratio.
    pub max_bound_ratio: f64,
    /// Largest f32 error, mm.
    pub max_f32_error_mm: f64,
    /// Largest f32 allowance, mm.
    pub max_f32_allowance_mm: f64,
    /// Sharp in every case ([`SurfaceCheck::sharp`]).
    pub sharp: bool,
    /// Hits compared.
    pub hits: usize,
    /// Rim flips.
    pub rim_flips: usize,
    /// Leaks.
    pub leaks: usize,
    /// Rays outside the tessellated disk but inside the clear aperture.
    pub uncovered: usize,
    /// Triangles of the nominal mesh.
    pub triangles: usize,
    /// Radius of the nominal mesh's disk, mm.
    pub disk_mm: f64,
    /// Clear semi-aperture, mm.
    pub semi_aperture_mm: f64,
}

/// Worst values over all cases.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationSummary {
    /// Cases run (nominal + trials).
    pub cases: usize,
    /// Cases with a failure.
    pub failed_cases: usize,
    /// Per surface.
    pub surfaces: Vec<SurfaceSummary>,
    /// Largest RMS spot difference, analytic normals, µm.
    pub max_rms_diff_um: f64,
    /// Largest image-point distance, analytic normals, µm.
    pub max_point_diff_um: f64,
    /// Largest RMS spot difference, interpolated mesh normals, µm.
    pub max_rms_diff_mesh_normal_um: f64,
    /// Largest image-point distance, mesh normals, µm.
    pub max_point_diff_mesh_normal_um: f64,
    /// Rays whose fate differs between the Embree (analytic-normal) and analytic traces.
    pub status_mismatches: usize,
    /// Rays compared at the image.
    pub rays_compared: usize,
    /// Timing summed over the cases.
    pub timing: Timing,
    /// Median over the cases of the per-case throughput, millions of ray-surfaces per second:
    /// Embree trace, analytic kernel, scalar reference (one thread each, the same rays; the
    /// median discounts cases slowed by other processes).
    pub median_mrs_per_s: [f64; 3],
}

/// A validation report: every case and the summary.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationReport {
    /// tolray version that wrote it.
    pub tolray_version: String,
    /// Embree version used.
    pub embree_version: String,
    /// The lens (name or path as given).
    pub lens: String,
    /// Settings.
    pub options: ValidateOptions,
    /// Nominal first, then the trials in order.
    pub cases: Vec<CaseReport>,
    /// Worst values.
    pub summary: ValidationSummary,
    /// True if no case failed.
    pub pass: bool,
}

/// Cross-checks `lens` nominal and perturbed by `opts.trials` sampled patterns. `progress` is
/// called after each case.
///
/// # Errors
/// Spec, pattern, ray-generation, mesh and Embree errors (naming the trial).
pub fn validate(
    device: &Device,
    lens: &Lens,
    lens_name: &str,
    opts: &ValidateOptions,
    progress: &dyn Fn(),
) -> Result<ValidationReport> {
    let c = &opts.check;
    if !(c.bound_scale > 0.0 && c.bound_scale.is_finite()) {
        return Err(Error::argument("bound scale must be positive"));
    }
    if !(c.spot_bound_um >= 0.0) {
        return Err(Error::argument("spot bound must be non-negative"));
    }
    opts.spec.validate(lens)?;
    let rays = check_rays(lens, c)?;
    let nominal_sys = lens.compile();
    check_feasible(&nominal_sys, &rays, c)?;
    let mut cases = Vec::with_capacity(opts.trials + 1);
    let mut nominal =
        check_system(device, &nominal_sys, &rays, c).map_err(|e| e.context("nominal lens"))?;
    nominal.trial = None;
    cases.push(nominal);
    progress();
    for k in 0..opts.trials {
        let pattern = opts.spec.sample(lens, opts.seed, k as u64)?;
        let (pl, adj) = pattern.apply(lens)?;
        let sys = System::compile(&pl, &adj, &|_, v| v);
        let mut case =
            check_system(device, &sys, &rays, c).map_err(|e| e.context(format!("trial {k}")))?;
        case.trial = Some(k);
        case.pattern = Some(pattern);
        cases.push(case);
        progress();
    }
    let summary = summarize(&cases);
    Ok(ValidationReport {
        tolray_version: env!("CARGO_PKG_VERSION").to_string(),
        embree_version: device.version_string(),
        lens: lens_name.to_string(),
        options: opts.clone(),
        pass: summary.failed_cases == 0,
        cases,
        summary,
    })
}

fn summarize(cases: &[CaseReport]) -> ValidationSummary {
    let ns = cases.first().map_or(0, |c| c.surfaces.len());
    let surfaces = (0..ns)
        .map(|i| {
            let it = || cases.iter().map(move |c| &c.surfaces[i]);
            let fmax = |f: &dyn Fn(&SurfaceCheck) -> f64| it().map(f).fold(0.0, f64::max);
            let hits: usize = it().map(|s| s.hits).sum();
            let ss: f64 = it()
                .map(|s| s.rms_hit_distance_mm.powi(2) * s.hits as f64)
                .sum();
            SurfaceSummary {
                surface: i,
                chord_bound_mm: fmax(&|s| s.chord_bound_mm),
                mesh_deviation_mm: fmax(&|s| s.mesh_deviation_mm),
                max_hit_distance_mm: fmax(&|s| s.max_hit_distance_mm),
                rms_hit_distance_mm: (ss / hits.max(1) as f64).sqrt(),
                max_bound_ratio: fmax(&|s| s.max_bound_ratio),
                max_f32_error_mm: fmax(&|s| s.max_f32_error_mm),
                max_f32_allowance_mm: fmax(&|s| s.max_f32_allowance_mm),
                sharp: it().all(|s| s.sharp),
                hits,
                rim_flips: it().map(|s| s.rim_flips).sum(),
                leaks: it().map(|s| s.leaks).sum(),
                uncovered: it().map(|s| s.uncovered).sum(),
                triangles: cases[0].surfaces[i].triangles,
                disk_mm: cases[0].surfaces[i].disk_mm,
                semi_aperture_mm: cases[0].surfaces[i].semi_aperture_mm,
            }
        })
        .collect();
    let fields = || cases.iter().flat_map(|c| c.fields.iter());
    let fmax = |f: &dyn Fn(&FieldCheck) -> f64| fields().map(f).fold(0.0, f64::max);
    let mut timing = Timing::default();
    for c in cases {
        timing.add(&c.timing);
    }
    let median = |k: usize| {
        let mut v: Vec<f64> = cases.iter().map(|c| c.timing.mrs_per_s()[k]).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    ValidationSummary {
        cases: cases.len(),
        failed_cases: cases.iter().filter(|c| !c.failures.is_empty()).count(),
        surfaces,
        max_rms_diff_um: fmax(&|f| f.rms_diff_um),
        max_point_diff_um: fmax(&|f| f.max_point_diff_um),
        max_rms_diff_mesh_normal_um: fmax(&|f| f.rms_diff_mesh_normal_um),
        max_point_diff_mesh_normal_um: fmax(&|f| f.max_point_diff_mesh_normal_um),
        status_mismatches: fields().map(|f| f.status_mismatches).sum(),
        rays_compared: fields().map(|f| f.compared).sum(),
        timing,
        median_mrs_per_s: [median(0), median(1), median(2)],
    }
}
