//! Monte Carlo histograms with the cumulative distribution and the yield lines.

use super::*;

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

pub(super) fn draw_tolerance<DB: DrawingBackend>(
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
