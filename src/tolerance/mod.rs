//! Manufacturing and assembly tolerances: elements, perturbation values (patterns), tolerance
//! specs, a seeded sampler, and the application of a perturbation to an immutable lens.
//!
//! Semantics (see ARCHITECTURE.md): an element (a singlet or a cemented group) moves rigidly:
//! `x -> pivot + R (x - pivot) + T` with `R = Rz(g) Ry(b) Rx(a)` (degrees, right-handed),
//! `T = (dx, dy, shift_z)`, pivot at the element's front vertex by default. A gap change
//! (`thickness` of an element, `gap` after a surface) moves every later surface and the image.
//! Curvature errors are per surface, in percent of the curvature. Surface decenter/tilt (wedge)
//! moves one surface about its own vertex before the element moves.

pub mod criterion;
pub mod monte_carlo;
pub mod spec;

pub use criterion::{Criterion, MtfDirection};
pub use monte_carlo::{
    merge_reports, monte_carlo, perturbed_criterion, sensitivity, McOptions, McReport,
    SensitivityNominal, SensitivityRow, TrialResult,
};
pub use spec::{Distribution, Operand, OperandKind, ToleranceSpec};

use crate::error::{Error, Result};
use crate::lens::{Adjustments, Lens, Material};
use crate::math::{Mat3, Rigid, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A lens element: surfaces `first..=last`, glass between them (a cemented group is one element).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Element {
    /// Front surface index.
    pub first: usize,
    /// Back surface index.
    pub last: usize,
}

/// Finds the elements of a prescription: a run of surfaces with glass between them, from the
/// surface that enters glass to the one that leaves it into air.
pub fn find_elements(lens: &Lens) -> Vec<Element> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, s) in lens.surfaces.iter().enumerate() {
        match (start, s.material.is_air()) {
            (None, false) => start = Some(i),
            (Some(f), true) => {
                out.push(Element { first: f, last: i });
                start = None;
            }
            _ => {}
        }
    }
    out
}

/// Where an element tilts about.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Pivot {
    /// The element's front vertex (the paper's convention, the default).
    #[default]
    Front,
    /// The element's back vertex.
    Back,
    /// Midway between the front and back vertices.
    Center,
}

/// The largest refractive-index error Δn_d a pattern may give an element's glass.
pub const MAX_INDEX_ERROR: f64 = 1.0;
/// The largest Abbe-number error ΔV_d a pattern may give an element's glass.
pub const MAX_ABBE_ERROR: f64 = 1000.0;

/// Perturbation of one element.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ElementPerturbation {
    /// Element index (from 0).
    pub element: usize,
    /// Decenter (x, y), mm.
    pub decenter_mm: [f64; 2],
    /// Tilt about x, y, z, degrees.
    pub tilt_deg: [f64; 3],
    /// Axial shift of the whole element (the paper's "centre thickness" error), mm.
    pub shift_mm: f64,
    /// True centre-thickness change (the gap after the front surface; later surfaces move), mm.
    pub thickness_mm: f64,
    /// Refractive-index error Δn_d of the element's glass.
    pub index: f64,
    /// Abbe-number error ΔV_d of the element's glass.
    pub abbe: f64,
}

/// Perturbation of one surface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SurfacePerturbation {
    /// Surface index (from 0).
    pub surface: usize,
    /// Curvature error, percent of the surface's curvature.
    pub curvature_pct: f64,
    /// Change of the gap after this surface (despace), mm; later surfaces move.
    pub gap_mm: f64,
    /// Surface decenter (x, y) about its vertex, mm.
    pub decenter_mm: [f64; 2],
    /// Surface tilt (wedge) about x and y through its vertex, degrees.
    pub tilt_deg: [f64; 2],
}

/// A tolerance pattern: explicit perturbation values of one fabricated lens. This is also the
/// file format of `--perturb` and of sampled patterns.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Perturbation {
    /// Tilt pivot of every element.
    pub pivot: Pivot,
    /// Per-element perturbations (any order; absent elements are nominal).
    pub elements: Vec<ElementPerturbation>,
    /// Per-surface perturbations.
    pub surfaces: Vec<SurfacePerturbation>,
}

