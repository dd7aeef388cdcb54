//! DeepLens' lens JSON: reading (2.5.x and legacy layouts) and writing.
//!
//! Accepted: `d_next` gaps or legacy absolute `d` (+ `d_sensor`), `roc` or `c`, `mat2` as a glass
//! name or `"n_d/V_d"` (legacy `mat1` ignored), `r_sensor` or `sensor_size`, `sensor_res`,
//! `obj_depth` (the object's z in mm: negative, or positive for a virtual object behind the
//! first vertex), `ai` with or without `use_ai2`. Keys in parentheses are
//! informational and ignored, except `"(object)": "inf"`, tolray's marker for an object at
//! infinity (DeepLens ignores it too). Unknown surface types are errors, never skipped.
//!
//! A surface's `r` is its semi-diameter and, as in DeepLens, clips rays. tolray adds an optional
//! `"aperture"` object (DeepLens ignores it) for what `r` cannot say: `{"type": "none"}` (the
//! surface does not clip: an OpticStudio semi-diameter), or a hard aperture
//! `{"type": "circular", "min": 0, "max": 5}`, `{"type": "rectangular", "half_x": 4, "half_y": 3}`,
//! `{"type": "elliptical", "half_x": 4, "half_y": 3}`, each with optional `"decenter": [x, y]`
//! (mm) and `"obscuration": true`.
//!
//! Also tolray's own (DeepLens ignores it, so such files are tolray's): `"shape"` on an
//! `Aspheric` or `Mirror` surface, `"even"` (the default: `ai` on ρ², ρ⁴, ...), `"odd"` (`ai` =
//! β1..β8 on ρ¹..ρ⁸, OpticStudio ODDASPHE), `"toroidal"` with `"c_rot"` (1/mm; `roc`, `k`
//! and `ai` describe the y-z profile, OpticStudio TOROIDAL), `"qbfs"` or `"qcon"` with
//! `"norm_radius"` (mm; `ai` = a_0..a_7 on Forbes' Q_0..Q_7, OpticStudio's Q-type asphere of
//! type 0 or 1; [`Shape::Qbfs`], [`Shape::Qcon`]), `"zernike_fringe"` or `"zernike_standard"`
//! with `"norm_radius"` (mm), `"zernike"` (the coefficients of Z1, Z2, ... in mm), and optional
//! `"zernike_decenter"` (`[x, y]` mm, default 0) and `"zernike_extrapolate"` (default true;
//! `ai` = α1..α8 on ρ²..ρ¹⁶; OpticStudio FZERNSAG and SZERNSAG, [`Shape::Zernike`]).
//! DeepLens' `ThinLens` (`"f"`, the
//! focal length in mm, between equal media) is an ideal thin lens (OpticStudio PARAXIAL).
//!
//! Two more surface keys of tolray's: `"roll_deg"`, the surface's rotation about its own axis
//! (degrees; [`Surface::roll_deg`]), and `"grating": {"lines_per_um": 0.6, "order": 1}`, a
//! diffraction grating ruled on the surface (grooves along its local x axis, OpticStudio's
//! DGRATING; [`super::Grating`]); `"phase": {"order": 1, "norm_radius": 10, "coefficients":
//! [-1000, 30]}`, a radial diffractive phase M Σ A_i ρ^(2i) in radians (OpticStudio's Binary 2;
//! [`super::phase::RadialPhase`]); `"gradient": {"form": "index", "n0": 1.6, "radial":
//! [-0.05], "axial": [], "step_mm": 0.1}`, a gradient-index medium after the surface
//! (OpticStudio's Gradient 1 to 3; [`super::Gradient`]; `"mat2"` then holds its vertex index).
//! On a mirror, `"fold": {"tilt_deg": [90, 0, 0], "pivot_mm": 0}` turns the axis for everything
//! after it (a fold mirror; [`super::Fold`]); the lens stays described unfolded.
//!
//! A top-level `"image_plane"` (`{"decenter": [x, y], "normal": [x, y, z], "roll_deg": r}`)
//! places a decentred, tilted or rolled image plane ([`super::ImagePlane`]); `"c"` (1/mm) and
//! `"k"` make it a curved (conic) image surface.
//!
//! A top-level `"object_medium"` (a medium written as `mat2` is) names the object space's
//! medium when it is not air (a .zmx `GLAS` on `SURF 0`, immersion optics).
//!
//! A top-level `"fields"` array keeps the field points of the lens' file (a .zmx file's, read
//! and converted): `{"angle_deg": [x, y]}`, `{"height_mm": [x, y]}` (object height),
//! `{"image_height_mm": [x, y]}` (paraxial image height, OpticStudio's field type 2) or
//! `{"real_image_height_mm": [x, y]}` (type 3), all of one kind, an optional `"weight"`,
//! and optional vignetting factors `"vignetting": {"vdx": 0, "vdy": 0.06, "vcx": 0, "vcy": 0.16}`
//! (OpticStudio's VDX, VDY, VCX, VCY; see [`crate::trace::Vignetting`]).

use super::field::{Field, FieldPoint, Vignetting};
use super::gradient::GradientForm;
use super::{
    Aperture, ApertureShape, GlassCatalogs, ImagePlane, Lens, Material, Object, Sensor, Shape,
    Surface, SurfaceRole, N_ASPH,
};
use crate::error::{Error, ErrorKind, Result};
use serde_json::{json, Map, Value};
use std::path::Path;

mod surface_keys;
use surface_keys::{fold, gradient, grating, phase};

