//! OpticStudio's tilted surface (TILTSURF): the plane z = x tan θx + y tan θy of its frame, which
//! the surfaces after it keep; traced against Snell's law written out, as an image surface, written
//! back through coordinate breaks and JSON.

use super::*;

/// A plate of a model glass whose back face is a TILTSURF (a wedge), the image `image` lines.
fn wedge(image: &str) -> String {
    format!(
        "MODE SEQ\nUNIT MM\nENPD 10\nWAVM 1 0.5875618 1\nPWAV 1\n\
        SURF 0\n DISZ INFINITY\n\
        SURF 1\n STOP\n TYPE STANDARD\n CURV 0\n DISZ 2\n\
        SURF 2\n TYPE STANDARD\n CURV 0\n DISZ 6\n GLAS ___BLANK 1 0 1.5168 64.17 0 0 0 0 0 0\n DIAM 8\n\
        SURF 3\n TYPE TILTSURF\n PARM 1 0.03\n PARM 2 -0.2\n DISZ 50\n DIAM 8\n\
        SURF 4\n{image} DIAM 10\n"
    )
}

/// Rays parallel to the axis at (x, y) on a grid inside the stop, traced to the image.
fn parallel_rays(lens: &Lens) -> Vec<(Vec3<f64>, Vec3<f64>, Vec3<f64>)> {
    let mut b = RayBatch::<f64>::new();
    let mut starts = Vec::new();
    for i in -3..=3 {
        for j in -3..=3 {
            let p = Vec3::new(1.2 * i as f64, 1.1 * j as f64, -1.0);
            starts.push(p);
            b.push(p, Vec3::new(0.0, 0.0, 1.0));
        }
    }
    trace(
        &lens.compile(),
        LAMBDA_D_NM,
        &mut b,
        TraceOptions::default(),
    );
    b.iter()
        .zip(starts)
        .map(|(r, p)| {
            assert!(r.status.is_alive(), "{p:?}: {:?}", r.status);
            (p, r.o, r.d)
        })
        .collect()
}

/// Snell's law in vector form: the unit direction after `d` crosses a surface of unit normal `n`
/// (either orientation) from index `n1` into `n2`.
fn snell(d: Vec3<f64>, n: Vec3<f64>, n1: f64, n2: f64) -> Vec3<f64> {
    let n = if d.dot(n) < 0.0 { n * -1.0 } else { n };
    let (mu, cos_i) = (n1 / n2, d.dot(n));
    let cos_t = (1.0 - mu * mu * (1.0 - cos_i * cos_i)).sqrt();
    d * mu + n * (cos_t - mu * cos_i)
}

/// The wedge deflects each ray as Snell's law says at the plane z = 8 + 0.03 x - 0.2 y (the
/// back face's vertex 8 mm behind the stop): positions on the image plane 50 mm further and
/// directions to 1e-12. The surface's normal is (-0.03, 0.2, 1) normalised, and the image plane
/// stays square to the axis (the frame after a TILTSURF is unchanged).
#[test]
fn a_tilted_surface_refracts_as_snell_s_law_says() {
    let z = parse(&wedge(" TYPE STANDARD\n CURV 0\n")).unwrap();
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    let lens = &z.lens;
    assert_eq!(lens.surfaces.len(), 3);
    let norm = (1.0f64 + 0.03 * 0.03 + 0.2 * 0.2).sqrt();
    let want = [-0.03 / norm, 0.2 / norm, 1.0 / norm];
    for (a, b) in lens.surfaces[2].vec_local.iter().zip(want) {
        assert!((a - b).abs() <= 1e-15, "{:?}", lens.surfaces[2].vec_local);
    }
    assert_eq!(lens.surfaces[2].pos_xy_mm, [0.0, 0.0]);
    assert_eq!(lens.image_plane.normal, [0.0, 0.0, 1.0]);
    let n_glass = lens.surfaces[1].material.index(LAMBDA_D_NM);
    let normal = Vec3::new(want[0], want[1], want[2]);
    for (p, o, d) in parallel_rays(lens) {
        // The back face: z = 8 + x tan θx + y tan θy.
        let hit = Vec3::new(p.x, p.y, 8.0 + 0.03 * p.x - 0.2 * p.y);
        let out = snell(Vec3::new(0.0, 0.0, 1.0), normal, n_glass, 1.0);
        let at_image = hit + out * ((58.0 - hit.z) / out.z);
        assert!(
            (o - at_image).norm() <= 1e-12,
            "{p:?}: {o:?} vs {at_image:?}"
        );
        assert!((d - out).norm() <= 1e-12, "{p:?}: {d:?} vs {out:?}");
    }
    // The deviation is the wedge's: 0.2 rad of slope gives ~6 degrees with n = 1.5168.
    let (_, _, d) = parallel_rays(lens)[0];
    let dev = d.z.acos().to_degrees();
    assert!((5.0..7.0).contains(&dev), "{dev}");
}

