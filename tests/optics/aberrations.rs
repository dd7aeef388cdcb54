//! Aberration curves against optiland 0.6.3 (`tests/data/wave/optiland_aberrations.json`, made
//! once by `scripts/waveref/aberration_reference.py`, which names optiland's methods) on the
//! lenses of `wave_reference`: field curvature (tangential and sagittal) and distortion (f-tan θ,
//! and f-θ for objects at infinity) at 0, 0.25, 0.5, 0.75 and 1 of the largest field; and
//! closed forms for relative illumination, lateral colour and the fans.

use super::wave::{oval_of, N};
use super::wave_reference::{floats, load};
use serde_json::Value;
use tolray::analysis::aberrations::{
    distortion, fans, field_curvature, grid_distortion, lateral_colour, relative_illumination,
    DistortionKind,
};
use tolray::trace::Field;
use tolray::wave::WaveOptions;
use tolray::Lens;

fn data() -> Value {
    let p = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/wave/optiland_aberrations.json"
    );
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// optiland's angle field (a positive angle sends the rays up) as tolray's; for a finite object
/// the object height it names at the entrance pupil (see `wave_reference::field`).
fn field(l: &Value, deg: f64) -> Field {
    let p = &l["paraxial"];
    if p["object_infinite"].as_bool() == Some(false) {
        let d = p["ep_z_global_mm"].as_f64().unwrap() - p["object_z_global_mm"].as_f64().unwrap();
        Field::HeightMm {
            x: 0.0,
            y: -d * deg.to_radians().tan(),
        }
    } else {
        Field::angle(-deg)
    }
}

#[test]
fn field_curvature_and_distortion_agree_with_optiland() {
    let d = data();
    let (mut worst_fc, mut worst_fc_rel, mut worst_dist) = (0.0f64, 0.0f64, 0.0f64);
    println!("| lens | field (deg) | T focus tolray / optiland (mm) | S focus | f-tan distortion % tolray / optiland |");
    println!("|---|---|---|---|---|");
    for l in d["lenses"].as_array().unwrap() {
        let lens = load(l);
        let sys = lens.compile();
        let wl = l["wavelength_um"].as_f64().unwrap() * 1e3;
        let degs = floats(&l["field_deg"]);
        let fields: Vec<Field> = degs.iter().map(|&a| field(l, a)).collect();
        // optiland's tangential crossing at its own 1e-5 pupil offset is noisy for a distant
        // finite object (the triplet's 20 m: it moves by 1e-4 mm between offsets of 1e-4 and
        // 1e-6); the script extrapolates larger pairs to zero offset and records their spread.
        // Sagittal: optiland's own numbers.
        let t_ref = floats(&l["field_curvature_tangential_richardson_mm"]);
        let t_spread = floats(&l["field_curvature_tangential_richardson_spread_mm"]);
        let s_ref = floats(&l["field_curvature_sagittal_mm"]);
        let id = l["id"].as_str().unwrap();
        for (k, &f) in fields.iter().enumerate() {
            let [t, s] = field_curvature(&lens, &sys, f, wl, false).unwrap();
            for (what, a, b, spread) in [("T", t, t_ref[k], t_spread[k]), ("S", s, s_ref[k], 0.0)] {
                let e = (a - b).abs();
                let tol = (1e-6 * b.abs().max(1e-3)).max(2.0 * spread);
                worst_fc = worst_fc.max(e);
                worst_fc_rel = worst_fc_rel.max(e / b.abs().max(1e-3));
                assert!(
                    e <= tol,
                    "{id} field {} deg {what}: {a} mm against optiland's {b} (tolerance {tol:.1e})",
                    degs[k]
                );
            }
        }
        let mut dist = Vec::new();
        for kind in [DistortionKind::FTan, DistortionKind::FTheta] {
            let key = match kind {
                DistortionKind::FTan => "distortion_f_tan_percent",
                DistortionKind::FTheta => "distortion_f_theta_percent",
            };
            if l[key].is_null() {
                continue;
            }
            let r = floats(&l[key]);
            let v = distortion(&lens, &sys, &fields, wl, kind, false).unwrap();
            for k in 0..v.len() {
                // Both are 100 (y - y_ideal) / y_ideal: compared as image heights, to 1e-8 of
                // the ideal height (1e-6 in percent).
                let e = (v[k] - r[k]).abs();
                worst_dist = worst_dist.max(e);
                assert!(
                    e < 1e-6,
                    "{id} {kind:?} field {} deg: {} % against optiland's {} %",
                    degs[k],
                    v[k],
                    r[k]
                );
            }
            dist.push(v);
        }
        for k in [1, 4] {
            let [t, s] = field_curvature(&lens, &sys, fields[k], wl, false).unwrap();
            println!(
                "| {id} | {:.4} | {t:.6} / {:.6} | {s:.6} / {:.6} | {:.6} / {:.6} |",
                degs[k],
                t_ref[k],
                s_ref[k],
                dist[0][k],
                floats(&l["distortion_f_tan_percent"])[k]
            );
        }
    }
    println!(
        "worst: field curvature {worst_fc:.2e} mm ({worst_fc_rel:.2e} relative), distortion {worst_dist:.2e} %"
    );
}

