//! Wave-optics pictures: the OPD map over the pupil, Zernike coefficients as bars, MTF curves
//! (against frequency, with the diffraction limit) and through-focus MTF.

use super::*;
use crate::wave::mtf::Mtf;
use crate::wave::Wavefront;

/// An OPD map: `n x n` values over the pupil square, NaN outside the rays that got through.
#[derive(Clone, Debug)]
pub(super) struct OpdMap {
    n: usize,
    values: Vec<f64>,
}

/// Grouped bars: term labels and one row of values per series.
#[derive(Clone, Debug)]
pub(super) struct Bars {
    rows: Vec<(String, Vec<f64>)>,
}

/// A curve: name, colour, dashed, points.
type Curve = (String, Rgb, bool, Vec<(f64, f64)>);

/// A through-focus row: label, tangential and sagittal points (focus shift mm, MTF).
pub type FocusRow = (String, Vec<(f64, f64)>, Vec<(f64, f64)>);

/// Line charts: x and y descriptions, a fixed y range, and series (name, colour, dashed, points).
#[derive(Clone, Debug)]
pub(super) struct Curves {
    x_desc: String,
    y_desc: String,
    y: Range<f64>,
    series: Vec<Curve>,
    /// Grey reference curves (the diffraction limit), not in the legend but the first.
    reference: Vec<Vec<(f64, f64)>>,
    reference_label: String,
}

/// The OPD map of `w` (traced with [`crate::wave::Sampling::Grid`]`(n)`) in waves, piston
/// removed, on a diverging colour map symmetric about zero, with a colour bar and the RMS and PV
/// in the title.
#[must_use]
pub fn opd_map_figure(w: &Wavefront, n: usize, title: &str) -> Figure {
    let mean: f64 = w.opd_waves.iter().zip(&w.weight).map(|(a, b)| a * b).sum();
    let mut values = vec![f64::NAN; n * n];
    let cell = |x: f64| (((x + 1.0) * 0.5 * n as f64).floor() as usize).min(n - 1);
    for (p, &v) in w.pupil.iter().zip(&w.opd_waves) {
        // Row 0 at the top (+y).
        values[(n - 1 - cell(p[1])) * n + cell(p[0])] = v - mean;
    }
    let rms = w
        .opd_waves
        .iter()
        .zip(&w.weight)
        .map(|(a, b)| b * (a - mean) * (a - mean))
        .sum::<f64>()
        .sqrt();
    let (lo, hi) = w
        .opd_waves
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    Figure {
        width: 600,
        height: 520,
        title: format!("{title}: RMS {rms:.4}, PV {:.4} waves", hi - lo),
        kind: Kind::OpdMap(OpdMap { n, values }),
    }
}

/// The smallest 1, 2, 2.5 or 5 times a power of ten at or above `v` (> 0).
fn nice_up(v: f64) -> f64 {
    let e = 10f64.powf(v.log10().floor());
    [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * e)
        .find(|x| *x >= v * (1.0 - 1e-12))
        .unwrap_or(10.0 * e)
}

fn diverging(t: f64) -> RGBColor {
    // colorous' RED_BLUE runs red (0) to blue (1); positive OPD drawn red.
    let c = colorous::RED_BLUE.eval_continuous(if t.is_finite() {
        (1.0 - t).clamp(0.0, 1.0)
    } else {
        0.5
    });
    RGBColor(c.r, c.g, c.b)
}

pub(super) fn draw_opd_map<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    m: &OpdMap,
) -> DrawResult<DB> {
    // A square plot (the pupil is round) and the colour bar beside it.
    let (w, h) = body.dim_in_pixel();
    let (plot, bar) = body.split_horizontally(h.min(w.saturating_sub(px(120.0, s))));
    let lim = nice_up(
        m.values
            .iter()
            .filter(|v| v.is_finite())
            .fold(0.0f64, |a, v| a.max(v.abs()))
            .max(1e-12),
    );
    let mut chart = frame(&plot, s, Right::Margin).build_cartesian_2d(-1.05..1.05, -1.05..1.05)?;
    house_mesh!(chart, s, "normalised pupil x", "normalised pupil y").draw()?;
    let n = m.n;
    let h = 2.0 / n as f64;
    chart.draw_series((0..n * n).filter(|k| m.values[*k].is_finite()).map(|k| {
        let (r, c) = (k / n, k % n);
        let x0 = -1.0 + c as f64 * h;
        let y1 = 1.0 - r as f64 * h;
        Rectangle::new(
            [(x0, y1), (x0 + h, y1 - h)],
            diverging(0.5 + 0.5 * m.values[k] / lim).filled(),
        )
    }))?;
    chart.draw_series(std::iter::once(PathElement::new(
        (0..=180)
            .map(|k| {
                let t = std::f64::consts::TAU * k as f64 / 180.0;
                (t.cos(), t.sin())
            })
            .collect::<Vec<_>>(),
        BLACK.stroke_width(px(0.8, s)),
    )))?;
    // Colour bar.
    let (_, bh) = bar.dim_in_pixel();
    let ticks: Vec<(f64, String)> = [-1.0, -0.5, 0.0, 0.5, 1.0]
        .iter()
        .map(|&v| (0.5 + 0.5 * v, tick(v * lim)))
        .collect();
    colour_bar(
        &bar,
        s,
        (12.0, 20.0, bh as f64 / s - 70.0),
        diverging,
        &ticks,
        "OPD, piston removed (waves)",
        80.0,
    )
}

