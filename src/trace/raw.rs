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
    check_wavelengths(sys, rays, 0)?;
    Ok(trace_checked(sys, rays, opts))
}

/// Refuses the first ray of `rays` (numbered from `first + 1` in messages) whose wavelength gives
/// some medium of `sys` no usable index.
fn check_wavelengths(sys: &System<f64>, rays: &[RawRay], first: usize) -> Result<()> {
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
            first + i + 1,
            short(rays[i].wavelength_nm),
            short(n)
        )));
    }
    Ok(())
}

/// [`trace_raw`] after [`check_wavelengths`].
fn trace_checked(sys: &System<f64>, rays: &[RawRay], opts: TraceOptions) -> Vec<RawHit> {
    let mut out: Vec<Option<RawHit>> = vec![None; rays.len()];
    // The rays grouped by wavelength (a stable sort: input order within a group; total_cmp, so
    // 0.0 and -0.0 are groups of their own and every input ray is traced exactly once).
    let wl = |i: usize| rays[i].wavelength_nm;
    let mut order: Vec<usize> = (0..rays.len()).collect();
    order.sort_by(|&a, &b| wl(a).total_cmp(&wl(b)));
    for idx in order.chunk_by(|&a, &b| wl(a).total_cmp(&wl(b)).is_eq()) {
        let wl = wl(idx[0]);
        let mut batch = RayBatch::<f64>::with_capacity(idx.len());
        for &i in idx {
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
    out.into_iter().flatten().collect()
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
        rays.extend(parse_csv_line(ln + 1, line)?);
    }
    Ok(rays)
}

/// Line `ln` (1-based) of CSV input: a ray, or `None` for a header, a comment or a blank line.
fn parse_csv_line(ln: usize, line: &str) -> Result<Option<RawRay>> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') {
        return Ok(None);
    }
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    if fields.first().is_some_and(|f| f.eq_ignore_ascii_case("ox")) {
        if fields != INPUT_COLUMNS {
            return Err(Error::new(
                ErrorKind::Parse,
                format!("line {ln}: header must be {}", INPUT_COLUMNS.join(",")),
            ));
        }
        return Ok(None);
    }
    if fields.len() != 7 {
        return Err(Error::new(
            ErrorKind::Parse,
            format!(
                "line {ln}: expected 7 columns ({}), found {}",
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
                        "line {ln}, column {} ({}): \"{f}\" is not a finite number",
                        k + 1,
                        INPUT_COLUMNS[k]
                    ),
                )
            })?;
    }
    if !(v[6] > 0.0) {
        return Err(Error::new(
            ErrorKind::Parse,
            format!("line {ln}: wavelength_nm must be positive"),
        ));
    }
    Ok(Some(RawRay {
        ox: v[0],
        oy: v[1],
        oz: v[2],
        dx: v[3],
        dy: v[4],
        dz: v[5],
        wavelength_nm: v[6],
    }))
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
    let mut s = String::from(CSV_HEADER);
    for h in hits {
        csv_row(&mut s, h);
    }
    s
}

/// The header line of the CSV output.
const CSV_HEADER: &str = "x,y,z,dx,dy,dz,opl_mm,status\n";

/// Appends the CSV row of `h`.
fn csv_row(s: &mut String, h: &RawHit) {
    use std::fmt::Write;
    let _ = writeln!(
        s,
        "{},{},{},{},{},{},{},{}",
        h.x, h.y, h.z, h.dx, h.dy, h.dz, h.opl_mm, h.status
    );
}

/// Input lines (CSV) or rays read, traced and written at a time by [`trace_csv_to`] and
/// [`trace_rays_to`].
pub const STREAM_RAYS: usize = 1 << 16;

/// The format of the hits that [`trace_csv_to`] and [`trace_rays_to`] write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HitFormat {
    /// [`to_csv`]'s text.
    Csv,
    /// `serde_json::to_string_pretty` of the hits, and a newline.
    Json,
}

