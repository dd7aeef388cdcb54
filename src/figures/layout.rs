//! Meridional layouts: the lens drawn to scale with a ray fan per field.

use super::*;

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
    // The image surface's meridional section (decentred or tilted with the lens' image plane;
    // a curved one drawn to its rim when that is nearer than the sensor's corner).
    let h = lens.sensor.half_diagonal_mm();
    let ip = &lens.image_plane;
    let (c, k1) = (ip.curvature_per_mm, 1.0 + ip.conic);
    let rim = if c != 0.0 && k1 > 0.0 {
        h.min(0.999_999 / (c.abs() * k1.sqrt()))
    } else {
        h
    };
    let sensor: Vec<(f64, f64)> = (0..=64)
        .map(|i| {
            let y = -rim + 2.0 * rim * i as f64 / 64.0;
            let a = (1.0 - k1 * c * c * y * y).max(0.0);
            let p = sys
                .image
                .point_to_global(Vec3::new(0.0, y, c * y * y / (1.0 + a.sqrt())));
            (p.z, p.y)
        })
        .collect();
    let ends = [sensor[0], sensor[64]];
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
                // Through a gradient-index medium the path curves: its steps' points.
                // Both faces of the medium are drawn at least as high as the path climbs.
                if let Some(i) = upto {
                    let path = crate::trace::reference::gradient_path(sys, i, r.o, r.d);
                    for p in &path {
                        for k in [i, i + 1] {
                            let row = &sys.rows[k];
                            let local = row.rot.apply_t(*p - row.pos);
                            ray_height[k] = ray_height[k].max(local.y.abs());
                        }
                    }
                    pts.extend(path.iter().map(|p| (p.z, p.y)));
                }
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
            sensor,
        },
    })
}

/// A lens name for a title: up to its first colon, and at most 72 characters (a longer name,
/// as a .zmx NAME line can be, is cut at a word with an ellipsis so the title fits the page).
pub(super) fn short(s: &str) -> String {
    let s = s.split(':').next().unwrap_or(s).trim();
    if s.chars().count() <= 72 {
        return s.to_string();
    }
    let head: String = s.chars().take(72).collect();
    let cut = head.rfind(' ').filter(|&i| i > 40).unwrap_or(head.len());
    format!("{}…", head[..cut].trim_end_matches([',', ';', ' ']))
}

#[allow(clippy::too_many_arguments)]
pub(super) fn draw_layout<DB: DrawingBackend>(
    body: &DrawingArea<DB, Shift>,
    s: f64,
    x: &Range<f64>,
    y: &Range<f64>,
    rays: &[(Rgb, Vec<(f64, f64)>)],
    fields: &[(String, Rgb)],
    outlines: &[Vec<(f64, f64)>],
    sensor: &[(f64, f64)],
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
        .label(if bends(sensor) {
            "image surface"
        } else {
            "image plane"
        })
        .legend(line_glyph(RGBColor(200, 0, 0), s));
    legend_box(&mut chart, s, SeriesLabelPosition::UpperLeft)
}

/// True when the drawn image section bends (a curved image surface).
fn bends(section: &[(f64, f64)]) -> bool {
    let (a, b) = (section[0], section[section.len() - 1]);
    let m = section[section.len() / 2];
    // Distance of the middle point from the chord.
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len = dx.hypot(dy).max(1e-300);
    ((m.0 - a.0) * dy - (m.1 - a.1) * dx).abs() / len > 1e-9 * (1.0 + len)
}
