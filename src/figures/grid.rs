//! Grid distortion: the ideal image of a grid of fields over the sensor and where the real
//! chief rays land.

use super::*;
use crate::analysis::aberrations::{DistortionKind, GridDistortion};

/// The grid picture's data: points per side, the ideal and the real points (row-major), mm.
#[derive(Clone, Debug)]
pub(super) struct Grid {
    n: usize,
    ideal: Vec<(f64, f64)>,
    real: Vec<(f64, f64)>,
    ideal_label: String,
}

/// Grid distortion ([`crate::analysis::aberrations::grid_distortion`]): the ideal grid in grey,
/// the real chief rays' image points in blue joined row by row and column by column, to scale
/// (equal axes, mm from the on-axis image point).
#[must_use]
pub fn grid_distortion_figure(g: &GridDistortion, title: &str) -> Figure {
    let pts = |v: &[[f64; 2]]| v.iter().map(|p| (p[0], p[1])).collect();
    let ideal_label = match g.kind {
        DistortionKind::FTan => "ideal (f-tan θ)",
        DistortionKind::FTheta => "ideal (f-θ)",
    };
    Figure {
        width: 640,
        height: 600,
        title: title.to_string(),
        kind: Kind::Grid(Grid {
            n: g.n,
            ideal: pts(&g.ideal_mm),
            real: pts(&g.real_mm),
            ideal_label: ideal_label.into(),
        }),
    }
}

pub(super) fn draw_grid<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    g: &Grid,
) -> DrawResult<DB> {
    let all = g.ideal.iter().chain(&g.real).copied().filter(finite);
    let half = all
        .fold(0.0f64, |m, p| m.max(p.0.abs()).max(p.1.abs()))
        .max(1e-9)
        * 1.08;
    let area = body.margin(0, px(10.0, s), px(10.0, s), px(10.0, s));
    let (m, labels) = (px(8.0, s), (px(42.0, s), px(58.0, s)));
    // Room above the grid for the legend.
    let (xr, yr) = equal_aspect(&area, m, labels, -half..half, -half..1.3 * half);
    let mut chart = ChartBuilder::on(&area)
        .margin(m)
        .x_label_area_size(labels.0)
        .y_label_area_size(labels.1)
        .build_cartesian_2d(xr, yr)?;
    house_mesh!(chart, s, "x (mm)", "y (mm)").draw()?;
    let n = g.n;
    // Rows and columns of a row-major n x n grid, each as one polyline.
    let lines = |v: &[(f64, f64)]| -> Vec<Vec<(f64, f64)>> {
        let rows = (0..n).map(|j| (0..n).map(|i| v[j * n + i]).collect());
        let cols = (0..n).map(|i| (0..n).map(|j| v[j * n + i]).collect());
        rows.chain(cols).collect()
    };
    // The real grid first, the ideal one over it in a thin dark line: where the two coincide
    // (a fraction of a percent) both stay visible.
    let blue = rgb(PALETTE[0]);
    for l in lines(&g.real) {
        chart.draw_series(line(l, tint(PALETTE[0], 0.35), 2.2, s))?;
    }
    let dark = RGBColor(60, 60, 60);
    for (k, l) in lines(&g.ideal).into_iter().enumerate() {
        let a = chart.draw_series(line(l, dark, 0.8, s))?;
        if k == 0 {
            a.label(g.ideal_label.clone()).legend(line_glyph(dark, s));
        }
    }
    let r = (2.2 * s).max(1.0);
    chart
        .draw_series(
            g.real
                .iter()
                .copied()
                .filter(finite)
                .map(|p| Circle::new(p, r, blue.filled())),
        )?
        .label("real chief rays")
        .legend(move |(x, y)| Circle::new((x + px(9.0, s) as i32, y), 3.5 * s, blue.filled()));
    legend_box(&mut chart, s, SeriesLabelPosition::UpperRight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::aberrations::grid_distortion;

    #[test]
    fn the_grid_draws_both_grids_with_units_and_legend() {
        let lens = Lens::load("cooke-triplet").unwrap();
        let g = grid_distortion(
            &lens,
            &lens.compile(),
            5,
            587.5618,
            DistortionKind::FTan,
            false,
        )
        .unwrap();
        let fig = grid_distortion_figure(&g, "grid");
        let svg = fig.to_svg().unwrap();
        for text in ["x (mm)", "y (mm)", "ideal (f-tan θ)", "real chief rays"] {
            assert!(svg.contains(text), "{text}");
        }
        assert!(fig.to_png().is_ok());
    }
}