/// What [`trace_csv_to`] or [`trace_rays_to`] traced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HitCounts {
    /// Rays traced (one hit written each).
    pub rays: usize,
    /// Rays that reached the image.
    pub alive: usize,
}

/// Writes hits in order, a chunk at a time, formatted on the rayon pool.
struct HitWriter<W: std::io::Write> {
    out: W,
    format: HitFormat,
    counts: HitCounts,
}

/// An output error of a streamed trace.
fn write_error(e: std::io::Error) -> Error {
    Error::new(ErrorKind::Io, format!("cannot write the hits: {e}"))
}

impl<W: std::io::Write> HitWriter<W> {
    fn new(mut out: W, format: HitFormat) -> Result<Self> {
        if format == HitFormat::Csv {
            out.write_all(CSV_HEADER.as_bytes()).map_err(write_error)?;
        }
        Ok(HitWriter {
            out,
            format,
            counts: HitCounts::default(),
        })
    }

    fn write(&mut self, hits: &[RawHit]) -> Result<()> {
        use rayon::prelude::*;
        let (format, first) = (self.format, self.counts.rays == 0);
        let texts: Vec<String> = hits
            .par_chunks(1024)
            .enumerate()
            .map(|(k, chunk)| {
                let mut s = String::with_capacity(chunk.len() * 160);
                for (i, h) in chunk.iter().enumerate() {
                    match format {
                        HitFormat::Csv => csv_row(&mut s, h),
                        HitFormat::Json => {
                            // The pretty array's element: the element's own pretty text,
                            // indented one level.
                            s.push_str(if first && k == 0 && i == 0 {
                                "[\n"
                            } else {
                                ",\n"
                            });
                            let one = serde_json::to_string_pretty(h).unwrap_or_default();
                            for (j, line) in one.lines().enumerate() {
                                if j > 0 {
                                    s.push('\n');
                                }
                                s.push_str("  ");
                                s.push_str(line);
                            }
                        }
                    }
                }
                s
            })
            .collect();
        for t in texts {
            self.out.write_all(t.as_bytes()).map_err(write_error)?;
        }
        self.counts.rays += hits.len();
        self.counts.alive += hits.iter().filter(|h| h.status == "alive").count();
        Ok(())
    }

    fn finish(mut self) -> Result<HitCounts> {
        if self.format == HitFormat::Json {
            let end = if self.counts.rays == 0 {
                "[]\n"
            } else {
                "\n]\n"
            };
            self.out.write_all(end.as_bytes()).map_err(write_error)?;
        }
        self.out.flush().map_err(write_error)?;
        Ok(self.counts)
    }
}

/// Traces `rays` as [`trace_raw`] does and writes their hits to `out` in `format`, a chunk of
/// [`STREAM_RAYS`] at a time (traced and formatted on the rayon pool): the bytes of [`to_csv`] or
/// of the pretty JSON of [`trace_raw`]'s hits, without holding them all.
///
/// # Errors
/// As [`trace_raw`]; [`ErrorKind::Io`] when `out` fails. Rays before the refused one may have been
/// written: write to a temporary file and keep it only on success (`tolray trace` does).
///
/// # Examples
/// ```
/// use tolray::trace::raw::{trace_raw, trace_rays_to, to_csv, HitFormat, RawRay};
/// use tolray::trace::TraceOptions;
/// let sys = tolray::lens::builtin("lens1").unwrap().compile();
/// let rays: Vec<RawRay> = (0..5)
///     .map(|k| RawRay { ox: 0.0, oy: k as f64, oz: -10.0, dx: 0.0, dy: 0.0, dz: 1.0,
///                       wavelength_nm: 587.6 })
///     .collect();
/// let mut out = Vec::new();
/// let n = trace_rays_to(&sys, &rays, &mut out, HitFormat::Csv, TraceOptions::default())?;
/// assert_eq!(n.rays, 5);
/// let hits = trace_raw(&sys, &rays, TraceOptions::default())?;
/// assert_eq!(String::from_utf8(out).unwrap(), to_csv(&hits));
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn trace_rays_to(
    sys: &System<f64>,
    rays: &[RawRay],
    out: impl std::io::Write,
    format: HitFormat,
    opts: TraceOptions,
) -> Result<HitCounts> {
    let mut w = HitWriter::new(out, format)?;
    for (k, chunk) in rays.chunks(STREAM_RAYS).enumerate() {
        check_wavelengths(sys, chunk, k * STREAM_RAYS)?;
        w.write(&trace_checked(sys, chunk, opts))?;
    }
    w.finish()
}