/// Reads a lens JSON file; every error names the file.
///
/// # Errors
/// I/O errors, JSON syntax errors (with line and column), and prescription errors naming the
/// surface index and key.
pub fn read_file(path: &Path) -> Result<Lens> {
    read_file_with(path, &GlassCatalogs::builtin())
}

/// As [`read_file`], looking glass names up in `catalogs` (the user's AGF catalogs first).
///
/// # Errors
/// As [`read_file`].
pub fn read_file_with(path: &Path, catalogs: &GlassCatalogs) -> Result<Lens> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    from_str_with(&text, catalogs).map_err(|e| e.context(path.display()))
}

/// Parses lens JSON text.
///
/// # Errors
/// As [`read_file`], without the file name.
pub fn from_str(text: &str) -> Result<Lens> {
    from_str_with(text, &GlassCatalogs::builtin())
}

/// As [`from_str`], looking glass names up in `catalogs`.
///
/// # Errors
/// As [`from_str`].
pub fn from_str_with(text: &str, catalogs: &GlassCatalogs) -> Result<Lens> {
    let v: Value = serde_json::from_str(text).map_err(|e| {
        Error::new(
            ErrorKind::Parse,
            format!(
                "line {}, column {}: malformed JSON: {e}",
                e.line(),
                e.column()
            ),
        )
    })?;
    from_value_with(&v, catalogs)
}

fn num(obj: &Map<String, Value>, key: &str, at: &str) -> Result<Option<f64>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => Ok(n.as_f64()),
        Some(other) => Err(Error::new(
            ErrorKind::Parse,
            format!("{at}\"{key}\" must be a number, found {other}"),
        )),
    }
}

/// `unknown key "k" (a, b, ...)` for the first key of `obj` not in `allowed`.
fn unknown_key(obj: &Map<String, Value>, allowed: &[&str]) -> Option<String> {
    obj.keys()
        .find(|k| !allowed.contains(&k.as_str()))
        .map(|k| format!("unknown key \"{k}\" ({})", allowed.join(", ")))
}

fn num_array<const N: usize>(
    obj: &Map<String, Value>,
    key: &str,
    at: &str,
) -> Result<Option<[f64; N]>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Array(a)) if a.len() == N && a.iter().all(Value::is_number) => {
            let mut out = [0.0; N];
            for (o, x) in out.iter_mut().zip(a) {
                *o = x.as_f64().unwrap_or(f64::NAN);
            }
            Ok(Some(out))
        }
        Some(other) => Err(Error::new(
            ErrorKind::Parse,
            format!("{at}\"{key}\" must be an array of {N} numbers, found {other}"),
        )),
    }
}

fn finite(v: f64, at: &str, key: &str) -> Result<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::invalid(format!(
            "{at}\"{key}\" is not a finite number"
        )))
    }
}

/// tolray's `"aperture"` key of a surface (see the module documentation); absent: the
/// semi-diameter clips (DeepLens' meaning of `r`).
fn aperture(s: &Map<String, Value>, at: &str) -> Result<Option<Aperture>> {
    let Some(v) = s.get("aperture") else {
        return Ok(Some(Aperture::SEMI_DIAMETER));
    };
    let at = format!("{at}\"aperture\": ");
    let parse = |m: String| Error::new(ErrorKind::Parse, format!("{at}{m}"));
    let Value::Object(a) = v else {
        return Err(parse(format!("must be an object, found {v}")));
    };
    let ty = match a.get("type") {
        Some(Value::String(t)) => t.as_str(),
        _ => return Err(parse("needs a \"type\" string".into())),
    };
    let need = |key: &str| -> Result<f64> {
        num(a, key, &at)?
            .ok_or_else(|| parse(format!("a {ty} aperture needs \"{key}\" (mm)")))
            .and_then(|v| finite(v, &at, key))
    };
    let shape = match ty {
        "none" => return Ok(None),
        "semi_diameter" => ApertureShape::SemiDiameter,
        "circular" => ApertureShape::Circular {
            min_mm: num(a, "min", &at)?.map_or(Ok(0.0), |v| finite(v, &at, "min"))?,
            max_mm: need("max")?,
        },
        "rectangular" => ApertureShape::Rectangular {
            half_x_mm: need("half_x")?,
            half_y_mm: need("half_y")?,
        },
        "elliptical" => ApertureShape::Elliptical {
            half_x_mm: need("half_x")?,
            half_y_mm: need("half_y")?,
        },
        other => {
            return Err(Error::invalid(format!(
            "{at}unknown type \"{other}\" (none, semi_diameter, circular, rectangular, elliptical)"
        )))
        }
    };
    let obscuration = match a.get("obscuration") {
        None => false,
        Some(Value::Bool(b)) => *b,
        Some(other) => {
            return Err(parse(format!(
                "\"obscuration\" must be true or false, found {other}"
            )))
        }
    };
    let decenter_mm = num_array::<2>(a, "decenter", &at)?.unwrap_or([0.0; 2]);
    for v in decenter_mm {
        finite(v, &at, "decenter")?;
    }
    let ap = Aperture {
        shape,
        decenter_mm,
        obscuration,
    };
    ap.validate()
        .map_err(|e| Error::invalid(format!("{at}{}", e.full_message())))?;
    Ok(Some(ap))
}