#[test]
fn relative_illumination_lateral_colour_and_fans_obey_closed_forms() {
    // A pinhole-like perfect focus: the oval stopped down. Its off-axis beam is not aberration
    // free, but the illumination of a small stop at the surface follows cos³ θ' (the image is
    // inside glass, the pupil at the surface): the projected solid angle of a stop of area A
    // seen from distance r is A cos θ / r², and r = f / cos θ at the image plane, with the
    // stop's own foreshortening cos θ: cos⁴ θ in image space.
    let l = oval_of(0.0, 0.5);
    let sys = l.compile();
    let wl = 587.5618;
    let f = N * 20.0 / (N - 1.0);
    let degs = [0.0, 2.0, 5.0];
    let fields: Vec<Field> = degs.iter().map(|&a| Field::angle(a)).collect();
    let ri = relative_illumination(&l, &sys, &fields, wl, false).unwrap();
    for (k, &a) in degs.iter().enumerate() {
        // Image-space angle of the chief ray through the surface vertex: sin θ' = sin θ / N.
        let tp = (a.to_radians().sin() / N).asin();
        let exact = tp.cos().powi(4);
        assert!(
            (ri[k] - exact).abs() < 2e-3,
            "{a} deg: {} against cos⁴ θ' = {exact} (f = {f})",
            ri[k]
        );
    }
    // No dispersion: no lateral colour.
    let lc = lateral_colour(&l, &sys, &fields, &[486.1327, 656.2725], false).unwrap();
    assert!(lc.iter().flatten().all(|v| v.abs() < 1e-9), "{lc:?}");
    // A glass lens has lateral colour, zero on axis, and the ray fan on axis is odd.
    let cooke = Lens::load("cooke-triplet").unwrap();
    let cs = cooke.compile();
    let lc = lateral_colour(
        &cooke,
        &cs,
        &[Field::fraction(0.0), Field::fraction(1.0)],
        &[486.1327, 656.2725],
        false,
    )
    .unwrap();
    assert!(lc[0].iter().all(|v| v.abs() < 1e-9) && lc[1][0] != lc[1][1]);
    let fan = fans(
        &cooke,
        &cs,
        Field::fraction(0.0),
        486.1327,
        11,
        &WaveOptions::default(),
    )
    .unwrap();
    for i in 0..11 {
        let j = 10 - i;
        // µm and waves: 1e-6 of a µm is 1e-9 mm. A ray the rim's aperture clips is NaN, on both
        // sides alike.
        let near = |a: f64, b: f64| (a.is_nan() && b.is_nan()) || (a - b).abs() < 1e-6;
        assert!(near(fan.tangential_um[i], -fan.tangential_um[j]), "{fan:?}");
        assert!(near(fan.sagittal_um[i], -fan.sagittal_um[j]), "{fan:?}");
        assert!(
            near(fan.opd_tangential_waves[i], fan.opd_sagittal_waves[i]),
            "{fan:?}"
        );
    }
    // Off the primary wavelength the fan's centre is the lateral colour (0 on axis) and the
    // OPD at the pupil centre is 0.
    assert!(fan.tangential_um[5].abs() < 1e-9 && fan.opd_tangential_waves[5].abs() < 1e-12);
    let off = fans(
        &cooke,
        &cs,
        Field::fraction(1.0),
        486.1327,
        11,
        &WaveOptions::default(),
    )
    .unwrap();
    assert!(
        (off.tangential_um[5] - lc[1][0]).abs() < 1e-6,
        "{} vs {}",
        off.tangential_um[5],
        lc[1][0]
    );
    // Bad input.
    assert!(fans(
        &cooke,
        &cs,
        Field::fraction(0.0),
        486.1327,
        2,
        &WaveOptions::default()
    )
    .is_err());
    assert!(distortion(
        &load_finite(),
        &load_finite().compile(),
        &[Field::fraction(0.5)],
        wl,
        DistortionKind::FTheta,
        false
    )
    .is_err());
}

