//! Training curves of the optics and of a deep-optics study.

use super::*;

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

pub(super) fn draw_training<DB: DrawingBackend>(
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

pub(super) fn draw_deep_training<DB: DrawingBackend>(
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