/// tolray's top-level `"fields"` key: the lens file's field points (see the module
/// documentation); absent: none.
/// tolray's top-level `"image_plane"`: `{"decenter": [x, y], "normal": [x, y, z], "roll_deg": r,
/// "c": 1/mm, "k": conic}` (each optional; absent: a plane centred on and perpendicular to the
/// axis; `c` and `k` make it a curved image surface).
fn image_plane(top: &Map<String, Value>) -> Result<ImagePlane> {
    let Some(v) = top.get("image_plane") else {
        return Ok(ImagePlane::default());
    };
    let at = "\"image_plane\": ";
    let Some(obj) = v.as_object() else {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("{at}must be an object like {{\"normal\": [0, -0.05, 1]}}, found {v}"),
        ));
    };
    if let Some(m) = unknown_key(obj, &["decenter", "normal", "roll_deg", "c", "k"]) {
        return Err(Error::invalid(format!("{at}{m}")));
    }
    let d = ImagePlane::default();
    Ok(ImagePlane {
        decenter_mm: num_array::<2>(obj, "decenter", at)?.unwrap_or(d.decenter_mm),
        normal: num_array::<3>(obj, "normal", at)?.unwrap_or(d.normal),
        roll_deg: match num(obj, "roll_deg", at)? {
            Some(r) => finite(r, at, "roll_deg")?,
            None => 0.0,
        },
        curvature_per_mm: match num(obj, "c", at)? {
            Some(c) => finite(c, at, "c")?,
            None => 0.0,
        },
        conic: match num(obj, "k", at)? {
            Some(k) => finite(k, at, "k")?,
            None => 0.0,
        },
    })
}

fn fields(top: &Map<String, Value>) -> Result<Vec<FieldPoint>> {
    let Some(v) = top.get("fields") else {
        return Ok(Vec::new());
    };
    let Value::Array(list) = v else {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("\"fields\" must be an array, found {v}"),
        ));
    };
    let mut out = Vec::with_capacity(list.len());
    for (k, f) in list.iter().enumerate() {
        let at = format!("\"fields\" {}: ", k + 1);
        let parse = |m: String| Error::new(ErrorKind::Parse, format!("{at}{m}"));
        let Value::Object(m) = f else {
            return Err(parse(format!("must be an object, found {f}")));
        };
        const KINDS: [&str; 4] = [
            "angle_deg",
            "height_mm",
            "image_height_mm",
            "real_image_height_mm",
        ];
        if let Some(e) = unknown_key(m, &[&KINDS[..], &["weight", "vignetting"]].concat()) {
            return Err(parse(e));
        }
        let mut given = Vec::new();
        for (k, key) in KINDS.iter().enumerate() {
            if let Some([x, y]) = num_array::<2>(m, key, &at)? {
                given.push(match k {
                    0 => Field::AngleDeg { x, y },
                    1 => Field::HeightMm { x, y },
                    2 => Field::ImageHeightMm { x, y },
                    _ => Field::RealImageHeightMm { x, y },
                });
            }
        }
        let [field] = given[..] else {
            return Err(parse(format!(
                "needs exactly one of {} (each [x, y])",
                KINDS.map(|k| format!("\"{k}\"")).join(", ")
            )));
        };
        let mut vignetting = Vignetting::default();
        match m.get("vignetting") {
            None => {}
            Some(Value::Object(v)) => {
                let at = format!("{at}\"vignetting\": ");
                if let Some(e) = unknown_key(v, &["vdx", "vdy", "vcx", "vcy"]) {
                    return Err(parse(format!("\"vignetting\": {e}")));
                }
                let get = |key: &str| num(v, key, &at).map(|x| x.unwrap_or(0.0));
                vignetting = Vignetting {
                    decenter_x: get("vdx")?,
                    decenter_y: get("vdy")?,
                    compress_x: get("vcx")?,
                    compress_y: get("vcy")?,
                };
            }
            Some(other) => {
                return Err(parse(format!(
                    "\"vignetting\" must be an object, found {other}"
                )))
            }
        }
        out.push(FieldPoint {
            field,
            weight: num(m, "weight", &at)?.unwrap_or(1.0),
            vignetting,
        });
    }
    Ok(out)
}

/// The `"fields"` value of a lens' field points (`None` when it has none).
fn fields_value(points: &[FieldPoint]) -> Option<Value> {
    if points.is_empty() {
        return None;
    }
    let list = points
        .iter()
        .map(|p| {
            let mut m = Map::new();
            match p.field {
                Field::AngleDeg { x, y } => m.insert("angle_deg".into(), json!([x, y])),
                Field::HeightMm { x, y } => m.insert("height_mm".into(), json!([x, y])),
                Field::ImageHeightMm { x, y } => m.insert("image_height_mm".into(), json!([x, y])),
                Field::RealImageHeightMm { x, y } => {
                    m.insert("real_image_height_mm".into(), json!([x, y]))
                }
                // Validation keeps fractions out of a lens.
                Field::Fraction { x, y } => m.insert("fraction".into(), json!([x, y])),
            };
            m.insert("weight".into(), json!(p.weight));
            let v = p.vignetting;
            if !v.is_none() {
                m.insert(
                    "vignetting".into(),
                    json!({"vdx": v.decenter_x, "vdy": v.decenter_y, "vcx": v.compress_x, "vcy": v.compress_y}),
                );
            }
            Value::Object(m)
        })
        .collect();
    Some(Value::Array(list))
}

