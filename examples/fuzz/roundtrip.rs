//! Round trips of the fuzzer (examples/fuzz.rs): what tolray writes reads back as the same lens.

use tolray::lens::material::GlassCatalogs;
use tolray::lens::{json, zemax, SurfaceRole};
use tolray::math::Vec3;
use tolray::trace::{raw, TraceOptions};
use tolray::Lens;

/// What tolray writes it reads back as the same lens: the JSON always (a lens that validates
/// is one its JSON can hold), the .zmx file unless the writer refused it (a name clash between
/// vendors) or the reader refuses it with a reason.
pub(crate) fn round_trip(l: &Lens, sys: &tolray::lens::System<f64>) -> Result<(), String> {
    let back = json::from_str(&json::to_string(l))
        .map_err(|e| format!("JSON round trip: tolray refuses the JSON it wrote: {e}"))?;
    same_lens(l, sys, &back, "JSON round trip", true, true)?;
    let text = zemax::to_string(l, None);
    // A fold whose frame is not its mirror's reflection of the axis, or that turns off the
    // mirror's vertex (a mutated or toleranced fold), and a mirror tilted 20 degrees or more
    // without a fold, read back as the same surfaces in space on the reflected axis turned at
    // the vertex (the .zmx reader's folds): the same lens for the light, but the unfolded
    // model's gaps, and so its first-order numbers, follow that axis.
    let dirs = l.travel_directions();
    let refolded = l.surfaces.iter().zip(&dirs).any(|(s, &dir)| match s.fold {
        Some(f) => !canonical_fold(s, f, dir),
        None => s.role == SurfaceRole::Mirror && tilt_deg(s.vec_local) >= 20.0,
    });
    // Near grazing (a surface or the image plane turned beyond 80 degrees), the last digit of
    // a written angle moves landing points by more than the rays' tolerance.
    let grazing = l.surfaces.iter().any(|s| tilt_deg(s.vec_local) > 80.0)
        || tilt_deg(l.image_plane.normal) > 80.0;
    match zemax::from_str(&text, &GlassCatalogs::builtin()) {
        Ok(z) => same_lens(l, sys, &z.lens, "zmx round trip", !refolded, !grazing),
        // The writer leaves what the format cannot say for the reader to refuse by name;
        // an error that does not say which line would be a finding of its own.
        Err(e) if e.message().contains("line") || e.message().contains("SURF") => Ok(()),
        Err(e) => Err(format!(
            "zmx round trip: the file tolray wrote is refused without a line: {e}"
        )),
    }
}

