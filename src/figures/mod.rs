//! Pictures: spot diagrams, lens layouts, tolerance histograms, PSF maps, training curves, and
//! the wave-optics pictures (OPD maps, Zernike bar charts, MTF curves; `wave.rs`).
//!
//! Each `*_figure` function gathers what a picture shows into a [`Figure`]; [`save`] draws it
//! with [`plotters`] in an embedded DejaVu Sans (so every machine draws the same glyphs, µ and λ
//! included) and writes it atomically as SVG (for `.svg` paths) or PNG (anything else), the PNG
//! at [`PNG_SCALE`] pixels per point for sharp lines and text. Series colours are Okabe-Ito
//! ([`PALETTE`]); heat maps use matplotlib's *inferno*, exact to its 256-entry table
//! (`colorous`). Non-finite values in the data are skipped, never drawn at a wrong place.
//!
//! # Examples
//! ```
//! use tolray::analysis::{spot_diagram, SpotOptions};
//! use tolray::trace::{Field, Pupil, TraceOptions};
//! use tolray::{figures, Lens};
//!
//! # fn main() -> tolray::Result<()> {
//! let lens = Lens::load("cooke-triplet")?;
//! let opts = SpotOptions {
//!     fields: vec![Field::fraction(0.0), Field::fraction(1.0)],
//!     wavelengths_nm: vec![486.1327, 587.5618, 656.2725],
//!     pupil: Pupil::grid(16),
//!     trace: TraceOptions { apertures: true },
//! };
//! let spots = spot_diagram(&lens, &lens.compile(), &opts)?;
//! let fig = figures::spot_figure(&spots, "Spot diagram: cooke-triplet");
//! assert_eq!(fig.size_pt(), (780, 450)); // two panels in a row
//! assert!(fig.to_svg()?.contains("x (µm)"));
//! // figures::save(&fig, std::path::Path::new("spots.png"))?; // PNG, or SVG for *.svg
//! # Ok(())
//! # }
//! ```

use crate::analysis::SpotResult;
use crate::error::{Error, ErrorKind, Result};
use crate::lens::{Lens, Paraxial, Shape, SurfaceRole, System};
use crate::math::Vec3;
use crate::trace::reference::trace_ray;
use crate::trace::{Field, Pupil, PupilPattern, RaySet};
use plotters::chart::SeriesAnno;
use plotters::coord::combinators::BindKeyPoints;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;
use std::path::Path;

pub use wave::{
    curves_figure, fan_figure, mtf_figure, opd_map_figure, through_focus_figure, zernike_figure,
    CurveSpec, FanRow, FocusRow,
};

/// An RGB colour, `[r, g, b]`.
pub type Rgb = [u8; 3];

/// Series colours (Okabe-Ito, reordered so the strongest on white come first; yellow darkened).
pub const PALETTE: [Rgb; 8] = [
    [0, 114, 178],   // blue
    [213, 94, 0],    // vermillion
    [0, 158, 115],   // bluish green
    [204, 121, 167], // reddish purple
    [230, 159, 0],   // orange
    [86, 180, 233],  // sky blue
    [0, 0, 0],       // black
    [190, 170, 0],   // dark yellow
];

/// Pixels per point of the PNG files: a figure of `w x h` points is written as a
/// `PNG_SCALE·w x PNG_SCALE·h` PNG.
pub const PNG_SCALE: u32 = 2;

/// The font every figure is drawn in: DejaVu Sans reduced to the characters figures use
/// (`assets/fonts/README.md` says how and under which licence).
const FONT_BYTES: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-subset.ttf");
/// The family name the font is registered under (also written into SVG files, so a viewer with
/// DejaVu Sans installed shows the same face).
const FAMILY: &str = "DejaVu Sans";
/// Largest side of a figure in points (PNG: times [`PNG_SCALE`]).
const MAX_SIDE_PT: u32 = 8192;

const GREY: Rgb = [120, 120, 120];
const LIGHT: RGBColor = RGBColor(232, 232, 232);
const FAINT: RGBColor = RGBColor(246, 246, 246);

