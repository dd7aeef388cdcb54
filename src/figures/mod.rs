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
        sensor: [(f64, f64); 2],
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
}

/// A named, coloured set of points.
type Series = (String, Rgb, Vec<(f64, f64)>);

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
            } => draw_layout(&body, s, x, y, rays, fields, outlines, *sensor),
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

// ---------------------------------------------------------------------------------------------
// Spot diagram.

/// A spot diagram: one panel per field, every wavelength overlaid in its own colour, in
/// micrometres about the field's polychromatic (or only) centroid, the same scale in every panel,
/// the field's RMS radius in its caption and the wavelengths in a legend.
#[must_use]
pub fn spot_figure(results: &[SpotResult], title: &str) -> Figure {
    // Afocal image space spots are angles: mrad positions, µrad sizes.
    let unit = if results.iter().any(|r| r.angular) {
        "µrad"
    } else {
        "µm"
    };
    let mut fields: Vec<Field> = Vec::new();
    for r in results {
        if !fields.contains(&r.field) {
            fields.push(r.field);
        }
    }
    let per_field = |f: Field| results.iter().filter(move |r| r.field == f);
    let mut half = 1e-3f64;
    let mut panels = Vec::new();
    for &f in &fields {
        let all: Vec<&SpotResult> = per_field(f).collect();
        let poly = all
            .iter()
            .find(|r| r.wavelength_nm.is_none())
            .or(all.first());
        let c = poly.map_or([0.0, 0.0], |r| r.stats.centroid_mm);
        let rms = poly.map_or(f64::NAN, |r| r.stats.rms_um);
        let mono: Vec<&&SpotResult> = all.iter().filter(|r| r.wavelength_nm.is_some()).collect();
        let colours = wavelength_colours(
            &mono
                .iter()
                .map(|r| r.wavelength_nm.unwrap_or(0.0))
                .collect::<Vec<_>>(),
        );
        let mut series = Vec::new();
        for (r, &colour) in mono.iter().zip(&colours) {
            let pts: Vec<(f64, f64)> = r
                .points
                .iter()
                .map(|p| ((p[0] - c[0]) * 1e3, (p[1] - c[1]) * 1e3))
                .filter(finite)
                .collect();
            for p in &pts {
                half = half.max(p.0.abs()).max(p.1.abs());
            }
            series.push((
                format!("{:.1} nm", r.wavelength_nm.unwrap_or(0.0)),
                colour,
                pts,
            ));
        }
        panels.push(SpotPanel {
            label: format!("field {} · RMS {:.2} {unit}", f.label(), rms),
            series,
        });
    }
    let cols = fields.len().clamp(1, 4);
    let rows = fields.len().div_ceil(cols).max(1);
    Figure {
        width: (cols as u32 * 380 + 20).min(MAX_SIDE_PT),
        height: (rows as u32 * 390 + 60).min(MAX_SIDE_PT),
        title: title.to_string(),
        kind: Kind::Spot {
            cols,
            half_um: half * 1.08,
            panels,
            unit,
        },
    }
}

/// Series colours for wavelengths: blue below 500 nm, green to 600 nm, vermillion above, when
/// each band holds at most one of them; otherwise the palette in order.
fn wavelength_colours(nm: &[f64]) -> Vec<Rgb> {
    let band = |w: f64| {
        if w < 500.0 {
            0
        } else if w <= 600.0 {
            2
        } else {
            1
        }
    };
    let bands: Vec<usize> = nm.iter().map(|&w| band(w)).collect();
    let distinct = bands
        .iter()
        .enumerate()
        .all(|(i, b)| !bands[..i].contains(b));
    if distinct {
        bands.iter().map(|&b| PALETTE[b]).collect()
    } else {
        (0..nm.len()).map(|i| PALETTE[i % PALETTE.len()]).collect()
    }
}