impl Perturbation {
    /// Reads a pattern file.
    ///
    /// # Errors
    /// I/O and JSON errors naming the file, line and column.
    pub fn read(path: &Path) -> Result<Perturbation> {
        crate::files::read_json(path)
    }

    /// Checks element and surface indices and values against `lens`.
    ///
    /// # Errors
    /// [`ErrorKind::Invalid`](crate::error::ErrorKind::Invalid) naming the out-of-range index or non-finite value.
    pub fn validate(&self, lens: &Lens) -> Result<()> {
        let ne = find_elements(lens).len();
        for e in &self.elements {
            if e.element >= ne {
                return Err(Error::invalid(format!(
                    "element {} is out of range: the lens has {ne} elements (0 to {})",
                    e.element,
                    ne.saturating_sub(1)
                )));
            }
            let v = [
                e.decenter_mm[0],
                e.decenter_mm[1],
                e.tilt_deg[0],
                e.tilt_deg[1],
                e.tilt_deg[2],
                e.shift_mm,
                e.thickness_mm,
                e.index,
                e.abbe,
            ];
            if v.iter().any(|x| !x.is_finite()) {
                return Err(Error::invalid(format!(
                    "element {}: a value is not finite",
                    e.element
                )));
            }
            // Glass errors beyond these are not fabrication errors, and larger Abbe offsets
            // leave a dispersion that rounds to nothing.
            if !(e.index.abs() <= MAX_INDEX_ERROR && e.abbe.abs() <= MAX_ABBE_ERROR) {
                return Err(Error::invalid(format!(
                    "element {}: index error {} (at most ±{MAX_INDEX_ERROR}) or Abbe-number error {} (at most ±{MAX_ABBE_ERROR}) out of range",
                    e.element, e.index, e.abbe
                )));
            }
        }
        let ns = lens.surfaces.len();
        for s in &self.surfaces {
            if s.surface >= ns {
                return Err(Error::invalid(format!(
                    "surface {} is out of range: the lens has {ns} surfaces (0 to {})",
                    s.surface,
                    ns - 1
                )));
            }
            let v = [
                s.curvature_pct,
                s.gap_mm,
                s.decenter_mm[0],
                s.decenter_mm[1],
                s.tilt_deg[0],
                s.tilt_deg[1],
            ];
            if v.iter().any(|x| !x.is_finite()) {
                return Err(Error::invalid(format!(
                    "surface {}: a value is not finite",
                    s.surface
                )));
            }
        }
        Ok(())
    }