/// A TILTSURF image surface is the tilted image plane z = 58 + 0.1 y of the image frame: every
/// ray ends on it, on its own straight path from the wedge.
#[test]
fn a_tilted_image_surface_is_a_tilted_image_plane() {
    let flat = parse(&wedge(" TYPE STANDARD\n CURV 0\n")).unwrap().lens;
    let z = parse(&wedge(" TYPE TILTSURF\n PARM 2 0.1\n")).unwrap();
    let norm = (1.0f64 + 0.01).sqrt();
    let n = z.lens.image_plane.normal;
    assert!(
        n[0] == 0.0 && (n[1] + 0.1 / norm).abs() <= 1e-15 && (n[2] - 1.0 / norm).abs() <= 1e-15
    );
    for ((p, o, d), (_, o_flat, d_flat)) in
        parallel_rays(&z.lens).into_iter().zip(parallel_rays(&flat))
    {
        assert!((d - d_flat).norm() <= 1e-15, "{p:?}");
        assert!((o.z - (58.0 + 0.1 * o.y)).abs() <= 1e-12, "{p:?}: {o:?}");
        // On the same line as the ray that ends on the square plane.
        let back = o_flat + d_flat * ((o.z - o_flat.z) / d_flat.z);
        assert!((o - back).norm() <= 1e-12, "{p:?}");
    }
}

/// tolray writes a tilted surface as a coordinate-break pair around a flat one, which reads back
/// as the same lens (rays to 1e-12); JSON keeps its normal exactly.
#[test]
fn a_tilted_surface_round_trips_through_zmx_and_json() {
    for image in [
        " TYPE STANDARD\n CURV 0\n",
        " TYPE TILTSURF\n PARM 1 -0.05\n PARM 2 0.1\n",
    ] {
        let z = parse(&wedge(image)).unwrap();
        let written = zemax::to_string(&z.lens, Some(&z.extras));
        assert!(written.contains("TYPE COORDBRK"), "{written}");
        let back = zemax::from_str(&written, &GlassCatalogs::builtin()).unwrap();
        assert_same_trace(
            &z.lens.compile(),
            &back.lens.compile(),
            1e-12,
            "zmx round trip",
        );
        assert_eq!(json::from_str(&json::to_string(&z.lens)).unwrap(), z.lens);
    }
}

/// What a TILTSURF cannot be in tolray is refused or warned of, naming the line: parameters beyond
/// its two tangents, a steep tilted mirror (OpticStudio keeps the frame, tolray turns the axis at a
/// mirror tilted 20 degrees or more); a curvature is ignored, as OpticStudio ignores it.
#[test]
fn what_a_tilted_surface_cannot_be_is_refused_by_line() {
    let text = wedge(" TYPE STANDARD\n CURV 0\n");
    let e = err(&text.replace(" PARM 2 -0.2\n", " PARM 2 -0.2\n PARM 3 0.1\n"));
    assert!(e.contains("PARM 3 = 0.1") && e.contains("TILTSURF"), "{e}");
    let e = err(&text.replace(" PARM 2 -0.2\n", " PARM 2 -1e300\n"));
    assert!(e.contains("PARM 2") && e.contains("finite"), "{e}");
    let steep = text
        .replace(
            " PARM 2 -0.2\n DISZ 50\n",
            " PARM 2 -0.5\n DISZ -50\n GLAS MIRROR\n",
        )
        .replace("SURF 4\n", "SURF 4\n DISZ 0\n");
    let e = err(&steep);
    assert!(e.contains("tilted 26.6 degrees by TILTSURF"), "{e}");
    assert!(
        e.contains(&format!("line {}", line_of(&steep, "TYPE TILTSURF"))),
        "{e}"
    );
    let curved = text.replace(" TYPE TILTSURF\n", " TYPE TILTSURF\n CURV 0.01\n");
    let z = parse(&curved).unwrap();
    assert!(
        z.warnings.iter().any(|w| w.contains("CURV 0.01 ignored")),
        "{:?}",
        z.warnings
    );
    assert_eq!(z.lens, parse(&text).unwrap().lens);
}