/// Widens `x` or `y` so that one data unit spans as many pixels on both axes of a chart built on
/// `area` with the given label areas.
fn equal_aspect<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    margin: u32,
    labels: (u32, u32),
    x: Range<f64>,
    y: Range<f64>,
) -> (Range<f64>, Range<f64>) {
    let (w, h) = area.dim_in_pixel();
    let pw = f64::from(w.saturating_sub(2 * margin + labels.1).max(1));
    let ph = f64::from(h.saturating_sub(2 * margin + labels.0).max(1));
    let (sx, sy) = ((x.end - x.start) / pw, (y.end - y.start) / ph);
    if sx > sy {
        let c = 0.5 * (y.start + y.end);
        let half = 0.5 * sx * ph;
        (x, (c - half)..(c + half))
    } else {
        let c = 0.5 * (x.start + x.end);
        let half = 0.5 * sy * pw;
        ((c - half)..(c + half), y)
    }
}

fn draw_spots<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    cols: usize,
    half: f64,
    panels: &[SpotPanel],
    unit: &str,
) -> DrawResult<DB> {
    let rows = panels.len().div_ceil(cols).max(1);
    let cells = body
        .margin(0, px(10.0, s), px(10.0, s), px(10.0, s))
        .split_evenly((rows, cols));
    for (panel, cell) in panels.iter().zip(&cells) {
        let area = caption(cell, &panel.label, 13.0, 22.0, s)?;
        let (m, labels) = (px(8.0, s), (px(42.0, s), px(58.0, s)));
        let (xr, yr) = equal_aspect(&area, m, labels, -half..half, -half..half);
        let mut chart = ChartBuilder::on(&area)
            .margin(m)
            .x_label_area_size(labels.0)
            .y_label_area_size(labels.1)
            .build_cartesian_2d(xr, yr)?;
        house_mesh!(chart, s, format!("x ({unit})"), format!("y ({unit})")).draw()?;
        let r = (1.1 * s).max(1.0);
        for (name, c, pts) in &panel.series {
            let colour = rgb(*c);
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, r, colour.filled())))?
                .label(name.as_str())
                .legend(move |(x, y)| {
                    Circle::new((x + px(9.0, s) as i32, y), 3.5 * s, colour.filled())
                });
        }
        legend_box(&mut chart, s, SeriesLabelPosition::UpperRight)?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Layout.

