//! tolray's own keys of a surface beyond DeepLens': `"fold"`, `"grating"`, `"phase"` and
//! `"gradient"` (see the [parent module](super)'s documentation).

use super::{finite, num, num_array, unknown_key};
use crate::error::{Error, ErrorKind, Result};
use crate::lens::gradient::{Gradient, GradientForm, N_AXIAL, N_RADIAL};
use crate::lens::phase::RadialPhase;
use crate::lens::{Fold, Grating};
use serde_json::{Map, Value};

/// tolray's `"fold"` key of a mirror: `{"tilt_deg": [a, b, g], "pivot_mm": p}` (`pivot_mm`
/// defaults to 0).
pub(super) fn fold(s: &Map<String, Value>, at: &str) -> Result<Option<Fold>> {
    let Some(v) = s.get("fold") else {
        return Ok(None);
    };
    let Some(obj) = v.as_object() else {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("{at}\"fold\" must be an object like {{\"tilt_deg\": [90, 0, 0], \"pivot_mm\": 0}}, found {v}"),
        ));
    };
    if let Some(e) = unknown_key(obj, &["tilt_deg", "pivot_mm"]) {
        return Err(Error::invalid(format!("{at}\"fold\": {e}")));
    }
    let Some(t) = num_array::<3>(obj, "tilt_deg", at)? else {
        return Err(Error::invalid(format!(
            "{at}\"fold\" needs \"tilt_deg\" (tilts about x, y, z in degrees)"
        )));
    };
    let mut tilt_deg = [0.0; 3];
    for (o, v) in tilt_deg.iter_mut().zip(t) {
        *o = finite(v, at, "fold tilt_deg")?;
    }
    Ok(Some(Fold {
        tilt_deg,
        pivot_mm: match num(obj, "pivot_mm", at)? {
            Some(p) => finite(p, at, "fold pivot_mm")?,
            None => 0.0,
        },
    }))
}

/// tolray's `"grating"` key of a surface: `{"lines_per_um": T, "order": m}`.
pub(super) fn grating(s: &Map<String, Value>, at: &str) -> Result<Option<Grating>> {
    let Some(v) = s.get("grating") else {
        return Ok(None);
    };
    let Some(obj) = v.as_object() else {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("{at}\"grating\" must be an object like {{\"lines_per_um\": 0.6, \"order\": 1}}, found {v}"),
        ));
    };
    if let Some(e) = unknown_key(obj, &["lines_per_um", "order"]) {
        return Err(Error::invalid(format!("{at}\"grating\": {e}")));
    }
    let get = |key: &str| -> Result<f64> {
        match num(obj, key, at)? {
            Some(x) => finite(x, at, key),
            None => Err(Error::invalid(format!("{at}\"grating\" needs \"{key}\""))),
        }
    };
    Ok(Some(Grating {
        lines_per_um: get("lines_per_um")?,
        order: get("order")?,
    }))
}

/// tolray's `"phase"` key: `{"order": 1, "norm_radius": 10, "coefficients": [-1000, 30]}` (a
/// radial diffractive phase, OpticStudio's Binary 2: radians on ρ², ρ⁴, ...).
pub(super) fn phase(s: &Map<String, Value>, at: &str) -> Result<Option<RadialPhase>> {
    let Some(v) = s.get("phase") else {
        return Ok(None);
    };
    let Some(obj) = v.as_object() else {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("{at}\"phase\" must be an object like {{\"order\": 1, \"norm_radius\": 10, \"coefficients\": [-1000]}}, found {v}"),
        ));
    };
    if let Some(e) = unknown_key(obj, &["order", "norm_radius", "coefficients"]) {
        return Err(Error::invalid(format!("{at}\"phase\": {e}")));
    }
    let get = |key: &str| -> Result<f64> {
        match num(obj, key, at)? {
            Some(x) => finite(x, at, key),
            None => Err(Error::invalid(format!("{at}\"phase\" needs \"{key}\""))),
        }
    };
    let coefficients = match obj.get("coefficients") {
        Some(Value::Array(v)) => v
            .iter()
            .map(|a| finite(a.as_f64().unwrap_or(f64::NAN), at, "coefficients"))
            .collect::<Result<Vec<f64>>>()?,
        other => {
            return Err(Error::invalid(format!(
                "{at}\"phase\" needs \"coefficients\", an array of numbers (radians), found {}",
                other.map_or("nothing".to_string(), |o| o.to_string())
            )))
        }
    };
    Ok(Some(RadialPhase {
        order: get("order")?,
        norm_radius_mm: get("norm_radius")?,
        coefficients,
    }))
}

/// tolray's `"gradient"` key: `{"form": "index", "n0": 1.6, "radial": [-0.05], "axial": [],
/// "step_mm": 0.1}`, a gradient-index medium after the surface ([`Gradient`]; `"form"`
/// `"index_squared"` for n² = n0² + ...; up to six radial terms on r², r⁴, ... and three axial on
/// z, z², z³, mm-based).
pub(super) fn gradient(s: &Map<String, Value>, at: &str) -> Result<Option<Gradient>> {
    let Some(v) = s.get("gradient") else {
        return Ok(None);
    };
    let bad = |m: String| Error::invalid(format!("{at}\"gradient\": {m}"));
    let Some(obj) = v.as_object() else {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("{at}\"gradient\" must be an object like {{\"form\": \"index\", \"n0\": 1.6, \"radial\": [-0.05], \"step_mm\": 0.1}}, found {v}"),
        ));
    };
    if let Some(e) = unknown_key(obj, &["form", "n0", "radial", "axial", "step_mm"]) {
        return Err(bad(e));
    }
    let form = match obj.get("form").and_then(Value::as_str) {
        Some("index") => GradientForm::Index,
        Some("index_squared") => GradientForm::IndexSquared,
        other => {
            return Err(bad(format!(
                "\"form\" must be \"index\" or \"index_squared\", found {}",
                other.unwrap_or("nothing")
            )))
        }
    };
    let get = |key: &str| -> Result<f64> {
        match num(obj, key, at)? {
            Some(x) => finite(x, at, key),
            None => Err(bad(format!("needs \"{key}\""))),
        }
    };
    let terms = |key: &str, max: usize| -> Result<Vec<f64>> {
        match obj.get(key) {
            None => Ok(Vec::new()),
            Some(Value::Array(v)) if v.len() <= max => v
                .iter()
                .map(|a| finite(a.as_f64().unwrap_or(f64::NAN), at, key))
                .collect(),
            Some(other) => Err(bad(format!(
                "\"{key}\" must be an array of at most {max} numbers, found {other}"
            ))),
        }
    };
    let mut g = Gradient::radial(
        form,
        get("n0")?,
        &terms("radial", N_RADIAL)?,
        get("step_mm")?,
    );
    let axial = terms("axial", N_AXIAL)?;
    g.axial[..axial.len()].copy_from_slice(&axial);
    g.validate().map_err(|e| bad(e.full_message()))?;
    Ok(Some(g))
}
