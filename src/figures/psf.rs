//! PSF mosaics in inferno with a colour bar; linear EXR files.

use super::*;

/// A PSF (or a mosaic of PSFs) as a heat map in the *inferno* colour map, each tile normalised
/// to its own peak (linear), with a colour bar. `tiles` are `ks x ks` row-major images laid out
/// `cols` per row (row 0 at the top).
#[must_use]
pub fn psf_figure(tiles: &[Vec<f64>], ks: usize, cols: usize, title: &str) -> Figure {
    let cols = cols.max(1);
    let rows = tiles.len().div_ceil(cols).max(1);
    let scale = (600 / (cols * ks.max(1))).clamp(1, 12) as u32;
    let tile = ks as u32 * scale;
    Figure {
        width: (cols as u32 * (tile + 2) + 150).clamp(420, MAX_SIDE_PT),
        height: (rows as u32 * (tile + 2) + 60).clamp(200, MAX_SIDE_PT),
        title: title.to_string(),
        kind: Kind::Psf {
            tiles: tiles.to_vec(),
            ks,
            cols,
            scale,
        },
    }
}

pub(super) fn inferno(t: f64) -> RGBColor {
    let c = colorous::INFERNO.eval_continuous(if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    });
    RGBColor(c.r, c.g, c.b)
}

pub(super) fn draw_psf<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    tiles: &[Vec<f64>],
    ks: usize,
    cols: usize,
    scale: u32,
) -> DrawResult<DB> {
    let p = |v: f64| (v * s).round() as i32;
    let cell = f64::from(scale);
    let tile = ks as f64 * cell;
    let x0 = 20.0;
    let y0 = 10.0;
    for (k, t) in tiles.iter().enumerate() {
        let (c, r) = ((k % cols) as f64, (k / cols) as f64);
        let (tx, ty) = (x0 + c * (tile + 2.0), y0 + r * (tile + 2.0));
        let peak = t
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        let norm = if peak > 0.0 { 1.0 / peak } else { 0.0 };
        for j in 0..ks {
            for i in 0..ks {
                let v = t.get(j * ks + i).copied().unwrap_or(0.0) * norm;
                let (ax, ay) = (tx + i as f64 * cell, ty + j as f64 * cell);
                body.draw(&Rectangle::new(
                    [(p(ax), p(ay)), (p(ax + cell), p(ay + cell))],
                    inferno(v).filled(),
                ))?;
            }
        }
    }
    // Colour bar to the right of the mosaic.
    let rows = tiles.len().div_ceil(cols).max(1) as f64;
    let height = (rows * (tile + 2.0) - 2.0).max(120.0);
    let bx = x0 + cols as f64 * (tile + 2.0) + 18.0;
    let ticks: Vec<(f64, String)> = [0.0, 0.25, 0.5, 0.75, 1.0]
        .iter()
        .map(|&v| (v, tick(v)))
        .collect();
    colour_bar(
        body,
        s,
        (bx, y0, height),
        inferno,
        &ticks,
        "intensity / tile peak",
        46.0,
    )?;
    Ok(())
}

/// Writes a single-channel linear image (e.g. a PSF map mosaic) as OpenEXR, atomically.
///
/// # Errors
/// [`crate::ErrorKind::Io`] naming the path.
pub fn save_exr(path: &Path, width: usize, height: usize, values: &[f64]) -> Result<()> {
    write_exr(path, width, height, |i| {
        let v = values.get(i).copied().unwrap_or(0.0) as f32;
        (v, v, v)
    })
}

/// Writes planar linear RGB (`3 · width · height` values, channel-major) as a 32-bit float
/// OpenEXR file, atomically.
///
/// # Errors
/// [`crate::ErrorKind::Io`] naming the path.
pub fn save_exr_rgb(path: &Path, width: usize, height: usize, planar: &[f32]) -> Result<()> {
    let n = width * height;
    write_exr(path, width, height, |i| {
        let g = |c: usize| planar.get(c * n + i).copied().unwrap_or(0.0);
        (g(0), g(1), g(2))
    })
}

/// Writes an RGB EXR whose pixel `i` (row-major) is `rgb(i)`, through a temporary file.
pub(super) fn write_exr(
    path: &Path,
    width: usize,
    height: usize,
    rgb: impl Fn(usize) -> (f32, f32, f32) + Sync,
) -> Result<()> {
    crate::files::write_via_temp(path, |tmp| {
        exr::prelude::write_rgb_file(tmp, width, height, |x, y| rgb(y * width + x))
            .map_err(|e| std::io::Error::other(e.to_string()))
    })
}

/// Lays `tiles` (`ks x ks` each) out in a `cols`-wide mosaic: (width, height, values).
#[must_use]
pub fn mosaic(tiles: &[Vec<f64>], ks: usize, cols: usize) -> (usize, usize, Vec<f64>) {
    let rows = tiles.len().div_ceil(cols.max(1));
    let (w, h) = (cols * ks, rows * ks);
    let mut out = vec![0.0; w * h];
    for (k, t) in tiles.iter().enumerate() {
        let (c, r) = (k % cols, k / cols);
        for j in 0..ks {
            for i in 0..ks {
                out[(r * ks + j) * w + c * ks + i] = t[j * ks + i];
            }
        }
    }
    (w, h, out)
}