/// Meridional layout: surface profiles, element edges, stop, image plane, and a fan of
/// `rays_per_field` meridional rays for each field (aimed at the paraxial entrance pupil), one
/// colour per field with a legend; equal scale on both axes.
///
/// # Errors
/// Paraxial or ray-generation errors.
pub fn layout_figure(
    lens: &Lens,
    sys: &System<f64>,
    para: &Paraxial,
    fields: &[Field],
    wavelength_nm: f64,
    rays_per_field: usize,
) -> Result<Figure> {
    // Where each vertex lies (after decentres, tilts and fold mirrors).
    let z: Vec<f64> = sys.rows.iter().map(|r| r.pos.z).collect();
    let mut ray_height = vec![0.0f64; lens.surfaces.len()];
    // The axial extent of every vertex and the image (a mirror system folds back: a
    // Cassegrain's secondary lies before its primary, at negative z).
    // The image plane's meridional section (decentred or tilted with the lens' image plane).
    let h = lens.sensor.half_diagonal_mm();
    let end = |y: f64| {
        let p = sys.image.point_to_global(Vec3::new(0.0, y, 0.0));
        (p.z, p.y)
    };
    let ends = [end(-h), end(h)];
    let z_lo = z
        .iter()
        .copied()
        .chain(ends.map(|e| e.0))
        .fold(0.0f64, f64::min);
    let z_hi = z
        .iter()
        .copied()
        .chain(ends.map(|e| e.0))
        .fold(0.0f64, f64::max);
    let span = (z_hi - z_lo).max(1e-3);
    let zmin = z_lo - 0.08 * span;
    let zmax = z_hi + 0.04 * span;
    let n = sys.indices(wavelength_nm);
    let mut rays = Vec::new();
    let mut legend = Vec::new();
    for (k, &f) in fields.iter().enumerate() {
        let set = RaySet::generate(
            lens,
            para,
            f,
            &Pupil {
                pattern: PupilPattern::Grid(1),
                scale: 1.0,
                aim: false,
            },
            wavelength_nm,
        )?;
        let colour = PALETTE[k % PALETTE.len()];
        legend.push((format!("field {}", f.label()), colour));
        let r_ep = 0.5 * para.entrance_pupil_diameter_mm;
        let m = rays_per_field.max(1);
        for j in 0..m {
            let py = if m == 1 {
                0.0
            } else {
                (2.0 * j as f64 / (m - 1) as f64 - 1.0) * r_ep * 0.999
            };
            let (o0, d0) = set.chief;
            // Shift the chief ray's pupil point along y (same object point or direction).
            let (o, d) = match lens.object {
                crate::Object::Finite { distance_mm } => {
                    let target = o0
                        + d0 * ((para.entrance_pupil_z_mm - o0.z) / d0.z)
                        + Vec3::new(0.0, py, 0.0);
                    if distance_mm < 0.0 {
                        // A virtual object: the fan converges on it (the chief ray's point at
                        // its depth), starting from the chief ray's start plane.
                        let q = o0 + d0 * ((-distance_mm - o0.z) / d0.z);
                        let d = (q - target).normalized();
                        (target - d * ((target.z - o0.z) / d.z), d)
                    } else {
                        (o0, (target - o0).normalized())
                    }
                }
                crate::Object::Infinite => (o0 + Vec3::new(0.0, py, 0.0), d0),
            };
            // Rays from infinity enter at the left edge; from a finite object, at the object
            // point or the left edge, whichever is nearer.
            let z0 = match lens.object {
                crate::Object::Infinite => zmin,
                crate::Object::Finite { .. } => o.z.max(zmin),
            };
            let mut pts = vec![(z0, o.y + d.y * ((z0 - o.z) / d.z))];
            for i in 0..=lens.surfaces.len() {
                let upto = (i < lens.surfaces.len()).then_some(i);
                let r = trace_ray(sys, &n, wavelength_nm, o, d, true, upto);
                if !r.status.is_alive() {
                    break;
                }
                if let Some(i) = upto {
                    // Measured in the surface's own frame (decentred or tilted surfaces).
                    let row = &sys.rows[i];
                    let local = row.rot.apply_t(r.o - row.pos);
                    ray_height[i] = ray_height[i].max(local.y.abs());
                }
                pts.push((r.o.z, r.o.y));
            }
            rays.push((colour, pts));
        }
    }
    // Surfaces are drawn to their semi-diameter, unless it is far larger than the rays use
    // (files that set it to the sphere's rim: the triplet's 435 mm on a 50 mm lens), where they
    // are drawn to 1.15 times the traced height so the lens stays readable.
    let drawn: Vec<f64> = lens
        .surfaces
        .iter()
        .zip(&ray_height)
        .map(|(s, &h)| {
            if h > 0.0 && s.semi_aperture_mm > 2.0 * h {
                1.15 * h
            } else {
                s.semi_aperture_mm
            }
        })
        .collect();
    // A point (0, y, z) of surface i's own frame, drawn where the (decentred, tilted) surface
    // puts it: (global z, global y).
    let place = |i: usize, y: f64, zl: f64| {
        let row = &sys.rows[i];
        let p = row.rot.apply(Vec3::new(0.0, y, zl)) + row.pos;
        (p.z, p.y)
    };
    let profile = |i: usize| -> Vec<(f64, f64)> {
        let s = &lens.surfaces[i];
        let r = drawn[i];
        (0..=80)
            .filter_map(|j| {
                let y = -r + 2.0 * r * j as f64 / 80.0;
                s.sag(y).map(|sz| place(i, y, sz))
            })
            .collect()
    };
    // Every surface as drawn and the image plane's ends.
    let ymax = (0..lens.surfaces.len())
        .flat_map(|i| [place(i, drawn[i], 0.0).1, place(i, -drawn[i], 0.0).1])
        .chain(ends.map(|e| e.1))
        .map(f64::abs)
        .fold(h, f64::max);
    let mut outlines = Vec::new();
    for (i, s) in lens.surfaces.iter().enumerate() {
        if s.role == SurfaceRole::Aperture || s.is_stop {
            let r = drawn[i];
            let zs = s.sag(r).unwrap_or(0.0);
            let bar = 0.15 * ymax;
            outlines.push(vec![place(i, r, zs), place(i, r + bar, zs)]);
            outlines.push(vec![place(i, -r, zs), place(i, -r - bar, zs)]);
        }
        if s.role != SurfaceRole::Aperture {
            outlines.push(profile(i));
        }
        // An ideal thin lens is a line with arrowheads at its ends, pointing out for a
        // converging lens and in for a diverging one (the textbook and OpticStudio symbol).
        if let Shape::Paraxial { focal_mm } = s.shape {
            let (r, a) = (drawn[i], 0.05 * ymax);
            let tip = if focal_mm > 0.0 { -a } else { a };
            for sign in [1.0, -1.0] {
                let y = sign * r;
                let back = sign * (r + tip);
                outlines.push(vec![
                    place(i, back, -a),
                    place(i, y, 0.0),
                    place(i, back, a),
                ]);
            }
        }
        // Element edges: join this surface to the next through the glass.
        if !s.material.is_air() && i + 1 < lens.surfaces.len() {
            let (a, b) = (profile(i), profile(i + 1));
            for (pa, pb) in [(a.first(), b.first()), (a.last(), b.last())] {
                if let (Some(pa), Some(pb)) = (pa, pb) {
                    let edge = if pa.1.abs() > pb.1.abs() {
                        (pb.0, pa.1)
                    } else {
                        (pa.0, pb.1)
                    };
                    outlines.push(vec![*pa, edge, *pb]);
                }
            }
        }
    }
    Ok(Figure {
        width: 1100,
        height: 560,
        title: {
            // A lens without a name (an unnamed .zmx file) starts at its EFL.
            let name = short(&lens.info);
            let first = if name.trim().is_empty() {
                String::new()
            } else {
                format!("{name} · ")
            };
            match (para.efl_mm, para.fnum, para.angular_magnification) {
                (Some(f), Some(n), _) => format!("{first}EFL {f:.2} mm · F/{n:.2}"),
                (_, _, m) => format!(
                    "{first}afocal · angular magnification {:.3}×",
                    m.unwrap_or(0.0)
                ),
            }
        },
        kind: Kind::Layout {
            x: zmin..zmax,
            y: -ymax * 1.12..ymax * 1.12,
            rays,
            fields: legend,
            outlines,
            sensor: ends,
        },
    })
}

