//! Tolerance specs: which operands, their ranges and distributions; and the seeded sampler.

use super::{find_elements, ElementPerturbation, Perturbation, Pivot, SurfacePerturbation};
use crate::error::{Error, Result};
use crate::lens::Lens;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// How an operand's value is drawn from its range ±max.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Distribution {
    /// The paper's: N(0, (max/3)²), clamped to ±max.
    #[default]
    Normal,
    /// Uniform on [−max, +max].
    Uniform,
    /// N(0, (max/3)²) truncated to ±max (redrawn until inside, no mass piles up at the limits).
    TruncatedNormal,
}

/// The kind of a tolerance operand. Element operands apply per element (decenter and tilt per
/// axis); surface operands per surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OperandKind {
    /// Element decenter in x and y, mm.
    Decenter,
    /// Element tilt about x, y and z, degrees.
    Tilt,
    /// Axial shift of the element (the paper's "centre thickness"), mm.
    Shift,
    /// True centre-thickness change of the element, mm (later surfaces move).
    Thickness,
    /// Refractive-index error of the element's glass (Δn_d).
    Index,
    /// Abbe-number error of the element's glass (ΔV_d).
    Abbe,
    /// Curvature error per surface, percent.
    Curvature,
    /// Air-gap (despace) error after a surface, mm.
    Gap,
    /// Surface decenter in x and y, mm.
    SurfaceDecenter,
    /// Surface tilt (wedge) about x and y, degrees.
    SurfaceTilt,
}

impl OperandKind {
    /// True for operands that apply to elements (else to surfaces).
    pub fn per_element(self) -> bool {
        matches!(
            self,
            OperandKind::Decenter
                | OperandKind::Tilt
                | OperandKind::Shift
                | OperandKind::Thickness
                | OperandKind::Index
                | OperandKind::Abbe
        )
    }
    /// Number of axes (independent draws) per target.
    pub fn axes(self) -> usize {
        match self {
            OperandKind::Decenter | OperandKind::SurfaceDecenter | OperandKind::SurfaceTilt => 2,
            OperandKind::Tilt => 3,
            _ => 1,
        }
    }
    /// Unit of the operand's values.
    pub fn unit(self) -> &'static str {
        match self {
            OperandKind::Tilt | OperandKind::SurfaceTilt => "deg",
            OperandKind::Curvature => "%",
            OperandKind::Index | OperandKind::Abbe => "",
            _ => "mm",
        }
    }
    /// Writes `value` for axis `axis` of target `t` into `p`.
    pub fn set(self, p: &mut Perturbation, t: usize, axis: usize, value: f64) {
        if self.per_element() {
            let e = match p.elements.iter().position(|e| e.element == t) {
                Some(k) => &mut p.elements[k],
                None => {
                    p.elements.push(ElementPerturbation {
                        element: t,
                        ..Default::default()
                    });
                    p.elements.last_mut().expect("just pushed")
                }
            };
            match self {
                OperandKind::Decenter => e.decenter_mm[axis] = value,
                OperandKind::Tilt => e.tilt_deg[axis] = value,
                OperandKind::Shift => e.shift_mm = value,
                OperandKind::Thickness => e.thickness_mm = value,
                OperandKind::Index => e.index = value,
                _ => e.abbe = value,
            }
        } else {
            let s = match p.surfaces.iter().position(|s| s.surface == t) {
                Some(k) => &mut p.surfaces[k],
                None => {
                    p.surfaces.push(SurfacePerturbation {
                        surface: t,
                        ..Default::default()
                    });
                    p.surfaces.last_mut().expect("just pushed")
                }
            };
            match self {
                OperandKind::Curvature => s.curvature_pct = value,
                OperandKind::Gap => s.gap_mm = value,
                OperandKind::SurfaceDecenter => s.decenter_mm[axis] = value,
                _ => s.tilt_deg[axis] = value,
            }
        }
    }
}

/// One operand of a spec.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Operand {
    /// What is perturbed.
    #[serde(rename = "type")]
    pub kind: OperandKind,
    /// Range: values lie in ±max (in the operand's unit); a finite number ≥ 0, checked when the
    /// spec is read.
    #[serde(deserialize_with = "non_negative_max")]
    pub max: f64,
    /// Distribution (default: the spec's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distribution: Option<Distribution>,
    /// Element indices it applies to (element operands; default: every element).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elements: Option<Vec<usize>>,
    /// Surface indices it applies to (surface operands; default: every refracting surface;
    /// for `gap`, every surface but the last).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surfaces: Option<Vec<usize>>,
}

/// Reads an operand's `max`, refusing what sampling would refuse later (a negative, NaN or
/// infinite range), so that every reader (files, the C ABI's JSON text) fails where the spec is.
fn non_negative_max<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    let v = f64::deserialize(d)?;
    if v >= 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(serde::de::Error::custom(format!(
            "range max {v} must be a finite number >= 0"
        )))
    }
}

/// A tolerance spec: operands with ranges and distributions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToleranceSpec {
    /// Default distribution of the operands.
    #[serde(default)]
    pub distribution: Distribution,
    /// Tilt pivot of the elements.
    #[serde(default)]
    pub pivot: Pivot,
    /// The operands.
    pub operands: Vec<Operand>,
}