    /// JSON text of the pattern.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// Applies the perturbation to `lens`: returns the lens with perturbed materials (a copy; the
    /// nominal lens is untouched) and the geometric adjustments to compile it with.
    ///
    /// # Errors
    /// As [`Perturbation::validate`]; also an index error that would take n below 1.
    pub fn apply(&self, lens: &Lens) -> Result<(Lens, Adjustments)> {
        self.validate(lens)?;
        let elements = find_elements(lens);
        let n = lens.surfaces.len();
        let mut out = lens.clone();
        let mut adj = Adjustments::none(n);
        // 1. Gap changes: every later surface and the image move along z.
        let mut dgap = vec![0.0; n];
        for s in &self.surfaces {
            dgap[s.surface] += s.gap_mm;
        }
        for e in &self.elements {
            dgap[elements[e.element].first] += e.thickness_mm;
        }
        let mut shift = vec![0.0; n + 1];
        for i in 1..=n {
            shift[i] = shift[i - 1] + dgap[i - 1];
        }
        let z = lens.vertex_z_mm();
        let vertex = |i: usize| {
            Vec3::new(
                lens.surfaces.get(i).map_or(0.0, |s| s.pos_xy_mm[0]),
                lens.surfaces.get(i).map_or(0.0, |s| s.pos_xy_mm[1]),
                z[i] + shift[i],
            )
        };
        for i in 0..n {
            adj.surface_motion[i] = Rigid {
                rotation: Mat3::identity(),
                translation: Vec3::new(0.0, 0.0, shift[i]),
            };
        }
        adj.image_motion = Rigid {
            rotation: Mat3::identity(),
            translation: Vec3::new(0.0, 0.0, shift[n]),
        };
        // 2. Surface errors: curvature, and decenter/tilt about the surface's own vertex.
        for s in &self.surfaces {
            let i = s.surface;
            adj.curvature_error[i] += s.curvature_pct * 0.01;
            if s.decenter_mm != [0.0; 2] || s.tilt_deg != [0.0; 2] {
                let r = Mat3::from_tilt_deg(s.tilt_deg[0], s.tilt_deg[1], 0.0);
                let m = Rigid::about_pivot(
                    r,
                    vertex(i),
                    Vec3::new(s.decenter_mm[0], s.decenter_mm[1], 0.0),
                );
                adj.surface_motion[i] = m.compose(&adj.surface_motion[i]);
            }
        }
        // 3. Element rigid motions about the pivot, and glass errors.
        for e in &self.elements {
            let el = elements[e.element];
            let pivot = match self.pivot {
                Pivot::Front => vertex(el.first),
                Pivot::Back => vertex(el.last),
                Pivot::Center => (vertex(el.first) + vertex(el.last)) * 0.5,
            };
            let r = Mat3::from_tilt_deg(e.tilt_deg[0], e.tilt_deg[1], e.tilt_deg[2]);
            let m = Rigid::about_pivot(
                r,
                pivot,
                Vec3::new(e.decenter_mm[0], e.decenter_mm[1], e.shift_mm),
            );
            for i in el.first..=el.last {
                adj.surface_motion[i] = m.compose(&adj.surface_motion[i]);
            }
            if e.index != 0.0 || e.abbe != 0.0 {
                for i in el.first..el.last {
                    let base = out.surfaces[i].material.clone();
                    out.surfaces[i].material = perturbed_material(&base, e.index, e.abbe)
                        .map_err(|m| Error::invalid(format!("element {}: {m}", e.element)))?;
                }
            }
        }
        Ok((out, adj))
    }
}

/// A glass with its n_d shifted by `dn` and its Abbe number by `dv`, keeping the shape of its
/// dispersion curve: n'(λ) = n_d' + (n(λ) - n_d) · ((n_d' - 1)/V') / ((n_d - 1)/V); a
/// gradient-index medium with its vertex index n0 shifted by `dn`.
fn perturbed_material(base: &Material, dn: f64, dv: f64) -> std::result::Result<Material, String> {
    use crate::lens::material::{LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
    let nd = base.index(LAMBDA_D_NM);
    let disp = base.index(LAMBDA_F_NM) - base.index(LAMBDA_C_NM);
    let nd2 = nd + dn;
    if !(nd2 >= 1.0) {
        return Err(format!("index error {dn} takes n_d below 1"));
    }
    if nd2 > crate::lens::material::MAX_INDEX {
        return Err(format!(
            "index error {dn} takes n_d above {}",
            crate::lens::material::MAX_INDEX
        ));
    }
    if let Material::Gradient(g) = base {
        // A gradient-index medium keeps its profile about a vertex index shifted by `dn`; it
        // has no dispersion for an Abbe-number error to change.
        let mut g = g.clone();
        g.n0 = nd2;
        return Ok(Material::Gradient(g));
    }
    if disp == 0.0 {
        return Ok(Material::Constant(nd2));
    }
    let vd = (nd - 1.0) / disp;
    let vd2 = vd + dv;
    if !(vd2 > 0.0) {
        return Err(format!("Abbe-number error {dv} makes V_d non-positive"));
    }
    Ok(Material::Perturbed {
        base: Box::new(base.clone()),
        nd,
        nd_new: nd2,
        scale: ((nd2 - 1.0) / vd2) / disp,
    })
}