/// tolray's `"aperture"` value for `a`, or `None` where DeepLens' `r` says it all.
fn aperture_value(a: Option<&Aperture>) -> Option<Value> {
    let Some(a) = a else {
        return Some(json!({"type": "none"}));
    };
    let mut m = match a.shape {
        ApertureShape::SemiDiameter if a.decenter_mm == [0.0; 2] && !a.obscuration => return None,
        ApertureShape::SemiDiameter => json!({"type": "semi_diameter"}),
        ApertureShape::Circular { min_mm, max_mm } => {
            json!({"type": "circular", "min": min_mm, "max": max_mm})
        }
        ApertureShape::Rectangular {
            half_x_mm,
            half_y_mm,
        } => json!({"type": "rectangular", "half_x": half_x_mm, "half_y": half_y_mm}),
        ApertureShape::Elliptical {
            half_x_mm,
            half_y_mm,
        } => json!({"type": "elliptical", "half_x": half_x_mm, "half_y": half_y_mm}),
    };
    if a.decenter_mm != [0.0; 2] {
        m["decenter"] = json!(a.decenter_mm);
    }
    if a.obscuration {
        m["obscuration"] = json!(true);
    }
    Some(m)
}

/// Builds a lens from parsed JSON.
///
/// # Errors
/// As [`from_str`].
pub fn from_value(v: &Value) -> Result<Lens> {
    from_value_with(v, &GlassCatalogs::builtin())
}

/// As [`from_value`], looking glass names up in `catalogs`.
///
/// # Errors
/// As [`from_str`].
pub fn from_value_with(v: &Value, catalogs: &GlassCatalogs) -> Result<Lens> {
    let top = v
        .as_object()
        .ok_or_else(|| Error::new(ErrorKind::Parse, "the top level must be a JSON object"))?;
    let surfaces_v = top
        .get("surfaces")
        .and_then(Value::as_array)
        .ok_or_else(|| Error::invalid("missing key \"surfaces\" (an array of surfaces)"))?;
    if surfaces_v.is_empty() {
        return Err(Error::invalid("\"surfaces\" is empty"));
    }
    let mut surfaces = Vec::with_capacity(surfaces_v.len());
    let mut abs_d = Vec::with_capacity(surfaces_v.len());
    for (i, sv) in surfaces_v.iter().enumerate() {
        let at = format!("surface {i}: ");
        let s = sv
            .as_object()
            .ok_or_else(|| Error::invalid(format!("{at}must be a JSON object")))?;
        let (surface, d_abs) = surface_from(s, &at, catalogs)?;
        surfaces.push(surface);
        abs_d.push(d_abs);
    }
    // Gaps: d_next wins; else legacy absolute d (and d_sensor for the last gap).
    let d_sensor = num(top, "d_sensor", "")?;
    let n = surfaces.len();
    for i in 0..n {
        if surfaces[i].d_next_mm.is_nan() {
            let next = if i + 1 < n { abs_d[i + 1] } else { d_sensor };
            match (abs_d[i], next) {
                (Some(a), Some(b)) => surfaces[i].d_next_mm = b - a,
                _ => {
                    let what = if i + 1 < n {
                        "\"d_next\" (or legacy absolute \"d\" on this and the next surface)"
                    } else {
                        "\"d_next\" (the distance to the sensor; or legacy \"d\" with a top-level \"d_sensor\")"
                    };
                    return Err(Error::invalid(format!("surface {i}: missing {what}")));
                }
            }
        }
    }

    let object = match (
        top.get("(object)").and_then(Value::as_str),
        num(top, "obj_depth", "")?,
    ) {
        (Some(s), _) => Object::parse(s)?,
        // DeepLens' depth is the object's z: negative in front of the lens, positive behind
        // it (a virtual object).
        (None, Some(d)) if d > 0.0 && d.is_finite() => Object::Finite { distance_mm: -d },
        (None, Some(d)) => Object::parse(&d.to_string())
            .map_err(|e| Error::invalid(format!("\"obj_depth\" {d}: {}", e.full_message())))?,
        (None, None) => Object::Infinite,
    };
    let size = num_array::<2>(top, "sensor_size", "")?;
    let res = match num_array::<2>(top, "sensor_res", "")? {
        Some([w, h]) if w >= 1.0 && h >= 1.0 && w.fract() == 0.0 && h.fract() == 0.0 => {
            [w as u32, h as u32]
        }
        Some(r) => {
            return Err(Error::invalid(format!(
                "\"sensor_res\" {r:?} must be two positive whole numbers"
            )))
        }
        // 2000 pixels along the longer side of a given sensor size (square pixels).
        None => match size {
            Some([w, h]) if w > 0.0 && h > 0.0 && w.is_finite() && h.is_finite() => {
                let short = |a: f64, b: f64| ((2000.0 * a / b).round() as u32).clamp(1, 2000);
                if w >= h {
                    [2000, short(h, w)]
                } else {
                    [short(w, h), 2000]
                }
            }
            _ => [2000, 2000],
        },
    };
    // tolray's pixels are square: a size whose aspect differs from the resolution's by more
    // than a pixel's rounding would be silently reshaped.
    if let Some([w, h]) = size {
        let (rw, rh) = (res[0] as f64, res[1] as f64);
        if w > 0.0 && h > 0.0 && (rh - rw * h / w).abs() > 1.0 && (rw - rh * w / h).abs() > 1.0 {
            return Err(Error::invalid(format!(
                "\"sensor_size\" [{w}, {h}] mm and \"sensor_res\" [{rw}, {rh}] give \
                 non-square pixels ({:.4} x {:.4} µm); tolray models square pixels: give a \
                 resolution with the sensor's aspect ratio",
                1e3 * w / rw,
                1e3 * h / rh
            )));
        }
    }
    let sensor = match (num(top, "r_sensor", "")?, size) {
        (Some(r), _) if r > 0.0 && r.is_finite() => Sensor::from_half_diagonal(r, res),
        (None, Some([w, h])) if w > 0.0 && h > 0.0 => {
            Sensor::from_half_diagonal(0.5 * w.hypot(h), res)
        }
        (Some(r), _) => return Err(Error::invalid(format!("\"r_sensor\" {r} must be positive"))),
        _ => {
            return Err(Error::invalid(
                "missing \"r_sensor\" (sensor half-diagonal, mm) or \"sensor_size\" [w, h] mm",
            ))
        }
    };
    let primary_um = num(top, "primary_wvln", "")?.unwrap_or(0.5875618);
    let ok = crate::lens::material::wavelength_um_ok;
    if !ok(primary_um) {
        return Err(Error::invalid(format!(
            "\"primary_wvln\" {primary_um} must be in micrometres ({})",
            crate::lens::material::WAVELENGTH_RANGE_TEXT
        )));
    }
    let rgb_um = num_array::<3>(top, "wvln_rgb", "")?.unwrap_or([0.656, 0.587, 0.486]);
    if rgb_um.iter().any(|&w| !ok(w)) {
        return Err(Error::invalid(format!(
            "\"wvln_rgb\" {rgb_um:?} must be in micrometres ({})",
            crate::lens::material::WAVELENGTH_RANGE_TEXT
        )));
    }
    let lens = Lens {
        info: top
            .get("info")
            .and_then(Value::as_str)
            .unwrap_or("")
            .to_string(),
        surfaces,
        object,
        sensor,
        primary_wavelength_nm: primary_um * 1e3,
        rgb_wavelengths_nm: rgb_um.map(|w| w * 1e3),
        object_medium: match top.get("object_medium") {
            None => Material::Air,
            Some(Value::String(m)) => {
                Material::parse_with(m, catalogs).map_err(|e| e.context("\"object_medium\""))?
            }
            Some(other) => {
                return Err(Error::new(
                    ErrorKind::Parse,
                    format!(
                    "\"object_medium\" must be a string (a medium as in \"mat2\"), found {other}"
                ),
                ))
            }
        },
        fields: fields(top)?,
        ray_aiming: match top.get("ray_aiming") {
            None => false,
            Some(Value::Bool(b)) => *b,
            Some(other) => {
                return Err(Error::new(
                    ErrorKind::Parse,
                    format!("\"ray_aiming\" must be true or false, found {other}"),
                ))
            }
        },
        image_plane: image_plane(top)?,
    };
    lens.validate()?;
    Ok(lens)
}

