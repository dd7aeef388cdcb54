//! Raw ray tracing from files: origins and directions in, image-plane hits out (CSV or JSON).

use super::{trace, RayBatch, RayStatus, TraceOptions};
use crate::error::{Error, ErrorKind, Result};
use crate::lens::System;
use crate::math::Vec3;
use serde::{Deserialize, Serialize};

/// An input ray: origin (mm), direction (need not be normalized), wavelength (nm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RawRay {
    /// Origin x, mm.
    pub ox: f64,
    /// Origin y, mm.
    pub oy: f64,
    /// Origin z, mm.
    pub oz: f64,
    /// Direction x.
    pub dx: f64,
    /// Direction y.
    pub dy: f64,
    /// Direction z.
    pub dz: f64,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
}

/// An output ray at the image plane (global frame).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RawHit {
    /// Position x, mm.
    pub x: f64,
    /// Position y, mm.
    pub y: f64,
    /// Position z, mm.
    pub z: f64,
    /// Unit direction x.
    pub dx: f64,
    /// Unit direction y.
    pub dy: f64,
    /// Unit direction z.
    pub dz: f64,
    /// Optical path length from the origin, mm.
    pub opl_mm: f64,
    /// `alive`, `vignetted@k`, `tir@k`, `missed@k` or `invalid`.
    pub status: String,
}

/// Traces `rays` (any mix of wavelengths) through `sys` in f64; output in input order.
/// Rays that did not reach the image carry their last position and a status naming the surface.
///
/// # Errors
/// [`ErrorKind::Invalid`] naming the first ray (1-based, in input order) whose wavelength gives
/// some medium no usable index (not a finite number from 0.9 to 5: a wavelength far outside
/// the glasses' formulas), the medium and its index there.
///
/// ```
/// use tolray::trace::{raw::{trace_raw, RawRay}, TraceOptions};
/// let sys = tolray::lens::builtin("lens1").unwrap().compile();
/// let ray = |wavelength_nm| RawRay {
///     ox: 0.0, oy: 1.0, oz: -10.0, dx: 0.0, dy: 0.0, dz: 1.0, wavelength_nm,
/// };
/// let hits = trace_raw(&sys, &[ray(587.6)], TraceOptions::default()).unwrap();
/// assert_eq!(hits[0].status, "alive");
/// let e = trace_raw(&sys, &[ray(587.6), ray(1e-300)], TraceOptions::default()).unwrap_err();
/// assert!(e.message().starts_with("ray 2 (wavelength 1e-300 nm)"), "{}", e.message());
/// ```
pub fn trace_raw(sys: &System<f64>, rays: &[RawRay], opts: TraceOptions) -> Result<Vec<RawHit>> {
    if let Some((i, (k, n))) = rays
        .iter()
        .enumerate()
        .filter(|(_, r)| r.wavelength_nm.is_finite() && r.wavelength_nm > 0.0)
        .find_map(|(i, r)| sys.unusable_index(r.wavelength_nm).map(|m| (i, m)))
    {
        let medium = match k {
            0 => "the object medium".to_string(),
            k => format!("the medium after surface {}", k - 1),
        };
        // (Display writes 1e-300 with 300 zeros.)
        let short = |x: f64| {
            if x == 0.0 || (1e-3..1e9).contains(&x.abs()) || !x.is_finite() {
                x.to_string()
            } else {
                format!("{x:e}")
            }
        };
        return Err(Error::invalid(format!(
            "ray {} (wavelength {} nm): {medium} has index {} there; a traced wavelength needs \
             every medium's index finite and from 0.9 to 5 (wavelengths are in nanometres)",
            i + 1,
            short(rays[i].wavelength_nm),
            short(n)
        )));
    }
    let mut out: Vec<Option<RawHit>> = vec![None; rays.len()];
    let mut wavelengths: Vec<f64> = rays.iter().map(|r| r.wavelength_nm).collect();
    wavelengths.sort_by(f64::total_cmp);
    // Grouped by the same relation that selects each group's rays below (0.0 and -0.0 differ
    // under total_cmp), so every input ray is traced and reported exactly once.
    wavelengths.dedup_by(|a, b| a.total_cmp(b).is_eq());
    for wl in wavelengths {
        let idx: Vec<usize> = (0..rays.len())
            .filter(|&i| rays[i].wavelength_nm.total_cmp(&wl).is_eq())
            .collect();
        let mut batch = RayBatch::<f64>::with_capacity(idx.len());
        for &i in &idx {
            let r = &rays[i];
            batch.push(Vec3::new(r.ox, r.oy, r.oz), Vec3::new(r.dx, r.dy, r.dz));
        }
        let ok_wl = wl.is_finite() && wl > 0.0;
        if ok_wl {
            trace(sys, wl, &mut batch, opts);
        }
        for (k, &i) in idx.iter().enumerate() {
            let r = batch.get(k);
            let status = if ok_wl { r.status } else { RayStatus::Invalid };
            out[i] = Some(RawHit {
                x: r.o.x,
                y: r.o.y,
                z: r.o.z,
                dx: r.d.x,
                dy: r.d.y,
                dz: r.d.z,
                opl_mm: r.opl,
                status: status.to_string(),
            });
        }
    }
    Ok(out.into_iter().flatten().collect())
}