/// Zernike Standard coefficients (waves) as grouped bars, one colour per row (field and
/// wavelength), piston left out.
#[must_use]
pub fn zernike_figure(rows: &[(String, Vec<f64>)], title: &str) -> Figure {
    let terms = rows.iter().map(|r| r.1.len()).max().unwrap_or(1);
    Figure {
        width: (300 + 18 * terms as u32).clamp(520, 1600),
        height: 420,
        title: title.to_string(),
        kind: Kind::Bars(Bars {
            rows: rows.to_vec(),
        }),
    }
}

pub(super) fn draw_bars<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    b: &Bars,
) -> DrawResult<DB> {
    let terms = b.rows.iter().map(|r| r.1.len()).max().unwrap_or(1);
    let vals = b.rows.iter().flat_map(|r| r.1.iter().skip(1).copied());
    let yr = span(vals.chain([0.0]), 0.08, -1.0..1.0);
    let mut chart =
        frame(body, s, Right::Margin).build_cartesian_2d(1.5..(terms as f64 + 0.5), yr)?;
    house_mesh!(
        chart,
        s,
        "Zernike Standard term j (Noll)",
        "coefficient (waves)"
    )
    .x_labels(terms.min(20))
    .x_label_formatter(&|v| format!("{}", v.round()))
    .draw()?;
    let k = b.rows.len().max(1) as f64;
    let w = 0.8 / k;
    for (i, (name, c)) in b.rows.iter().enumerate() {
        let col = rgb(PALETTE[i % PALETTE.len()]);
        chart
            .draw_series(c.iter().enumerate().skip(1).map(|(j, &v)| {
                let x = (j + 1) as f64 - 0.4 + i as f64 * w;
                Rectangle::new([(x, 0.0), (x + w, v)], col.filled())
            }))?
            .label(name.clone())
            .legend(move |(x, y)| {
                Rectangle::new(
                    [
                        (x, y - px(4.0, s) as i32),
                        (x + px(12.0, s) as i32, y + px(4.0, s) as i32),
                    ],
                    col.filled(),
                )
            });
    }
    legend_box(&mut chart, s, SeriesLabelPosition::UpperRight)
}

/// MTF against frequency from 0 to the cutoff for each (label, MTF): tangential solid,
/// sagittal dashed, one colour per label, the diffraction limits in grey.
#[must_use]
pub fn mtf_figure(curves: &[(String, Mtf)], title: &str) -> Figure {
    let mut series = Vec::new();
    let mut reference = Vec::new();
    for (i, (name, m)) in curves.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let pts = |v: &[f64]| m.freq_lpmm.iter().copied().zip(v.iter().copied()).collect();
        series.push((format!("{name} T"), c, false, pts(&m.tangential)));
        series.push((format!("{name} S"), c, true, pts(&m.sagittal)));
        reference.push(pts(&m.diffraction_limit));
    }
    Figure {
        width: 720,
        height: 460,
        title: title.to_string(),
        kind: Kind::Curves(Curves {
            x_desc: "spatial frequency (cycles/mm)".into(),
            y_desc: "modulus of the OTF".into(),
            y: 0.0..1.02,
            series,
            reference,
            reference_label: "diffraction limit".into(),
        }),
    }
}

/// A curve of [`curves_figure`]: label, palette colour index, dashed, points.
pub type CurveSpec = (String, usize, bool, Vec<(f64, f64)>);

/// A line chart of `series` (label, palette colour index, dashed, points): the aberration
/// curves' picture. `y` fixes the vertical range; `None` takes the data's with a margin.
#[must_use]
pub fn curves_figure(
    title: &str,
    x_desc: &str,
    y_desc: &str,
    y: Option<Range<f64>>,
    series: &[CurveSpec],
) -> Figure {
    let y = y.unwrap_or_else(|| {
        let ys = series.iter().flat_map(|s| s.3.iter().map(|p| p.1));
        span(ys, 0.08, -1.0..1.0)
    });
    Figure {
        width: 720,
        height: 460,
        title: title.to_string(),
        kind: Kind::Curves(Curves {
            x_desc: x_desc.into(),
            y_desc: y_desc.into(),
            y,
            series: series
                .iter()
                .map(|(n, c, d, p)| (n.clone(), PALETTE[c % PALETTE.len()], *d, p.clone()))
                .collect(),
            reference: Vec::new(),
            reference_label: String::new(),
        }),
    }
}

/// Line charts on a grid, `cols` per row, each with its own axes.
#[derive(Clone, Debug)]
pub(super) struct Panels {
    cols: usize,
    panels: Vec<Curves>,
}