/// A picture ready to be written: its size in points and the data it shows.
///
/// Made by [`spot_figure`], [`layout_figure`], [`tolerance_figure`], [`psf_figure`],
/// [`training_curves`], [`deep_training_curves`] and the wave-optics figures; written by
/// [`save`], or rendered in memory
/// by [`Figure::to_png`] and [`Figure::to_svg`].
#[derive(Clone, Debug)]
pub struct Figure {
    width: u32,
    height: u32,
    title: String,
    kind: Kind,
}

#[derive(Clone, Debug)]
enum Kind {
    Spot {
        cols: usize,
        half_um: f64,
        panels: Vec<SpotPanel>,
        /// "µm", or "µrad" for an afocal image space spot.
        unit: &'static str,
    },
    Layout {
        x: Range<f64>,
        y: Range<f64>,
        rays: Vec<(Rgb, Vec<(f64, f64)>)>,
        fields: Vec<(String, Rgb)>,
        outlines: Vec<Vec<(f64, f64)>>,
        sensor: Vec<(f64, f64)>,
    },
    Tolerance {
        values: Vec<f64>,
        nominal: f64,
        yields: Vec<(f64, f64)>,
        /// The axis label (the criterion and its unit) and the unit after numbers.
        axis: (String, String),
    },
    Psf {
        tiles: Vec<Vec<f64>>,
        ks: usize,
        cols: usize,
        scale: u32,
    },
    Training {
        /// (iteration, loss, spot µm, PSF similarity), and the first stage-2 iteration.
        rows: Vec<(f64, f64, f64, Option<f64>)>,
        stage2: Option<f64>,
    },
    DeepTraining {
        /// Name, colour, (iteration, batch PSNR, validation PSNR, image loss) per series.
        series: Vec<DeepSeries>,
        split: usize,
    },
    OpdMap(wave::OpdMap),
    Bars(wave::Bars),
    Curves(wave::Curves),
    Panels(wave::Panels),
    Grid(grid::Grid),
}

/// A named, coloured set of points.
type Series = (String, Rgb, Vec<(f64, f64)>);
type DeepSeries = (String, Rgb, Vec<(f64, f64, Option<f64>, f64)>);

#[derive(Clone, Debug)]
struct SpotPanel {
    label: String,
    series: Vec<Series>,
}

/// Error type of drawing on backend `DB`.
type DrawResult<DB> =
    std::result::Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

impl Figure {
    /// The figure's size in points (the PNG is [`PNG_SCALE`] times as many pixels each way).
    #[must_use]
    pub fn size_pt(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The title drawn at the top.
    #[must_use]
    pub fn title(&self) -> &str {
        &self.title
    }

    /// Draws the figure into an RGB image of `PNG_SCALE·width x PNG_SCALE·height` pixels.
    ///
    /// # Errors
    /// [`ErrorKind::Numerical`] if the drawing backend fails (it does not for finite data).
    pub fn to_png(&self) -> Result<image::RgbImage> {
        register_font()?;
        // Drawn at twice the size and averaged down: the bitmap backend draws thick lines
        // without anti-aliasing or joins (a lens outline came out with one-pixel notches at
        // every segment); 2x2 supersampling smooths every line, text and edge.
        const SUPER: u32 = 2;
        let (w, h) = (self.width * PNG_SCALE, self.height * PNG_SCALE);
        let (ws, hs) = (w * SUPER, h * SUPER);
        let mut buf = vec![255u8; ws as usize * hs as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (ws, hs)).into_drawing_area();
            self.draw(&root, f64::from(PNG_SCALE * SUPER))
                .map_err(draw_error)?;
            root.present().map_err(draw_error)?;
        }
        let big = image::RgbImage::from_raw(ws, hs, buf).ok_or_else(|| {
            Error::new(ErrorKind::Numerical, "figure: image buffer size mismatch")
        })?;
        // The mean of each 2x2 block (a box filter: exact, no ringing).
        let mut out = image::RgbImage::new(w, h);
        for (x, y, p) in out.enumerate_pixels_mut() {
            for c in 0..3 {
                let sum: u32 = (0..SUPER)
                    .flat_map(|dy| (0..SUPER).map(move |dx| (dx, dy)))
                    .map(|(dx, dy)| u32::from(big.get_pixel(x * SUPER + dx, y * SUPER + dy)[c]))
                    .sum();
                p[c] = ((sum + SUPER * SUPER / 2) / (SUPER * SUPER)) as u8;
            }
        }
        Ok(out)
    }