fn surface_from(
    s: &Map<String, Value>,
    at: &str,
    catalogs: &GlassCatalogs,
) -> Result<(Surface, Option<f64>)> {
    let ty = s.get("type").and_then(Value::as_str).ok_or_else(|| {
        Error::invalid(format!(
            "{at}missing \"type\" (Spheric, Aspheric, Aperture, Stop, Plane, Mirror or ThinLens)"
        ))
    })?;
    let role = match ty {
        "Spheric" | "Aspheric" | "Plane" | "ThinLens" => SurfaceRole::Refractive,
        "Aperture" | "Stop" => SurfaceRole::Aperture,
        "Mirror" => SurfaceRole::Mirror,
        other => {
            return Err(Error::invalid(format!(
                "{at}unsupported surface type \"{other}\" (tolray traces Spheric, Aspheric, Aperture, Stop, Plane, Mirror and ThinLens)"
            )))
        }
    };
    let r = num(s, "r", at)?
        .ok_or_else(|| Error::invalid(format!("{at}missing \"r\" (semi-diameter, mm)")))?;
    let r = finite(r, at, "r")?;
    let c = match (num(s, "roc", at)?, num(s, "c", at)?) {
        (_, Some(c)) => finite(c, at, "c")?,
        (Some(roc), None) if roc == 0.0 || roc.is_infinite() => 0.0,
        (Some(roc), None) => {
            let c = 1.0 / finite(roc, at, "roc")?;
            // DeepLens writes the exact curvature as "(c)"; use it when it is 1/roc to rounding,
            // so that files written by tolray round-trip exactly.
            match num(s, "(c)", at)? {
                Some(cc) if (cc - c).abs() <= 8.0 * f64::EPSILON * c.abs() => cc,
                _ => c,
            }
        }
        (None, None) if role == SurfaceRole::Aperture || ty == "Plane" || ty == "ThinLens" => 0.0,
        (None, None) => {
            return Err(Error::invalid(format!(
                "{at}missing \"roc\" (radius, mm) or \"c\" (curvature, 1/mm)"
            )))
        }
    };
    let k = finite(num(s, "k", at)?.unwrap_or(0.0), at, "k")?;
    let mut asph = [0.0; N_ASPH];
    if let Some(ai) = s.get("ai") {
        let ai = ai
            .as_array()
            .filter(|a| a.iter().all(Value::is_number))
            .ok_or_else(|| {
                Error::new(
                    ErrorKind::Parse,
                    format!("{at}\"ai\" must be an array of numbers"),
                )
            })?;
        let use_ai2 = match s.get("use_ai2") {
            None => true,
            Some(Value::Bool(b)) => *b,
            Some(other) => {
                return Err(Error::new(
                    ErrorKind::Parse,
                    format!("{at}\"use_ai2\" must be true or false, found {other}"),
                ))
            }
        };
        let offset = usize::from(!use_ai2);
        if ai.len() + offset > N_ASPH {
            return Err(Error::invalid(format!(
                "{at}\"ai\" has {} terms; tolray supports even terms up to a16",
                ai.len()
            )));
        }
        for (j, a) in ai.iter().enumerate() {
            asph[j + offset] = finite(a.as_f64().unwrap_or(f64::NAN), at, "ai")?;
        }
    }
    let material = match s.get("mat2") {
        Some(Value::String(m)) => Material::parse_with(m, catalogs).map_err(|e| {
            e.context(format!(
                "surface {}",
                at.trim_end_matches(": ").trim_start_matches("surface ")
            ))
        })?,
        None => {
            return Err(Error::invalid(format!(
                "{at}missing \"mat2\" (the medium after the surface)"
            )))
        }
        Some(other) => {
            return Err(Error::new(
                ErrorKind::Parse,
                format!("{at}\"mat2\" must be a string, found {other}"),
            ))
        }
    };
    // tolray's "gradient" key makes the medium a gradient-index one ("mat2" then holds its
    // vertex index, for readers without it).
    let material = match gradient(s, at)? {
        Some(g) => Material::Gradient(Box::new(g)),
        None => material,
    };
    let is_square = s.get("is_square").and_then(Value::as_bool).unwrap_or(false);
    if is_square {
        return Err(Error::invalid(format!(
            "{at}square apertures (\"is_square\": true) are not supported"
        )));
    }
    let is_stop = role == SurfaceRole::Aperture
        || s.get("is_aperture")
            .and_then(Value::as_bool)
            .unwrap_or(false);
    let d_next = match num(s, "d_next", at)? {
        Some(d) => finite(d, at, "d_next")?,
        None => f64::NAN,
    };
    let shape = match s.get("shape") {
        None => Shape::Even,
        Some(Value::String(v)) => match v.as_str() {
            "even" => Shape::Even,
            "odd" => Shape::Odd,
            "toroidal" => Shape::Toroidal {
                c_rot: finite(num(s, "c_rot", at)?.unwrap_or(0.0), at, "c_rot")?,
            },
            q @ ("qbfs" | "qcon") => {
                let norm_radius_mm = finite(
                    num(s, "norm_radius", at)?.ok_or_else(|| {
                        Error::invalid(format!(
                            "{at}missing \"norm_radius\" (mm) of the \"{q}\" shape"
                        ))
                    })?,
                    at,
                    "norm_radius",
                )?;
                if q == "qbfs" {
                    Shape::Qbfs { norm_radius_mm }
                } else {
                    Shape::Qcon { norm_radius_mm }
                }
            }
            z @ ("zernike_fringe" | "zernike_standard") => {
                let norm_radius_mm = finite(
                    num(s, "norm_radius", at)?.ok_or_else(|| {
                        Error::invalid(format!(
                            "{at}missing \"norm_radius\" (mm) of the \"{z}\" shape"
                        ))
                    })?,
                    at,
                    "norm_radius",
                )?;
                let decenter_mm = match num_array::<2>(s, "zernike_decenter", at)? {
                    Some([x, y]) => [
                        finite(x, at, "zernike_decenter")?,
                        finite(y, at, "zernike_decenter")?,
                    ],
                    None => [0.0; 2],
                };
                let extrapolate = match s.get("zernike_extrapolate") {
                    None => true,
                    Some(Value::Bool(b)) => *b,
                    Some(other) => {
                        return Err(Error::new(
                            ErrorKind::Parse,
                            format!("{at}\"zernike_extrapolate\" must be true or false, found {other}"),
                        ))
                    }
                };
                Shape::Zernike {
                    ordering: if z == "zernike_fringe" {
                        crate::math::zernike::Ordering::Fringe
                    } else {
                        crate::math::zernike::Ordering::Standard
                    },
                    norm_radius_mm,
                    decenter_mm,
                    extrapolate,
                }
            }
            other => {
                return Err(Error::invalid(format!(
                    "{at}unknown \"shape\" \"{other}\" (even, odd, toroidal, qbfs, qcon, zernike_fringe or zernike_standard)"
                )))
            }
        },
        Some(other) => {
            return Err(Error::new(
                ErrorKind::Parse,
                format!("{at}\"shape\" must be a string, found {other}"),
            ))
        }
    };
    let shape = if ty == "ThinLens" {
        let f = num(s, "f", at)?
            .ok_or_else(|| Error::invalid(format!("{at}missing \"f\" (focal length, mm)")))?;
        Shape::Paraxial {
            focal_mm: finite(f, at, "f")?,
        }
    } else {
        shape
    };
    if shape != Shape::Even && role == SurfaceRole::Aperture {
        return Err(Error::invalid(format!(
            "{at}an {ty} surface is flat; \"shape\" belongs on Aspheric or Mirror surfaces"
        )));
    }
    let zernike = match s.get("zernike") {
        None => Vec::new(),
        Some(Value::Array(v)) => v
            .iter()
            .map(|a| finite(a.as_f64().unwrap_or(f64::NAN), at, "zernike"))
            .collect::<Result<Vec<f64>>>()?,
        Some(other) => {
            return Err(Error::new(
                ErrorKind::Parse,
                format!("{at}\"zernike\" must be an array of numbers (mm), found {other}"),
            ))
        }
    };
    if !zernike.is_empty() && !matches!(shape, Shape::Zernike { .. }) {
        return Err(Error::invalid(format!(
            "{at}\"zernike\" coefficients belong on a \"zernike_fringe\" or \"zernike_standard\" shape"
        )));
    }
    let surface = Surface {
        role,
        c,
        k,
        asph,
        shape,
        zernike,
        semi_aperture_mm: r,
        aperture: aperture(s, at)?,
        d_next_mm: d_next,
        material,
        is_stop,
        pos_xy_mm: num_array::<2>(s, "pos_xy", at)?.unwrap_or([0.0; 2]),
        vec_local: num_array::<3>(s, "vec_local", at)?.unwrap_or([0.0, 0.0, 1.0]),
        roll_deg: match num(s, "roll_deg", at)? {
            Some(v) => finite(v, at, "roll_deg")?,
            None => 0.0,
        },
        grating: grating(s, at)?,
        fold: fold(s, at)?,
        phase: phase(s, at)?,
    };
    Ok((surface, num(s, "d", at)?))
}