/// A lens name for a title: up to its first colon, and at most 72 characters (a longer name,
/// as a .zmx NAME line can be, is cut at a word with an ellipsis so the title fits the page).
fn short(s: &str) -> String {
    let s = s.split(':').next().unwrap_or(s).trim();
    if s.chars().count() <= 72 {
        return s.to_string();
    }
    let head: String = s.chars().take(72).collect();
    let cut = head.rfind(' ').filter(|&i| i > 40).unwrap_or(head.len());
    format!("{}…", head[..cut].trim_end_matches([',', ';', ' ']))
}

#[allow(clippy::too_many_arguments)]
fn draw_layout<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    x: &Range<f64>,
    y: &Range<f64>,
    rays: &[(Rgb, Vec<(f64, f64)>)],
    fields: &[(String, Rgb)],
    outlines: &[Vec<(f64, f64)>],
    sensor: [(f64, f64); 2],
) -> DrawResult<DB> {
    let (m, labels) = (px(10.0, s), (px(42.0, s), px(58.0, s)));
    let (xr, yr) = equal_aspect(body, m, labels, x.clone(), y.clone());
    let mut chart = ChartBuilder::on(body)
        .margin(m)
        .x_label_area_size(labels.0)
        .y_label_area_size(labels.1)
        .build_cartesian_2d(xr.clone(), yr)?;
    house_mesh!(chart, s, "z (mm)", "y (mm)").draw()?;
    chart.draw_series(line(
        vec![(xr.start, 0.0), (xr.end, 0.0)],
        RGBColor(170, 170, 170),
        0.6,
        s,
    ))?;
    for (c, pts) in rays {
        for run in runs(pts) {
            chart.draw_series(line(run, rgb(*c), 0.9, s))?;
        }
    }
    for (name, c) in fields {
        let colour = rgb(*c);
        chart
            .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())?
            .label(name.as_str())
            .legend(line_glyph(colour, s));
    }
    for o in outlines {
        for run in runs(o) {
            chart.draw_series(line(run, BLACK, 1.3, s))?;
        }
    }
    chart
        .draw_series(line(sensor.to_vec(), RGBColor(200, 0, 0), 2.0, s))?
        .label("image plane")
        .legend(line_glyph(RGBColor(200, 0, 0), s));
    legend_box(&mut chart, s, SeriesLabelPosition::UpperLeft)
}