    /// Draws the figure as an SVG document (`width x height` user units; text as text).
    ///
    /// # Errors
    /// [`ErrorKind::Numerical`] if the drawing backend fails (it does not for finite data).
    pub fn to_svg(&self) -> Result<String> {
        register_font()?;
        let mut s = String::new();
        {
            let root =
                SVGBackend::with_string(&mut s, (self.width, self.height)).into_drawing_area();
            self.draw(&root, 1.0).map_err(draw_error)?;
            root.present().map_err(draw_error)?;
        }
        Ok(s)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, s: f64) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let body = caption(root, &self.title, 17.0, 34.0, s)?;
        match &self.kind {
            Kind::Spot {
                cols,
                half_um,
                panels,
                unit,
            } => draw_spots(&body, s, *cols, *half_um, panels, unit),
            Kind::Layout {
                x,
                y,
                rays,
                fields,
                outlines,
                sensor,
            } => draw_layout(&body, s, x, y, rays, fields, outlines, sensor),
            Kind::Tolerance {
                values,
                nominal,
                yields,
                axis,
            } => draw_tolerance(&body, s, values, *nominal, yields, axis),
            Kind::Psf {
                tiles,
                ks,
                cols,
                scale,
            } => draw_psf(&body, s, tiles, *ks, *cols, *scale),
            Kind::Training { rows, stage2 } => draw_training(&body, s, rows, *stage2),
            Kind::DeepTraining { series, split } => draw_deep_training(&body, s, series, *split),
            Kind::OpdMap(m) => wave::draw_opd_map(&body, s, m),
            Kind::Bars(b) => wave::draw_bars(&body, s, b),
            Kind::Curves(c) => wave::draw_curves(&body, s, c),
            Kind::Panels(p) => wave::draw_panels(&body, s, p),
            Kind::Grid(g) => grid::draw_grid(&body, s, g),
        }
    }
}

/// Draws `text` centred in a band of `band_pt` points at the top of `area`; returns the rest.
fn caption<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    text: &str,
    size_pt: f64,
    band_pt: f64,
    s: f64,
) -> std::result::Result<DrawingArea<DB, Shift>, DrawingAreaErrorKind<DB::ErrorType>> {
    let band = px(band_pt, s);
    let (head, rest) = area.split_vertically(band);
    let w = head.dim_in_pixel().0;
    head.draw(&Text::new(
        text.to_string(),
        ((w / 2) as i32, (band / 2) as i32),
        font(size_pt, s).pos(Pos::new(HPos::Center, VPos::Center)),
    ))?;
    Ok(rest)
}

fn draw_error(e: impl std::fmt::Display) -> Error {
    Error::new(ErrorKind::Numerical, format!("drawing a figure: {e}"))
}

/// Registers the embedded font with plotters, once per process.
fn register_font() -> Result<()> {
    static DONE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(Error::new(
            ErrorKind::Numerical,
            "figures: the embedded font could not be read",
        ))
    }
}

