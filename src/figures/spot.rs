//! Spot diagrams: a panel per field, wavelengths coloured by band.

use super::*;

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
pub(super) fn wavelength_colours(nm: &[f64]) -> Vec<Rgb> {
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
pub(super) fn equal_aspect<DB: DrawingBackend>(
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

pub(super) fn draw_spots<DB: DrawingBackend>(
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