/// Reads CSV rays from `input` (as [`parse_csv`] reads them), traces them as [`trace_raw`] does
/// and writes their hits to `out` as [`trace_rays_to`] does, a chunk of [`STREAM_RAYS`] rays at a
/// time (parsed, traced and formatted on the rayon pool): memory independent of the number of
/// rays.
///
/// # Errors
/// As [`parse_csv`] and [`trace_raw`] (lines and rays numbered from the start of the input; the
/// first error of a chunk in input order, parse errors of a chunk before its wavelength errors);
/// [`ErrorKind::Io`] when `input` cannot be read or `out` written. Hits before the error may have
/// been written.
///
/// # Examples
/// ```
/// use tolray::trace::raw::{parse_csv, trace_csv_to, trace_rays_to, HitFormat};
/// use tolray::trace::TraceOptions;
/// let sys = tolray::lens::builtin("lens1").unwrap().compile();
/// let csv = "ox,oy,oz,dx,dy,dz,wavelength_nm\n\
///            0,1,-10,0,0,1,587.6\n# a comment\n0,2,-10,0,0.1,1,486.1\n";
/// let mut out = Vec::new();
/// let n = trace_csv_to(&sys, csv.as_bytes(), &mut out, HitFormat::Json, TraceOptions::default())?;
/// assert_eq!((n.rays, n.alive), (2, 2));
/// let mut whole = Vec::new();
/// let rays = parse_csv(csv)?;
/// trace_rays_to(&sys, &rays, &mut whole, HitFormat::Json, TraceOptions::default())?;
/// assert_eq!(out, whole);
/// let e = trace_csv_to(&sys, "0,1,-10,0,0,1,587.6\n0,1,x,0,0,1,587.6\n".as_bytes(),
///                      std::io::sink(), HitFormat::Csv, TraceOptions::default()).unwrap_err();
/// assert!(e.message().starts_with("line 2, column 3 (oz)"), "{}", e.message());
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn trace_csv_to(
    sys: &System<f64>,
    input: impl std::io::BufRead,
    out: impl std::io::Write,
    format: HitFormat,
    opts: TraceOptions,
) -> Result<HitCounts> {
    use rayon::prelude::*;
    let mut w = HitWriter::new(out, format)?;
    let mut lines = input.lines();
    let (mut line_no, mut traced) = (0, 0);
    loop {
        let mut chunk = Vec::with_capacity(STREAM_RAYS);
        for line in lines.by_ref().take(STREAM_RAYS) {
            chunk.push(line.map_err(|e| {
                Error::new(
                    ErrorKind::Io,
                    format!("cannot read line {}: {e}", line_no + chunk.len() + 1),
                )
            })?);
        }
        if chunk.is_empty() {
            break;
        }
        let parsed: Vec<Result<Option<RawRay>>> = chunk
            .par_iter()
            .enumerate()
            .map(|(k, l)| parse_csv_line(line_no + k + 1, l))
            .collect();
        line_no += chunk.len();
        let rays = parsed
            .into_iter()
            .filter_map(Result::transpose)
            .collect::<Result<Vec<RawRay>>>()?;
        check_wavelengths(sys, &rays, traced)?;
        traced += rays.len();
        w.write(&trace_checked(sys, &rays, opts))?;
    }
    w.finish()
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