// ---------------------------------------------------------------------------------------------
// Tolerance histogram.

/// Histogram of Monte Carlo RMS spots (mean over fields, left axis) with their cumulative
/// distribution (right axis, %), the nominal design and the 50 % / 90 % yield marked.
#[must_use]
pub fn tolerance_figure(report: &crate::tolerance::McReport) -> Figure {
    let crit = report.summary.as_ref().and_then(|sm| sm.criterion.as_ref());
    let (values, nominal_per_field, axis): (Vec<f64>, &[f64], (String, String)) =
        match (crit, &report.nominal_criterion) {
            (Some(c), Some(nom)) => (
                report
                    .trials
                    .iter()
                    .filter_map(|t| t.mean_criterion)
                    .filter(|v| v.is_finite())
                    .collect(),
                nom,
                (format!("field mean of {}", c.label), String::new()),
            ),
            _ => (
                report
                    .trials
                    .iter()
                    .map(|t| t.mean_rms_um)
                    .filter(|v| v.is_finite())
                    .collect(),
                &report.nominal_rms_um,
                ("mean RMS spot over fields (µm)".into(), " µm".into()),
            ),
        };
    let nominal = nominal_per_field.iter().sum::<f64>() / nominal_per_field.len().max(1) as f64;
    let yields = report.summary.as_ref().map_or_else(Vec::new, |sm| {
        let st = crit.map_or(&sm.mean_over_fields, |c| &c.mean_over_fields);
        let table = if st.yield_above.is_empty() {
            &st.yield_below
        } else {
            &st.yield_above
        };
        table
            .iter()
            .filter(|r| r[0] == 0.9 || r[0] == 0.5)
            .map(|r| (r[0], r[1]))
            .collect()
    });
    Figure {
        width: 900,
        height: 480,
        title: format!(
            "Monte Carlo tolerance analysis of {}: {} trials",
            report.lens,
            values.len()
        ),
        kind: Kind::Tolerance {
            values,
            nominal,
            yields,
            axis,
        },
    }
}