/// `b` is `a` (compiled as `sys_a`) as far as the light can tell: the same media at the
/// lens' wavelengths, the same first-order data (when `first_order`), and (when `rays`) the
/// same path for a fan of rays entering the first surface at two angles and three wavelengths
/// (to 1e-7 mm and 1e-9 in direction, what writing angles and positions as decimal text may
/// cost; one ray in 20 may change its fate at an aperture's edge).
pub(crate) fn same_lens(
    a: &Lens,
    sys_a: &tolray::lens::System<f64>,
    b: &Lens,
    what: &str,
    first_order: bool,
    rays: bool,
) -> Result<(), String> {
    if a.surfaces.len() != b.surfaces.len() {
        return Err(format!(
            "{what}: {} surfaces became {}",
            a.surfaces.len(),
            b.surfaces.len()
        ));
    }
    let mut wavelengths = vec![a.primary_wavelength_nm];
    wavelengths.extend(a.rgb_wavelengths_nm);
    let close = |x: f64, y: f64, tol: f64| (x - y).abs() <= tol * (1.0 + x.abs().max(y.abs()));
    for &wl in &wavelengths {
        for (k, (sa, sb)) in a.surfaces.iter().zip(&b.surfaces).enumerate() {
            let (na, nb) = (sa.material.index(wl), sb.material.index(wl));
            if !close(na, nb, 1e-9) {
                return Err(format!(
                    "{what}: surface {k}'s medium {} (n = {na} at {wl} nm) became {} (n = {nb})",
                    sa.material.json_name(),
                    sb.material.json_name()
                ));
            }
        }
        let (na, nb) = (a.object_medium.index(wl), b.object_medium.index(wl));
        if !close(na, nb, 1e-9) {
            return Err(format!(
                "{what}: the object medium's index {na} became {nb}"
            ));
        }
    }
    let wl = a.primary_wavelength_nm;
    let paraxial = |l: &Lens| {
        if first_order {
            l.paraxial(wl).map(Some)
        } else {
            Ok(None)
        }
    };
    match (paraxial(a), paraxial(b)) {
        (Ok(None), Ok(None)) => {}
        (Ok(Some(pa)), Ok(Some(pb))) => {
            let pairs = [
                ("EFL", pa.efl_mm.unwrap_or(0.0), pb.efl_mm.unwrap_or(0.0)),
                (
                    "image distance",
                    pa.image_distance_mm.unwrap_or(0.0),
                    pb.image_distance_mm.unwrap_or(0.0),
                ),
                (
                    "entrance pupil diameter",
                    pa.entrance_pupil_diameter_mm,
                    pb.entrance_pupil_diameter_mm,
                ),
                ("magnification", pa.magnification, pb.magnification),
                ("total track", pa.total_track_mm, pb.total_track_mm),
            ];
            for (name, x, y) in pairs {
                if !close(x, y, 1e-7) {
                    return Err(format!("{what}: paraxial {name} {x} became {y}"));
                }
            }
        }
        (Err(_), Err(_)) => {}
        (ra, rb) => {
            return Err(format!(
                "{what}: paraxial data {} became {}",
                if ra.is_ok() { "computed" } else { "refused" },
                if rb.is_ok() { "computed" } else { "refused" }
            ))
        }
    }
    // A refolded lens (`first_order` false) may read back with its image on the other side of
    // the last surface along the unfolded axis: a real image becomes a virtual one, to which
    // the rays are extended backwards, and the rays' fates are not comparable.
    let image_is_virtual = |l: &Lens| {
        let last = l.surfaces.last().map_or(0.0, |s| s.d_next_mm);
        last * l.travel_directions().last().copied().unwrap_or(1.0) < 0.0
    };
    if !rays || (!first_order && image_is_virtual(a) != image_is_virtual(b)) {
        return Ok(());
    }
    let sys_b = b.compile();
    let r = 0.5 * a.surfaces[0].semi_aperture_mm;
    let mut rays = Vec::new();
    for &wl in &wavelengths {
        for deg in [0.0f64, 1.0] {
            let (sn, cs) = deg.to_radians().sin_cos();
            for i in -2..=2 {
                for j in -2..=2 {
                    rays.push(raw::RawRay {
                        ox: r * i as f64 / 2.0,
                        oy: r * j as f64 / 2.0,
                        oz: -1.0,
                        dx: 0.0,
                        dy: sn,
                        dz: cs,
                        wavelength_nm: wl,
                    });
                }
            }
        }
    }
    // The same rays relative to the lens: a prescription keeps its first vertex at z = 0, so a
    // baked pattern that moves that vertex along the axis moves the global frame with it (rays
    // launched at one global point would enter a slanted beam elsewhere in the pupil).
    let dz = sys_b.rows[0].pos.z - sys_a.rows[0].pos.z;
    let rays_b: Vec<raw::RawRay> = rays
        .iter()
        .map(|r| raw::RawRay {
            oz: r.oz + dz,
            ..*r
        })
        .collect();
    let opts = TraceOptions { apertures: true };
    // Both refuse a wavelength at which a medium has no index, or neither does.
    let (ha, hb) = match (
        raw::trace_raw(sys_a, &rays, opts),
        raw::trace_raw(&sys_b, &rays_b, opts),
    ) {
        (Ok(ha), Ok(hb)) => (ha, hb),
        (Err(_), Err(_)) => return Ok(()),
        (x, y) => {
            let says = |r: &tolray::Result<Vec<raw::RawHit>>| match r {
                Ok(_) => "traced".to_string(),
                Err(e) => format!("refused ({})", e.message()),
            };
            return Err(format!(
                "{what}: the raw trace was {}, read back {}",
                says(&x),
                says(&y)
            ));
        }
    };
    // Where each ray lands as a user sees it: x, y in the image surface's own frame, and the
    // direction there.
    let on_sensor = |sys: &tolray::lens::System<f64>, h: &raw::RawHit| {
        let p = sys.image.point_to_local(Vec3::new(h.x, h.y, h.z));
        let d = sys.image.rotation.apply_t(Vec3::new(h.dx, h.dy, h.dz));
        [p.x, p.y, d.x, d.y, d.z]
    };
    // A ray meeting a surface at its edge or at t = 0 (coincident surfaces) may change its fate
    // with the last digit of a written number; a lens read back as another changes many.
    let mut fates = 0;
    for (k, (x, y)) in ha.iter().zip(&hb).enumerate() {
        if x.status != y.status {
            fates += 1;
            if fates > rays.len() / 20 {
                return Err(format!(
                    "{what}: ray {k} {} became {} ({fates} rays changed their fate)",
                    x.status, y.status
                ));
            }
            continue;
        }
        if x.status != "alive" {
            continue;
        }
        let (p, q) = (on_sensor(sys_a, x), on_sensor(&sys_b, y));
        let ok = close(p[0], q[0], 1e-7)
            && close(p[1], q[1], 1e-7)
            && (2..5).all(|i| (p[i] - q[i]).abs() < 1e-9);
        if !ok {
            return Err(format!(
                "{what}: ray {k} lands at ({}, {}) mm on the image surface, read back at ({}, {})",
                p[0], p[1], q[0], q[1]
            ));
        }
    }
    Ok(())
}

/// The angle (degrees) between a surface normal and the axis.
fn tilt_deg(n: [f64; 3]) -> f64 {
    let v = Vec3::new(n[0], n[1], n[2]);
    (v.z / v.norm()).clamp(-1.0, 1.0).acos().to_degrees()
}

/// True when the fold turns the axis at the mirror's vertex by the mirror's reflection of it
/// (`dir`: the direction of travel along z before the mirror, as the .zmx reader's folds).
fn canonical_fold(s: &tolray::lens::Surface, f: tolray::lens::Fold, dir: f64) -> bool {
    let n = Vec3::new(s.vec_local[0], s.vec_local[1], s.vec_local[2]).normalized();
    let d = Vec3::new(0.0, 0.0, dir);
    let v = d - n * (2.0 * d.dot(n));
    let turned = f.rotation().apply(Vec3::new(0.0, 0.0, -dir));
    f.pivot_mm == 0.0 && (turned - v).norm() < 1e-12
}