/// The lens as DeepLens 2.5-style JSON (plus tolray's ignored `"(object)"` key at infinity).
pub fn to_value(lens: &Lens) -> Value {
    let mut top = Map::new();
    top.insert("info".into(), json!(lens.info));
    if let Ok(p) = lens.paraxial(lens.primary_wavelength_nm) {
        // An afocal lens has neither (DeepLens' keys are informative; tolray ignores them).
        if let (Some(f), Some(n)) = (p.efl_mm, p.fnum) {
            top.insert("foclen".into(), json!(f));
            top.insert("fnum".into(), json!(n));
        }
    }
    // µm values that read back to the same nm (exact round trips).
    let um = super::material::um_from_nm;
    top.insert("primary_wvln".into(), json!(um(lens.primary_wavelength_nm)));
    top.insert("wvln_rgb".into(), json!(lens.rgb_wavelengths_nm.map(um)));
    match lens.object {
        Object::Finite { distance_mm } => {
            top.insert("obj_depth".into(), json!(-distance_mm));
        }
        Object::Infinite => {
            top.insert("(object)".into(), json!("inf"));
        }
    }
    top.insert("r_sensor".into(), json!(lens.sensor.half_diagonal_mm()));
    top.insert(
        "(d_sensor)".into(),
        json!(lens.vertex_z_mm().last().copied().unwrap_or(0.0)),
    );
    top.insert("(sensor_size)".into(), json!(lens.sensor.size_mm()));
    top.insert("sensor_res".into(), json!(lens.sensor.resolution));
    if lens.ray_aiming {
        top.insert("ray_aiming".into(), json!(true));
    }
    if !lens.object_medium.is_air() {
        top.insert(
            "object_medium".into(),
            json!(lens.object_medium.json_name()),
        );
    }
    if let Some(f) = fields_value(&lens.fields) {
        top.insert("fields".into(), f);
    }
    if !lens.image_plane.is_default() {
        let ip = &lens.image_plane;
        let mut v =
            json!({"decenter": ip.decenter_mm, "normal": ip.normal, "roll_deg": ip.roll_deg});
        if ip.is_curved() || ip.conic != 0.0 {
            v["c"] = json!(ip.curvature_per_mm);
            v["k"] = json!(ip.conic);
        }
        top.insert("image_plane".into(), v);
    }
    let surfaces: Vec<Value> = lens
        .surfaces
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let mut m = Map::new();
            m.insert("idx".into(), json!(i));
            let ty = match s.role {
                _ if matches!(s.shape, Shape::Paraxial { .. }) => "ThinLens",
                SurfaceRole::Aperture => "Aperture",
                SurfaceRole::Refractive if s.k != 0.0 || s.is_aspheric() => "Aspheric",
                SurfaceRole::Refractive => "Spheric",
                SurfaceRole::Mirror => "Mirror",
            };
            m.insert("type".into(), json!(ty));
            m.insert("r".into(), json!(s.semi_aperture_mm));
            if let Shape::Paraxial { focal_mm } = s.shape {
                m.insert("f".into(), json!(focal_mm));
            } else if s.role != SurfaceRole::Aperture {
                let roc = if s.c == 0.0 { 0.0 } else { 1.0 / s.c };
                if roc.is_finite() {
                    m.insert("(c)".into(), json!(s.c));
                    m.insert("roc".into(), json!(roc));
                } else {
                    // A curvature so small that its radius overflows (below ~5.6e-309 /mm):
                    // written as the curvature the reader takes as it is.
                    m.insert("c".into(), json!(s.c));
                }
            }
            if ty == "Aspheric" || ty == "Mirror" {
                m.insert("k".into(), json!(s.k));
                m.insert("ai".into(), json!(s.asph.to_vec()));
                m.insert("use_ai2".into(), json!(true));
                match s.shape {
                    Shape::Even | Shape::Paraxial { .. } => {}
                    Shape::Odd => {
                        m.insert("shape".into(), json!("odd"));
                    }
                    Shape::Toroidal { c_rot } => {
                        m.insert("shape".into(), json!("toroidal"));
                        m.insert("c_rot".into(), json!(c_rot));
                    }
                    Shape::Qbfs { norm_radius_mm } => {
                        m.insert("shape".into(), json!("qbfs"));
                        m.insert("norm_radius".into(), json!(norm_radius_mm));
                    }
                    Shape::Qcon { norm_radius_mm } => {
                        m.insert("shape".into(), json!("qcon"));
                        m.insert("norm_radius".into(), json!(norm_radius_mm));
                    }
                    Shape::Zernike {
                        ordering,
                        norm_radius_mm,
                        decenter_mm,
                        extrapolate,
                    } => {
                        let name = match ordering {
                            crate::math::zernike::Ordering::Fringe => "zernike_fringe",
                            crate::math::zernike::Ordering::Standard => "zernike_standard",
                        };
                        m.insert("shape".into(), json!(name));
                        m.insert("norm_radius".into(), json!(norm_radius_mm));
                        m.insert("zernike".into(), json!(s.zernike));
                        if decenter_mm != [0.0; 2] {
                            m.insert("zernike_decenter".into(), json!(decenter_mm));
                        }
                        if !extrapolate {
                            m.insert("zernike_extrapolate".into(), json!(false));
                        }
                    }
                }
            }
            m.insert("d_next".into(), json!(s.d_next_mm));
            m.insert("pos_xy".into(), json!(s.pos_xy_mm));
            m.insert("vec_local".into(), json!(s.vec_local));
            if s.roll_deg != 0.0 {
                m.insert("roll_deg".into(), json!(s.roll_deg));
            }
            if let Some(g) = s.grating {
                m.insert(
                    "grating".into(),
                    json!({"lines_per_um": g.lines_per_um, "order": g.order}),
                );
            }
            if let Some(p) = &s.phase {
                m.insert(
                    "phase".into(),
                    json!({"order": p.order, "norm_radius": p.norm_radius_mm, "coefficients": p.coefficients}),
                );
            }
            if let Some(f) = s.fold {
                m.insert(
                    "fold".into(),
                    json!({"tilt_deg": f.tilt_deg, "pivot_mm": f.pivot_mm}),
                );
            }
            m.insert("is_square".into(), json!(false));
            m.insert("mat2".into(), json!(s.material.json_name()));
            if let Material::Gradient(g) = &s.material {
                let form = match g.form {
                    GradientForm::Index => "index",
                    GradientForm::IndexSquared => "index_squared",
                };
                let used = |v: &[f64]| v.iter().rposition(|&a| a != 0.0).map_or(0, |j| j + 1);
                m.insert(
                    "gradient".into(),
                    json!({"form": form, "n0": g.n0, "radial": g.radial[..used(&g.radial)],
                        "axial": g.axial[..used(&g.axial)], "step_mm": g.step_mm}),
                );
            }
            if let Some(a) = aperture_value(s.aperture.as_ref()) {
                m.insert("aperture".into(), a);
            }
            if s.is_stop && s.role != SurfaceRole::Aperture {
                m.insert("is_aperture".into(), json!(true));
            }
            Value::Object(m)
        })
        .collect();
    top.insert("surfaces".into(), Value::Array(surfaces));
    Value::Object(top)
}