fn draw_tolerance<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    values: &[f64],
    nominal: f64,
    yields: &[(f64, f64)],
    axis: &(String, String),
) -> DrawResult<DB> {
    let all = values.iter().copied().chain(std::iter::once(nominal));
    let pad = if axis.1.is_empty() { 0.05 } else { 1.0 };
    let r = span(all, 0.0, nominal - pad..nominal + pad);
    let bins = (values.len() as f64).sqrt().clamp(5.0, 60.0) as usize;
    let w = (r.end - r.start) / bins as f64;
    let mut counts = vec![0usize; bins];
    for x in values {
        counts[(((x - r.start) / w) as usize).min(bins - 1)] += 1;
    }
    let top = *counts.iter().max().unwrap_or(&1) as f64;
    let xr = (r.start - w)..(r.end + w);
    let mut chart = frame(body, s, Right::Axis)
        .build_cartesian_2d(xr.clone(), 0.0..(top * 1.12).max(1.0))?
        .set_secondary_coord(xr, 0.0..112.0);
    house_mesh!(chart, s, axis.0.as_str(), "trials").draw()?;
    house_secondary!(chart, s, "cumulative share of trials (%)")?;
    let bar = tint(PALETTE[0], 0.55);
    // The bars, filled, then again with white outlines that part neighbours.
    let bars = |style: ShapeStyle| {
        counts
            .iter()
            .enumerate()
            .filter(|(_, &c)| c > 0)
            .map(move |(b, &c)| {
                let x0 = r.start + b as f64 * w;
                Rectangle::new([(x0, 0.0), (x0 + w, c as f64)], style)
            })
    };
    chart
        .draw_series(bars(bar.filled()))?
        .label("trials per bin")
        .legend(move |(x, y)| {
            Rectangle::new(
                [
                    (x, y - px(5.0, s) as i32),
                    (x + px(18.0, s) as i32, y + px(5.0, s) as i32),
                ],
                bar.filled(),
            )
        });
    chart.draw_series(bars(WHITE.stroke_width(px(0.8, s))))?;
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len().max(1) as f64;
    let mut cdf = Vec::with_capacity(2 * sorted.len());
    for (i, &x) in sorted.iter().enumerate() {
        cdf.push((x, i as f64 / n * 100.0));
        cdf.push((x, (i + 1) as f64 / n * 100.0));
    }
    let orange = rgb(PALETTE[1]);
    chart
        .draw_secondary_series(line(cdf, orange, 1.6, s))?
        .label("cumulative distribution (right axis)")
        .legend(line_glyph(orange, s));
    let green = rgb(PALETTE[2]);
    let ymax = top * 1.12;
    chart
        .draw_series(line(vec![(nominal, 0.0), (nominal, ymax)], green, 1.8, s))?
        .label(format!("nominal design ({}{})", tick(nominal), axis.1))
        .legend(line_glyph(green, s));
    for (k, &(frac, v)) in yields.iter().enumerate() {
        let label = format!("{:.0} %", frac * 100.0);
        let series = mark(&mut chart, s, v, (0.0, ymax), &label, 1.3)?;
        if k == 0 {
            series
                .label("50 % / 90 % yield")
                .legend(line_glyph(rgb(GREY), s));
        }
    }
    legend_box(&mut chart, s, SeriesLabelPosition::UpperLeft)
}

// ---------------------------------------------------------------------------------------------
// PSF mosaics.

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

fn inferno(t: f64) -> RGBColor {
    let c = colorous::INFERNO.eval_continuous(if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    });
    RGBColor(c.r, c.g, c.b)
}