fn load_finite() -> Lens {
    Lens::load("lens1").unwrap()
}

/// Grid distortion is the radial distortion in two dimensions: on a rotationally symmetric lens
/// every grid point's distortion is the meridional distortion at its field radius, and its real
/// image point the ideal one scaled by it, in the same direction; the grid covers the sensor's
/// rectangle.
#[test]
fn grid_distortion_is_the_meridional_distortion_at_each_radius() {
    let mut lens = Lens::load("lens2").unwrap();
    let wl = 587.5618;
    for (res, n) in [([600, 600], 5), ([1600, 900], 4)] {
        lens.sensor.resolution = res;
        let sys = lens.compile();
        let g = grid_distortion(&lens, &sys, n, wl, DistortionKind::FTan, false).unwrap();
        assert_eq!(g.fields.len(), n * n);
        // The corners are the sensor's: full field along the diagonal, the sensor's aspect.
        let c = g.fields[n * n - 1];
        assert!((c[0].hypot(c[1]) - 1.0).abs() < 1e-12, "{c:?}");
        assert!((c[0] / c[1] - f64::from(res[0]) / f64::from(res[1])).abs() < 1e-12);
        let mut largest = 0.0f64;
        for (k, f) in g.fields.iter().enumerate() {
            let r = f[0].hypot(f[1]);
            let d = distortion(
                &lens,
                &sys,
                &[Field::fraction(r)],
                wl,
                DistortionKind::FTan,
                false,
            )
            .unwrap()[0];
            assert!(
                (g.distortion_pct[k] - d).abs() < 1e-6,
                "field {f:?}: {} % against {d} % along y",
                g.distortion_pct[k]
            );
            let s = 1.0 + d / 100.0;
            let (i, re) = (g.ideal_mm[k], g.real_mm[k]);
            assert!(
                (re[0] - s * i[0]).abs() < 1e-8 && (re[1] - s * i[1]).abs() < 1e-8,
                "field {f:?}: real {re:?}, ideal {i:?}, scale {s}"
            );
            if d.abs() > largest.abs() {
                largest = d;
            }
        }
        assert!((g.max_distortion_pct - largest).abs() < 1e-6);
        // An image inverts: a field above the axis lands below it.
        assert!(g.real_mm[n * n - 1][1] < 0.0 && g.ideal_mm[n * n - 1][1] < 0.0);
    }
    let sys = lens.compile();
    assert!(grid_distortion(&lens, &sys, 1, wl, DistortionKind::FTan, false).is_err());
    assert!(grid_distortion(&lens, &sys, 102, wl, DistortionKind::FTan, false).is_err());
    let finite = load_finite();
    assert!(grid_distortion(
        &finite,
        &finite.compile(),
        3,
        wl,
        DistortionKind::FTheta,
        false
    )
    .is_err());
}