/// Column names of the CSV input.
pub const INPUT_COLUMNS: [&str; 7] = ["ox", "oy", "oz", "dx", "dy", "dz", "wavelength_nm"];

/// Parses CSV input (`ox,oy,oz,dx,dy,dz,wavelength_nm`, optional header, `#` comments).
///
/// # Errors
/// [`ErrorKind::Parse`] naming the line and column.
pub fn parse_csv(text: &str) -> Result<Vec<RawRay>> {
    let mut rays = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.first().is_some_and(|f| f.eq_ignore_ascii_case("ox")) {
            if fields != INPUT_COLUMNS {
                return Err(Error::new(
                    ErrorKind::Parse,
                    format!(
                        "line {}: header must be {}",
                        ln + 1,
                        INPUT_COLUMNS.join(",")
                    ),
                ));
            }
            continue;
        }
        if fields.len() != 7 {
            return Err(Error::new(
                ErrorKind::Parse,
                format!(
                    "line {}: expected 7 columns ({}), found {}",
                    ln + 1,
                    INPUT_COLUMNS.join(","),
                    fields.len()
                ),
            ));
        }
        let mut v = [0.0; 7];
        for (k, f) in fields.iter().enumerate() {
            v[k] = f
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    Error::new(
                        ErrorKind::Parse,
                        format!(
                            "line {}, column {} ({}): \"{f}\" is not a finite number",
                            ln + 1,
                            k + 1,
                            INPUT_COLUMNS[k]
                        ),
                    )
                })?;
        }
        if !(v[6] > 0.0) {
            return Err(Error::new(
                ErrorKind::Parse,
                format!("line {}: wavelength_nm must be positive", ln + 1),
            ));
        }
        rays.push(RawRay {
            ox: v[0],
            oy: v[1],
            oz: v[2],
            dx: v[3],
            dy: v[4],
            dz: v[5],
            wavelength_nm: v[6],
        });
    }
    Ok(rays)
}

/// Parses JSON input: an array of objects with the CSV column names.
///
/// # Errors
/// [`ErrorKind::Parse`] with line and column.
pub fn parse_json(text: &str) -> Result<Vec<RawRay>> {
    serde_json::from_str(text).map_err(|e| {
        Error::new(
            ErrorKind::Parse,
            format!("line {}, column {}: {e}", e.line(), e.column()),
        )
    })
}

/// CSV output with header `x,y,z,dx,dy,dz,opl_mm,status`; numbers in shortest round-trip form.
pub fn to_csv(hits: &[RawHit]) -> String {
    let mut s = String::from("x,y,z,dx,dy,dz,opl_mm,status\n");
    for h in hits {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{}\n",
            h.x, h.y, h.z, h.dx, h.dy, h.dz, h.opl_mm, h.status
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_errors_name_line_and_column() {
        let e = parse_csv("ox,oy,oz,dx,dy,dz,wavelength_nm\n0,0,0,0,0,1,587\n0,0,x,0,0,1,587\n")
            .unwrap_err();
        assert!(
            e.message().starts_with("line 3, column 3 (oz)"),
            "{}",
            e.message()
        );
        let e = parse_csv("0,0,0,0,0,1\n").unwrap_err();
        assert!(e.message().contains("line 1: expected 7 columns"));
        assert_eq!(parse_csv("# c\n0,0,-1,0,0,1,587.5618\n").unwrap().len(), 1);
    }
}