fn draw_psf<DB: DrawingBackend>(
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
    let steps = 128;
    for k in 0..steps {
        let t0 = k as f64 / steps as f64;
        let ya = y0 + height * (1.0 - t0 - 1.0 / steps as f64);
        body.draw(&Rectangle::new(
            [
                (p(bx), p(ya)),
                (p(bx + 14.0), p(ya + height / steps as f64) + 1),
            ],
            inferno(t0 + 0.5 / steps as f64).filled(),
        ))?;
    }
    body.draw(&Rectangle::new(
        [(p(bx), p(y0)), (p(bx + 14.0), p(y0 + height))],
        BLACK.stroke_width(px(0.6, s)),
    ))?;
    for v in [0.0, 0.25, 0.5, 0.75, 1.0] {
        let y = y0 + height * (1.0 - v);
        body.draw(&Text::new(
            tick(v),
            (p(bx + 18.0), p(y)),
            font(10.5, s).pos(Pos::new(HPos::Left, VPos::Center)),
        ))?;
    }
    body.draw(&Text::new(
        "intensity / tile peak",
        (p(bx + 46.0), p(y0 + 0.5 * height)),
        font(11.0, s)
            .transform(FontTransform::Rotate90)
            .pos(Pos::new(HPos::Center, VPos::Center)),
    ))?;
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
fn write_exr(
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

// ---------------------------------------------------------------------------------------------
// Training curves.

/// Training curves of the optics: the loss per iteration on a log scale (top), and the spot
/// size with the PSF similarity on a second axis (bottom); `stage2`, the iteration where stage
/// 2 starts, is marked. Each row is (iteration, loss, spot µm, PSF similarity); the optimizer's
/// logs make them (`optim::train::training_figure`).
///
/// ```
/// let rows = (0..10).map(|i| (i as f64, 1.0 / (1.0 + i as f64), 20.0 - i as f64, None)).collect();
/// let fig = tolray::figures::training_curves(rows, None, "Training");
/// assert!(fig.to_svg()?.contains("training loss"));
/// # Ok::<(), tolray::Error>(())
/// ```
#[must_use]
pub fn training_curves(
    rows: Vec<(f64, f64, f64, Option<f64>)>,
    stage2: Option<f64>,
    title: &str,
) -> Figure {
    Figure {
        width: 900,
        height: 680,
        title: title.to_string(),
        kind: Kind::Training { rows, stage2 },
    }
}

fn draw_training<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    rows: &[(f64, f64, f64, Option<f64>)],
    stage2: Option<f64>,
) -> DrawResult<DB> {
    let (top, bottom) = body.split_vertically(body.dim_in_pixel().1 / 2);
    let xr = 0.0..rows.iter().map(|r| r.0 + 1.0).fold(2.0, f64::max);
    let lr = log_span(rows.iter().map(|r| r.1));
    let mut chart = frame(&top, s, Right::Room).build_cartesian_2d(
        xr.clone(),
        lr.clone().log_scale().with_key_points(log_keys(&lr)),
    )?;
    house_mesh!(chart, s, "iteration", "training loss (log scale)").draw()?;
    let blue = rgb(PALETTE[0]);
    let loss: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.0, r.1))
        .filter(|p| finite(p) && p.1 > 0.0)
        .collect();
    chart
        .draw_series(line(loss, blue, 1.4, s))?
        .label("loss")
        .legend(line_glyph(blue, s));
    if let Some(at) = stage2 {
        let label = "stage 2: tolerance-aware";
        mark(&mut chart, s, at, (lr.start, lr.end), label, 1.2)?;
    }
    legend_box(&mut chart, s, SeriesLabelPosition::UpperRight)?;

    let sr = span(rows.iter().map(|r| r.2), 0.06, 0.0..1.0);
    let sims: Vec<(f64, f64)> = rows
        .iter()
        .filter_map(|r| r.3.map(|v| (r.0, v)))
        .filter(finite)
        .collect();
    let simr = span(sims.iter().map(|p| p.1), 0.06, 0.0..1.0);
    let mut chart = frame(&bottom, s, Right::Axis)
        .build_cartesian_2d(xr.clone(), sr.clone())?
        .set_secondary_coord(xr, simr);
    house_mesh!(
        chart,
        s,
        "iteration",
        "spot (µm): RMS (stage 1), mean distance (stage 2)"
    )
    .draw()?;
    let orange = rgb(PALETTE[1]);
    let spot: Vec<(f64, f64)> = rows.iter().map(|r| (r.0, r.2)).filter(finite).collect();
    chart
        .draw_series(line(spot, orange, 1.4, s))?
        .label("spot (left axis)")
        .legend(line_glyph(orange, s));
    if !sims.is_empty() {
        house_secondary!(chart, s, "PSF similarity")?;
        let green = rgb(PALETTE[2]);
        chart
            .draw_secondary_series(line(sims, green, 1.4, s))?
            .label("PSF similarity (right axis)")
            .legend(line_glyph(green, s));
    }
    if let Some(at) = stage2 {
        mark(&mut chart, s, at, (sr.start, sr.end), "", 1.2)?;
    }
    legend_box(&mut chart, s, SeriesLabelPosition::UpperRight)
}

/// One curve of a deep-optics training figure.
#[derive(Clone, Debug)]
pub struct DeepCurve {
    /// The legend's name.
    pub name: String,
    /// Colour: an index into the house palette, or `None` for grey (the shared stage 1).
    pub colour: Option<usize>,
    /// (iteration, batch PSNR dB, validation PSNR dB when validated, batch image loss).
    pub rows: Vec<(f64, f64, Option<f64>, f64)>,
}