/// Pretty-printed JSON text of the lens.
pub fn to_string(lens: &Lens) -> String {
    let mut s = serde_json::to_string_pretty(&to_value(lens)).unwrap_or_default();
    s.push('\n');
    s
}

/// Serde helpers that store a [`Lens`] as its DeepLens JSON text in a string field (what
/// training checkpoints hold): `#[serde(with = "tolray::lens::json::as_text")]`. Reading
/// parses the text with the built-in glass catalog; the round trip is exact.
///
/// # Examples
/// ```
/// use serde::{Deserialize, Serialize};
/// #[derive(Serialize, Deserialize)]
/// struct Saved {
///     #[serde(with = "tolray::lens::json::as_text")]
///     lens: tolray::Lens,
/// }
/// let lens = tolray::Lens::load("lens1")?;
/// let text = serde_json::to_string(&Saved { lens: lens.clone() }).unwrap();
/// let back: Saved = serde_json::from_str(&text).unwrap();
/// assert_eq!(tolray::lens::json::to_string(&back.lens), tolray::lens::json::to_string(&lens));
/// # Ok::<(), tolray::Error>(())
/// ```
pub mod as_text {
    use super::{from_str, to_string, Lens};
    use serde::{Deserialize, Deserializer, Serializer};

    /// Writes the lens as a string of DeepLens JSON.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(lens: &Lens, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(&to_string(lens))
    }

    /// Reads a lens from a string of DeepLens JSON.
    ///
    /// # Errors
    /// The deserializer's, and the lens reader's message for invalid text.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Lens, D::Error> {
        let text = String::deserialize(d)?;
        from_str(&text).map_err(|e| serde::de::Error::custom(e.full_message()))
    }

    /// [`as_text`](self) for an optional lens (`null` when absent).
    pub mod option {
        use super::{from_str, to_string, Lens};
        use serde::{Deserialize, Deserializer, Serializer};

        /// Writes the lens as a string of DeepLens JSON, or `null`.
        ///
        /// # Errors
        /// The serializer's.
        pub fn serialize<S: Serializer>(
            lens: &Option<Lens>,
            s: S,
        ) -> std::result::Result<S::Ok, S::Error> {
            match lens {
                Some(l) => s.serialize_some(&to_string(l)),
                None => s.serialize_none(),
            }
        }

        /// Reads an optional string of DeepLens JSON.
        ///
        /// # Errors
        /// The deserializer's, and the lens reader's message for invalid text.
        pub fn deserialize<'de, D: Deserializer<'de>>(
            d: D,
        ) -> std::result::Result<Option<Lens>, D::Error> {
            Option::<String>::deserialize(d)?
                .map(|t| from_str(&t).map_err(|e| serde::de::Error::custom(e.full_message())))
                .transpose()
        }
    }
}

/// Writes the lens to `path` atomically.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path.
pub fn write_file(lens: &Lens, path: &Path) -> Result<()> {
    crate::files::write_atomic(path, to_string(lens).as_bytes())
}