/// Ray or OPD fans: a row of two panels per field (tangential: the error against the pupil
/// coordinate along the field's direction; sagittal: across it), a curve per wavelength in one
/// colour each, one vertical scale for every panel. `rows` holds (field label, [(wavelength
/// label, tangential points, sagittal points)]).
#[must_use]
pub fn fan_figure(title: &str, y_desc: &str, rows: &[FanRow]) -> Figure {
    let ys = rows
        .iter()
        .flat_map(|r| r.1.iter())
        .flat_map(|c| c.1.iter().chain(c.2.iter()).map(|p| p.1));
    let y = span(ys.chain([0.0]), 0.08, -1.0..1.0);
    let mut panels = Vec::new();
    for (field, curves) in rows {
        for (k, which) in ["tangential", "sagittal"].iter().enumerate() {
            panels.push(Curves {
                x_desc: format!("field {field}: {which} pupil coordinate"),
                y_desc: y_desc.to_string(),
                y: y.clone(),
                series: curves
                    .iter()
                    .enumerate()
                    .map(|(i, c)| {
                        let pts = if k == 0 { c.1.clone() } else { c.2.clone() };
                        (c.0.clone(), PALETTE[i % PALETTE.len()], false, pts)
                    })
                    .collect(),
                reference: vec![vec![(-1.0, 0.0), (1.0, 0.0)]],
                reference_label: String::new(),
            });
        }
    }
    Figure {
        width: 900,
        height: (40 + 280 * rows.len().max(1) as u32).min(MAX_SIDE_PT),
        title: title.to_string(),
        kind: Kind::Panels(Panels { cols: 2, panels }),
    }
}

/// One field's fans: (field label, [(wavelength label, tangential, sagittal)]).
pub type FanRow = (String, Vec<(String, Vec<(f64, f64)>, Vec<(f64, f64)>)>);

pub(super) fn draw_panels<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    p: &Panels,
) -> DrawResult<DB> {
    let cols = p.cols.max(1);
    let rows = p.panels.len().div_ceil(cols).max(1);
    let areas = body.split_evenly((rows, cols));
    for (c, a) in p.panels.iter().zip(areas.iter()) {
        draw_curves(a, s, c)?;
    }
    Ok(())
}

/// Through-focus MTF at one frequency: (label, tangential points, sagittal points) with the
/// sensor shift (mm) on x.
#[must_use]
pub fn through_focus_figure(rows: &[FocusRow], freq_lpmm: f64, title: &str) -> Figure {
    let mut series = Vec::new();
    for (i, (name, t, sag)) in rows.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        series.push((format!("{name} T"), c, false, t.clone()));
        series.push((format!("{name} S"), c, true, sag.clone()));
    }
    Figure {
        width: 720,
        height: 460,
        title: title.to_string(),
        kind: Kind::Curves(Curves {
            x_desc: "sensor shift along the axis (mm)".into(),
            y_desc: format!("MTF at {freq_lpmm} cycles/mm"),
            y: 0.0..1.02,
            series,
            reference: Vec::new(),
            reference_label: String::new(),
        }),
    }
}

pub(super) fn draw_curves<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    c: &Curves,
) -> DrawResult<DB> {
    let xs = c
        .series
        .iter()
        .flat_map(|x| x.3.iter().map(|p| p.0))
        .chain(c.reference.iter().flat_map(|r| r.iter().map(|p| p.0)));
    let xr = span(xs, 0.0, 0.0..1.0);
    let mut chart = frame(body, s, Right::Margin).build_cartesian_2d(xr, c.y.clone())?;
    house_mesh!(chart, s, c.x_desc.as_str(), c.y_desc.as_str()).draw()?;
    let grey = rgb(GREY);
    for (k, r) in c.reference.iter().enumerate() {
        let a = chart.draw_series(line(r.clone(), grey, 1.0, s))?;
        if k == 0 && !c.reference_label.is_empty() {
            a.label(c.reference_label.clone())
                .legend(line_glyph(grey, s));
        }
    }
    for (name, col, dashed, pts) in &c.series {
        let col = rgb(*col);
        let pts: Vec<(f64, f64)> = pts.iter().copied().filter(finite).collect();
        let a = if *dashed {
            chart.draw_series(std::iter::once(DashedPathElement::new(
                pts,
                px(5.0, s),
                px(3.0, s),
                col.stroke_width(px(1.6, s)),
            )))?
        } else {
            chart.draw_series(line(pts, col, 1.6, s))?
        };
        let d = *dashed;
        a.label(name.clone()).legend(move |(x, y)| {
            if d {
                PathElement::new(
                    vec![(x, y), (x + px(5.0, s) as i32, y)],
                    col.stroke_width(px(2.0, s)),
                )
            } else {
                PathElement::new(
                    vec![(x, y), (x + px(18.0, s) as i32, y)],
                    col.stroke_width(px(2.0, s)),
                )
            }
        });
    }
    // One curve needs no legend: the title names it.
    if c.series.len() > 1 || !c.reference_label.is_empty() {
        legend_box(&mut chart, s, SeriesLabelPosition::UpperRight)?;
    }
    Ok(())
}