/// Training curves of a deep-optics study: the batch PSNR (light) and the validation PSNR
/// (dots) against the iteration (top), and the batch image loss on a log scale (bottom). A
/// dashed line marks `split`, where the branches start (0: none). The study's logs make the
/// curves (`deep::deep_training_figure`).
#[must_use]
pub fn deep_training_curves(curves: Vec<DeepCurve>, split: usize, title: &str) -> Figure {
    let series = curves
        .into_iter()
        .map(|c| {
            let colour = c.colour.map_or(GREY, |k| PALETTE[k % PALETTE.len()]);
            (c.name, colour, c.rows)
        })
        .collect();
    Figure {
        width: 900,
        height: 700,
        title: title.to_string(),
        kind: Kind::DeepTraining { series, split },
    }
}

type DeepSeries = (String, Rgb, Vec<(f64, f64, Option<f64>, f64)>);

fn draw_deep_training<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    series: &[DeepSeries],
    split: usize,
) -> DrawResult<DB> {
    let (top, bottom) = body.split_vertically((f64::from(body.dim_in_pixel().1) * 0.56) as u32);
    let all = || series.iter().flat_map(|x| x.2.iter());
    let xr = 0.0..all().map(|r| r.0 + 1.0).fold(2.0, f64::max);
    let yr = span(
        all().flat_map(|r| [Some(r.1), r.2]).flatten(),
        0.05,
        0.0..1.0,
    );
    let mut chart = frame(&top, s, Right::Margin).build_cartesian_2d(xr.clone(), yr.clone())?;
    house_mesh!(chart, s, "iteration", "PSNR (dB)").draw()?;
    if split > 0 {
        mark(
            &mut chart,
            s,
            split as f64,
            (yr.start, yr.end),
            "stage 2",
            1.2,
        )?;
    }
    for (_, c, rows) in series {
        let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.0, r.1)).filter(finite).collect();
        chart.draw_series(line(pts, tint(*c, 0.62), 1.0, s))?;
    }
    for (name, c, rows) in series {
        let colour = rgb(*c);
        let val: Vec<(f64, f64)> = rows
            .iter()
            .filter_map(|r| r.2.map(|v| (r.0, v)))
            .filter(finite)
            .collect();
        chart.draw_series(line(val.clone(), colour, 1.6, s))?;
        chart
            .draw_series(
                val.iter()
                    .map(|&p| Circle::new(p, 2.8 * s, colour.filled())),
            )?
            .label(name.as_str())
            .legend(move |(x, y)| {
                EmptyElement::at((x, y))
                    + PathElement::new(
                        vec![(0, 0), (px(18.0, s) as i32, 0)],
                        colour.stroke_width(px(1.6, s)),
                    )
                    + Circle::new((px(9.0, s) as i32, 0), 2.8 * s, colour.filled())
            });
    }
    chart
        .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())?
        .label("light: training batch; dots: held-out fabricated units")
        .legend(|(x, y)| EmptyElement::at((x, y)));
    legend_box(&mut chart, s, SeriesLabelPosition::LowerMiddle)?;

    let lr = log_span(all().map(|r| r.3));
    let mut chart = frame(&bottom, s, Right::Margin)
        .build_cartesian_2d(xr, lr.clone().log_scale().with_key_points(log_keys(&lr)))?;
    house_mesh!(chart, s, "iteration", "training batch image loss (log)").draw()?;
    if split > 0 {
        mark(&mut chart, s, split as f64, (lr.start, lr.end), "", 1.2)?;
    }
    for (_, c, rows) in series {
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .map(|r| (r.0, r.3))
            .filter(|p| finite(p) && p.1 > 0.0)
            .collect();
        chart.draw_series(line(pts, rgb(*c), 1.2, s))?;
    }
    Ok(())
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
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zemax/thinlens.zmx");
        let mut lens = Lens::load(path).unwrap();
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

// The wave-optics figures (after the house macros, which they use).
mod wave;