/// Writes `figure` atomically: SVG if `path` ends in `.svg` (any case), PNG otherwise.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path, or a drawing error.
pub fn save(figure: &Figure, path: &Path) -> Result<()> {
    let svg = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    if svg {
        let text = figure.to_svg()?;
        crate::files::write_via_temp(path, |tmp| std::fs::write(tmp, text.as_bytes()))
    } else {
        let img = figure.to_png()?;
        crate::files::write_via_temp(path, |tmp| {
            img.save_with_format(tmp, image::ImageFormat::Png)
                .map_err(|e| std::io::Error::other(e.to_string()))
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Styles shared by every figure. `s` is pixels per point.

fn font(size_pt: f64, s: f64) -> TextStyle<'static> {
    (FAMILY, size_pt * s).into_font().color(&BLACK)
}

fn rgb(c: Rgb) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// `c` mixed with white: `t = 0` is `c`, `t = 1` white.
fn tint(c: Rgb, t: f64) -> RGBColor {
    let m = |v: u8| (f64::from(v) + (255.0 - f64::from(v)) * t).round() as u8;
    RGBColor(m(c[0]), m(c[1]), m(c[2]))
}

fn px(v_pt: f64, s: f64) -> u32 {
    (v_pt * s).round().max(1.0) as u32
}

/// A vertical colour bar in `area`: `map` over [0, 1] from bottom to top in 128 steps from
/// (`x0`, `y0`) (points, top left) over `height` points, 14 points wide and outlined; each of
/// `ticks` (a position in [0, 1] and its label) written beside it, and `label` turned along it
/// `label_dx` points right of `x0`.
#[allow(clippy::too_many_arguments)]
fn colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    s: f64,
    (x0, y0, height): (f64, f64, f64),
    map: fn(f64) -> RGBColor,
    ticks: &[(f64, String)],
    label: &str,
    label_dx: f64,
) -> DrawResult<DB> {
    let p = |v: f64| (v * s).round() as i32;
    let steps = 128;
    for k in 0..steps {
        let t0 = k as f64 / steps as f64;
        let ya = y0 + height * (1.0 - t0 - 1.0 / steps as f64);
        area.draw(&Rectangle::new(
            [
                (p(x0), p(ya)),
                (p(x0 + 14.0), p(ya + height / steps as f64) + 1),
            ],
            map(t0 + 0.5 / steps as f64).filled(),
        ))?;
    }
    area.draw(&Rectangle::new(
        [(p(x0), p(y0)), (p(x0 + 14.0), p(y0 + height))],
        BLACK.stroke_width(px(0.6, s)),
    ))?;
    for (t, text) in ticks {
        let y = y0 + height * (1.0 - t);
        area.draw(&Text::new(
            text.as_str(),
            (p(x0 + 18.0), p(y)),
            font(10.5, s).pos(Pos::new(HPos::Left, VPos::Center)),
        ))?;
    }
    area.draw(&Text::new(
        label,
        (p(x0 + label_dx), p(y0 + 0.5 * height)),
        font(11.0, s)
            .transform(FontTransform::Rotate90)
            .pos(Pos::new(HPos::Center, VPos::Center)),
    ))
}

/// Tick label: up to 6 significant decimals, no trailing zeros, a true minus sign, exponent
/// form for very large or small magnitudes.
fn tick(v: f64) -> String {
    let a = v.abs();
    // Below 1e-12 is the rounding of a tick computed as a sum (−0.15 + 3 × 0.05), not a value.
    let text = if a < 1e-12 || !v.is_finite() {
        "0".to_string()
    } else if !(1e-4..1e6).contains(&a) {
        format!("{v:.0e}")
    } else {
        let digits = (5 - a.log10().floor() as i32).clamp(0, 9) as usize;
        let t = format!("{v:.digits$}");
        if t.contains('.') {
            t.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            t
        }
    };
    text.replace('-', "\u{2212}")
}

/// A finite, non-empty range covering the finite values of `v` with `pad` of its span on each
/// side (`fallback` if there are none).
fn span(v: impl IntoIterator<Item = f64>, pad: f64, fallback: Range<f64>) -> Range<f64> {
    let (lo, hi) = v
        .into_iter()
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
    if !lo.is_finite() {
        return fallback;
    }
    if hi > lo {
        let w = hi - lo;
        (lo - pad * w)..(hi + pad * w)
    } else {
        // One value: a window of its magnitude around it.
        let w = 0.5 * lo.abs().max(1e-9);
        (lo - w)..(hi + w)
    }
}

/// A positive range for a log axis over the positive finite values of `v`.
fn log_span(v: impl IntoIterator<Item = f64>) -> Range<f64> {
    let (lo, hi) = v
        .into_iter()
        .filter(|x| x.is_finite() && *x > 0.0)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
    if !lo.is_finite() {
        return 0.1..10.0;
    }
    let (lo, hi) = if hi > lo * 1.01 {
        (lo, hi)
    } else {
        (lo / 2.0, hi * 2.0)
    };
    let pad = (hi / lo).powf(0.04);
    (lo / pad)..(hi * pad)
}

/// Tick positions for a log axis over `r`: 1-2-3-5 in each decade, thinned to decades when there
/// are too many, filled with 1..9 when there are too few.
fn log_keys(r: &Range<f64>) -> Vec<f64> {
    let (a, b) = (r.start.log10().floor() as i32, r.end.log10().ceil() as i32);
    let pick = |ms: &[f64]| -> Vec<f64> {
        (a..=b)
            // m / 10^-k for negative k, so 3 · 0.1 is 0.3 exactly.
            .flat_map(|k| {
                ms.iter().map(move |m| {
                    if k < 0 {
                        m / 10f64.powi(-k)
                    } else {
                        m * 10f64.powi(k)
                    }
                })
            })
            .filter(|v| r.contains(v))
            .collect()
    };
    let keys = pick(&[1.0, 2.0, 3.0, 5.0]);
    let keys = if keys.len() > 10 {
        pick(&[1.0])
    } else if keys.len() < 3 {
        pick(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    } else {
        keys
    };
    if keys.len() >= 2 {
        return keys;
    }
    // Less than a digit step wide: four values, two significant digits.
    (0..4)
        .map(|i| {
            let v = r.start + (r.end - r.start) * (f64::from(i) + 0.5) / 4.0;
            let e = 10f64.powi(v.log10().floor() as i32 - 1);
            (v / e).round() * e
        })
        .filter(|v| r.contains(v))
        .collect()
}

fn finite(p: &(f64, f64)) -> bool {
    p.0.is_finite() && p.1.is_finite()
}

/// Splits a polyline at its non-finite points into finite runs.
fn runs(pts: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
    pts.split(|p| !finite(p))
        .filter(|r| !r.is_empty())
        .map(<[_]>::to_vec)
        .collect()
}

/// The grid and labels of a linear chart in the house style.
macro_rules! house_mesh {
    ($chart:expr, $s:expr, $xdesc:expr, $ydesc:expr) => {
        $chart
            .configure_mesh()
            .x_desc($xdesc)
            .y_desc($ydesc)
            .label_style(font(11.0, $s))
            .axis_desc_style(font(12.0, $s))
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| tick(*v))
            .bold_line_style(LIGHT.stroke_width(px(0.6, $s)))
            .light_line_style(FAINT.stroke_width(px(0.5, $s)))
            .axis_style(BLACK.stroke_width(px(0.8, $s)))
            .x_labels(8)
            .y_labels(7)
    };
}

/// What a chart keeps on its right.
#[derive(Clone, Copy)]
enum Right {
    /// A secondary axis with its labels.
    Axis,
    /// As much room as an axis, empty (so stacked panels line up with one that has an axis).
    Room,
    /// The margin only.
    Margin,
}

/// A chart builder on `area` in the house layout (margins and label areas in points).
fn frame<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    s: f64,
    right: Right,
) -> ChartBuilder<'a, 'b, DB> {
    let mut b = ChartBuilder::on(area);
    b.margin(px(10.0, s))
        .x_label_area_size(px(40.0, s))
        .y_label_area_size(px(64.0, s));
    match right {
        Right::Axis => {
            b.right_y_label_area_size(px(58.0, s));
        }
        Right::Room => {
            b.margin_right(px(68.0, s));
        }
        Right::Margin => {}
    }
    b
}

/// The labels of a dual-axis chart's secondary (right) axis in the house style, with `desc`.
macro_rules! house_secondary {
    ($chart:expr, $s:expr, $desc:expr) => {
        $chart
            .configure_secondary_axes()
            .y_desc($desc)
            .label_style(font(11.0, $s))
            .axis_desc_style(font(12.0, $s))
            .y_label_formatter(&|v| tick(*v))
            .axis_style(BLACK.stroke_width(px(0.8, $s)))
            .draw()
    };
}

fn legend_box<'a, DB: DrawingBackend + 'a, C>(
    chart: &mut ChartContext<'a, DB, C>,
    s: f64,
    at: SeriesLabelPosition,
) -> DrawResult<DB>
where
    C: CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(at)
        .label_font(font(11.0, s))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK.mix(0.35).stroke_width(px(0.6, s)))
        .margin(px(6.0, s))
        .legend_area_size(px(22.0, s) as i32)
        .draw()
}