impl Default for ToleranceSpec {
    /// The paper's Table A1: decenter ±0.04 mm, tilt ±0.05°, centre thickness (axial shift)
    /// ±0.04 mm per element, curvature ±0.3 % per surface; N(0, (max/3)²) clamped.
    fn default() -> Self {
        let op = |kind, max| Operand {
            kind,
            max,
            distribution: None,
            elements: None,
            surfaces: None,
        };
        ToleranceSpec {
            distribution: Distribution::Normal,
            pivot: Pivot::Front,
            operands: vec![
                op(OperandKind::Decenter, 0.04),
                op(OperandKind::Tilt, 0.05),
                op(OperandKind::Shift, 0.04),
                op(OperandKind::Curvature, 0.3),
            ],
        }
    }
}

/// One perturbation target: (operand index, target index, axis).
pub(crate) type Slot = (usize, usize, usize);

impl ToleranceSpec {
    /// Reads a spec file.
    ///
    /// # Errors
    /// I/O and JSON errors naming the file, line and column (unknown operands are named).
    pub fn read(path: &Path) -> Result<ToleranceSpec> {
        crate::files::read_json(path)
    }

    /// JSON text of the spec.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// The targets of every operand, in sampling order: operands in spec order, then targets in
    /// index order, then axes x, y, z.
    ///
    /// # Errors
    /// [`ErrorKind::Invalid`] for a negative or non-finite range or an index out of range.
    pub(crate) fn slots(&self, lens: &Lens) -> Result<Vec<Slot>> {
        let ne = find_elements(lens).len();
        let ns = lens.surfaces.len();
        let mut out = Vec::new();
        for (k, op) in self.operands.iter().enumerate() {
            let at = format!("operand {k} ({:?})", op.kind);
            if !(op.max >= 0.0) || !op.max.is_finite() {
                return Err(Error::invalid(format!(
                    "{at}: range max {} must be a non-negative number",
                    op.max
                )));
            }
            let limit = match op.kind {
                OperandKind::Index => super::MAX_INDEX_ERROR,
                OperandKind::Abbe => super::MAX_ABBE_ERROR,
                _ => f64::INFINITY,
            };
            if op.max > limit {
                return Err(Error::invalid(format!(
                    "{at}: range max {} is beyond the ±{limit} a pattern may hold",
                    op.max
                )));
            }
            let targets: Vec<usize> = if op.kind.per_element() {
                if op.surfaces.is_some() {
                    return Err(Error::invalid(format!(
                        "{at}: an element operand takes \"elements\", not \"surfaces\""
                    )));
                }
                let t = op.elements.clone().unwrap_or_else(|| (0..ne).collect());
                if let Some(&bad) = t.iter().find(|&&e| e >= ne) {
                    return Err(Error::invalid(format!(
                        "{at}: element {bad} is out of range (the lens has {ne} elements)"
                    )));
                }
                t
            } else {
                if op.elements.is_some() {
                    return Err(Error::invalid(format!(
                        "{at}: a surface operand takes \"surfaces\", not \"elements\""
                    )));
                }
                let default: Vec<usize> = match op.kind {
                    OperandKind::Gap => (0..ns - 1).collect(),
                    _ => (0..ns)
                        .filter(|&i| {
                            lens.surfaces[i].role == crate::lens::SurfaceRole::Refractive
                                && (op.kind != OperandKind::Curvature || lens.surfaces[i].c != 0.0)
                        })
                        .collect(),
                };
                let t = op.surfaces.clone().unwrap_or(default);
                if let Some(&bad) = t.iter().find(|&&s| s >= ns) {
                    return Err(Error::invalid(format!(
                        "{at}: surface {bad} is out of range (the lens has {ns} surfaces)"
                    )));
                }
                t
            };
            for t in targets {
                for axis in 0..op.kind.axes() {
                    out.push((k, t, axis));
                }
            }
        }
        Ok(out)
    }

    /// Pattern `index` of `seed`: the same on every machine and for any thread count (its random
    /// stream is ChaCha8 seeded with `seed`, stream number `index`).
    ///
    /// # Errors
    /// As [`ToleranceSpec::validate`].
    pub fn sample(&self, lens: &Lens, seed: u64, index: u64) -> Result<Perturbation> {
        let slots = self.slots(lens)?;
        Ok(self.sample_slots(&slots, seed, index))
    }

    pub(crate) fn sample_slots(&self, slots: &[Slot], seed: u64, index: u64) -> Perturbation {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        let mut p = Perturbation {
            pivot: self.pivot,
            ..Default::default()
        };
        for &(k, t, axis) in slots {
            let op = &self.operands[k];
            let v = draw(
                &mut rng,
                op.distribution.unwrap_or(self.distribution),
                op.max,
            );
            op.kind.set(&mut p, t, axis, v);
        }
        p.elements.sort_by_key(|e| e.element);
        p.surfaces.sort_by_key(|s| s.surface);
        p
    }

    /// Checks the spec against a lens.
    ///
    /// # Errors
    /// [`ErrorKind::Invalid`](crate::error::ErrorKind::Invalid) naming the operand and what is wrong.
    pub fn validate(&self, lens: &Lens) -> Result<()> {
        self.slots(lens).map(|_| ())
    }
}

/// One draw of `dist` over ±`max`.
fn draw(rng: &mut ChaCha8Rng, dist: Distribution, max: f64) -> f64 {
    if max == 0.0 {
        return 0.0;
    }
    match dist {
        Distribution::Normal => (crate::math::normal::one(rng) * max / 3.0).clamp(-max, max),
        Distribution::Uniform => (2.0 * rng.random::<f64>() - 1.0) * max,
        Distribution::TruncatedNormal => loop {
            let v = crate::math::normal::one(rng) * max / 3.0;
            if v.abs() <= max {
                break v;
            }
        },
    }
}