/// A line-sample legend glyph of colour `c`.
fn line_glyph(c: RGBColor, s: f64) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| {
        PathElement::new(
            vec![(x, y), (x + px(18.0, s) as i32, y)],
            c.stroke_width(px(2.0, s)),
        )
    }
}

/// `pts` as one solid line of `colour`, `width_pt` points wide: a series for `draw_series`.
fn line(
    pts: Vec<(f64, f64)>,
    colour: RGBColor,
    width_pt: f64,
    s: f64,
) -> std::iter::Once<PathElement<(f64, f64)>> {
    std::iter::once(PathElement::new(pts, colour.stroke_width(px(width_pt, s))))
}

/// A dashed grey vertical line at `at` across `y`, `width_pt` points wide, with ` label` written
/// at its top (an empty label writes nothing): stage starts, yield levels. Returns the line's
/// series, for a legend entry.
fn mark<'a, 'b, DB: DrawingBackend + 'a, Y: Ranged<ValueType = f64>>(
    chart: &'b mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, Y>>,
    s: f64,
    at: f64,
    y: (f64, f64),
    label: &str,
    width_pt: f64,
) -> std::result::Result<
    &'b mut SeriesAnno<'a, DB>,
    DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>,
> {
    let grey = rgb(GREY);
    if !label.is_empty() {
        chart.draw_series(std::iter::once(Text::new(
            format!(" {label}"),
            (at, y.1),
            font(10.5, s)
                .pos(Pos::new(HPos::Left, VPos::Top))
                .color(&grey),
        )))?;
    }
    chart.draw_series(std::iter::once(DashedPathElement::new(
        vec![(at, y.0), (at, y.1)],
        px(5.0, s),
        px(3.0, s),
        grey.stroke_width(px(width_pt, s)),
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_read_as_a_person_writes_them() {
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(0.30000000000000004), "0.3");
        assert_eq!(tick(-200.0), "\u{2212}200");
        assert_eq!(tick(12.5), "12.5");
        assert_eq!(tick(2e-6), "2e\u{2212}6");
        assert_eq!(tick(3e7), "3e7");
    }

    #[test]
    fn ranges_ignore_non_finite_values_and_never_collapse() {
        assert_eq!(
            span([f64::NAN, 1.0, 3.0, f64::INFINITY], 0.0, 0.0..1.0),
            1.0..3.0
        );
        assert_eq!(span([f64::NAN], 0.0, -1.0..1.0), -1.0..1.0);
        let r = span([5.0, 5.0], 0.0, 0.0..1.0);
        assert!(r.start < 5.0 && r.end > 5.0);
        assert_eq!(
            log_keys(&(0.015..0.6)),
            vec![0.02, 0.03, 0.05, 0.1, 0.2, 0.3, 0.5]
        );
        assert_eq!(log_keys(&(1e-9..1.5)).len(), 10);
        let k = log_keys(&(1.1..1.9));
        assert!(
            k.len() == 4 && k.iter().all(|v| (1.1..1.9).contains(v)),
            "{k:?}"
        );
        let l = log_span([0.0, -1.0, 1e-3, 1.0]);
        assert!(l.start > 0.0 && l.start < 1e-3 && l.end > 1.0);
        assert_eq!(
            runs(&[(0.0, 0.0), (1.0, f64::NAN), (2.0, 2.0), (3.0, 3.0)]).len(),
            2
        );
    }

    /// Pixels of `img` inside `(x0, y0, w, h)` that are not white.
    fn inked(img: &image::RgbImage, (x0, y0, w, h): (u32, u32, u32, u32)) -> usize {
        (y0..y0 + h)
            .flat_map(|y| (x0..x0 + w).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0 != [255, 255, 255])
            .count()
    }

    /// An ideal thin lens is drawn with arrowheads at both ends: out for f > 0, in for f < 0.
    #[test]
    fn thin_lenses_carry_arrowheads_that_tell_their_sign() {
        let bytes = include_bytes!("../../tests/data/zemax/thinlens.zmx");
        let catalogs = crate::lens::GlassCatalogs::builtin();
        let mut lens = crate::lens::zemax::from_bytes(bytes, &catalogs)
            .unwrap()
            .lens;
        let i = (lens.surfaces.iter())
            .position(|s| matches!(s.shape, Shape::Paraxial { .. }))
            .unwrap();
        let zi = lens.vertex_z_mm()[i];
        for sign in [1.0, -1.0] {
            lens.surfaces[i].shape = Shape::Paraxial {
                focal_mm: 80.0 * sign,
            };
            let para = lens.paraxial(587.5618).unwrap();
            let fig = layout_figure(
                &lens,
                &lens.compile(),
                &para,
                &[Field::angle(0.0)],
                587.6,
                3,
            );
            let Kind::Layout { outlines, .. } = fig.unwrap().kind else {
                panic!("not a layout")
            };
            // Three-point outlines centred on the thin lens' plane: its two arrowheads.
            let heads: Vec<&Vec<(f64, f64)>> = outlines
                .iter()
                .filter(|o| o.len() == 3 && (o[1].0 - zi).abs() < 1e-12 && o[0].0 < zi)
                .collect();
            assert_eq!(heads.len(), 2, "f = {}", 80.0 * sign);
            for h in heads {
                // The tip is at the end of the lens line; the barbs lie toward the axis for a
                // converging lens and away from it for a diverging one.
                let inward = h[0].1.abs() < h[1].1.abs();
                assert_eq!(inward, sign > 0.0, "f = {}: {h:?}", 80.0 * sign);
                assert_eq!(h[0].1, h[2].1);
            }
        }
    }

    #[test]
    fn every_figure_draws_its_data_text_and_units_in_png_and_svg() {
        let lens = Lens::load("cooke-triplet").unwrap();
        let para = lens.paraxial(lens.primary_wavelength_nm).unwrap();
        let fields = [Field::fraction(0.0), Field::fraction(1.0)];
        let opts = crate::analysis::SpotOptions {
            fields: fields.to_vec(),
            wavelengths_nm: vec![486.1327, 587.5618],
            pupil: Pupil::grid(8),
            trace: crate::trace::TraceOptions { apertures: true },
        };
        let spots = crate::analysis::spot_diagram(&lens, &lens.compile(), &opts).unwrap();
        let layout = layout_figure(&lens, &lens.compile(), &para, &fields, 587.5618, 5).unwrap();
        let rows: Vec<(f64, f64, f64, Option<f64>)> = (0..20)
            .map(|i| {
                let sim = (i >= 12).then_some(0.7 + 0.01 * f64::from(i));
                (
                    f64::from(i),
                    1.0 / (1.0 + f64::from(i)),
                    20.0 - f64::from(i) * 0.5,
                    sim,
                )
            })
            .collect();
        let psf: Vec<f64> = (0..81).map(|i| if i == 40 { 1.0 } else { 0.0 }).collect();
        let cases = [
            (
                spot_figure(&spots, "spots"),
                vec!["x (µm)", "486.1 nm", "587.6 nm", "RMS"],
            ),
            (layout, vec!["z (mm)", "field 1.000", "image plane", "EFL"]),
            (
                training_curves(rows, Some(12.0), "train"),
                vec!["PSF similarity", "stage 2", "spot (µm)"],
            ),
            (
                psf_figure(&[psf.clone(), psf], 9, 2, "psf"),
                vec!["intensity / tile peak"],
            ),
        ];
        for (fig, words) in &cases {
            let svg = fig.to_svg().unwrap();
            for w in words {
                assert!(svg.contains(w), "{}: no \"{w}\" in the SVG", fig.title());
            }
            assert!(svg.contains("DejaVu Sans"));
            let png = fig.to_png().unwrap();
            let (w, h) = fig.size_pt();
            assert_eq!(png.dimensions(), (w * PNG_SCALE, h * PNG_SCALE));
            // The title band is inked in its middle and the plot body holds data.
            let c = png.width() / 2;
            assert!(
                inked(&png, (c - 60, 0, 120, 30 * PNG_SCALE)) > 20,
                "{}",
                fig.title()
            );
            let body = (
                0,
                40 * PNG_SCALE,
                png.width(),
                png.height() - 40 * PNG_SCALE,
            );
            assert!(inked(&png, body) > 2000, "{}", fig.title());
        }
    }

    #[test]
    fn non_finite_data_is_skipped_not_drawn_or_fatal() {
        let rows: Vec<(f64, f64, f64, Option<f64>)> = [f64::NAN, 0.0, f64::INFINITY, 0.5]
            .iter()
            .enumerate()
            .map(|(i, &v)| (i as f64, v, v, None))
            .collect();
        let fig = training_curves(rows, None, "bad values");
        assert!(fig.to_png().is_ok() && fig.to_svg().is_ok());
        let empty = training_curves(Vec::new(), None, "no iterations");
        assert!(empty.to_png().is_ok());
        let psf = psf_figure(&[vec![f64::NAN; 4]], 2, 1, "nan psf");
        assert!(psf.to_png().is_ok());
    }

    #[test]
    fn save_writes_svg_or_png_by_extension_and_names_a_bad_path() {
        let dir = std::env::temp_dir().join(format!("tolray-figures-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let psf: Vec<f64> = vec![0.0, 1.0, 1.0, 0.0];
        let fig = psf_figure(&[psf], 2, 1, "tiny");
        save(&fig, &dir.join("a.SVG")).unwrap();
        save(&fig, &dir.join("a.png")).unwrap();
        let svg = std::fs::read_to_string(dir.join("a.SVG")).unwrap();
        assert!(svg.starts_with("<svg"));
        let png = image::open(dir.join("a.png")).unwrap();
        assert_eq!(png.width(), fig.size_pt().0 * PNG_SCALE);
        let bad = dir.join("missing-dir/a.png");
        let e = save(&fig, &bad).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Io);
        assert!(e.message().contains("missing-dir"), "{}", e.message());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn wavelengths_take_the_colour_of_their_band() {
        let (b, g, r) = (PALETTE[0], PALETTE[2], PALETTE[1]);
        assert_eq!(wavelength_colours(&[656.3, 587.6, 486.1]), vec![r, g, b]);
        assert_eq!(wavelength_colours(&[587.6]), vec![g]);
        assert_eq!(
            wavelength_colours(&[540.0, 550.0]),
            vec![PALETTE[0], PALETTE[1]]
        );
    }

    #[test]
    fn the_colour_map_is_inferno() {
        // matplotlib's inferno: first entry #000004, last #fcffa4.
        assert_eq!(inferno(0.0), RGBColor(0, 0, 4));
        assert_eq!(inferno(1.0), RGBColor(252, 255, 164));
        assert_eq!(inferno(f64::NAN), RGBColor(0, 0, 4));
    }
}

// One file per kind of figure (after the house macros, which they use).
mod grid;
mod layout;
mod psf;
mod spot;
mod tolerance;
mod training;
mod wave;

pub use grid::grid_distortion_figure;
pub use layout::layout_figure;
use layout::*;
use psf::*;
pub use psf::{mosaic, psf_figure, save_exr, save_exr_rgb};
pub use spot::spot_figure;
use spot::*;
pub use tolerance::tolerance_figure;
use tolerance::*;
use training::*;
pub use training::{deep_training_curves, training_curves, DeepCurve};
