//! Malformed .zmx input is an error naming its line; skipped or approximated input warns, naming it.

use super::*;

#[test]
fn malformed_lines_are_errors_that_name_the_line() {
    let base = text("asphere.zmx");
    let check_n = |t: &str, n: usize, want: &[&str]| {
        let m = err(t);
        assert!(m.starts_with(&format!("line {n}: ")), "line {n}: {m}");
        for w in want {
            assert!(m.contains(w), "line {n}: \"{m}\" lacks \"{w}\"");
        }
    };
    let check = |t: &str, start: &str, want: &[&str]| check_n(t, line_of(t, start), want);
    let t = replace_line(&base, "CURV 0.05", "  CURV 0.05x");
    check(
        &t,
        "CURV 0.05x",
        &["CURV", "\"0.05x\" is not a finite number"],
    );
    let t = replace_line(&base, "TYPE EVENASPH", "  TYPE BICONICX");
    check(
        &t,
        "TYPE BICONICX",
        &["surface type BICONICX (SURF 2) is not supported"],
    );
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS ___BLANK 1 0 1.5168");
    check(&t, "GLAS ___BLANK", &["a model glass needs n_d and V_d"]);
    // Vignetting factors tolray cannot apply: a rotated pupil, a pupil of no size.
    let t = base.replace("FWGN 1 1 1\n", "FWGN 1 1 1\nVANN 0 0 12\n");
    check(
        &t,
        "VANN",
        &[
            "field 3: vignetting angle (VANN) 12°",
            "not a rotated vignetted pupil",
        ],
    );
    let t = base.replace("FWGN 1 1 1\n", "FWGN 1 1 1\nVCYN 0 1 0\n");
    check(
        &t,
        "VCYN",
        &["field 2: vignetting compression y 1", "below 1"],
    );
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS");
    check(&t, "GLAS", &["GLAS needs a glass name"]);
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS N-BK77");
    check(
        &t,
        "GLAS N-BK77",
        &["unknown glass \"N-BK77\"", "N-BK7", "--glass-catalog"],
    );
    // A mirror followed by a positive thickness: the next surface lies behind the light.
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS MIRROR");
    check(
        &t,
        "SURF 3",
        &["SURF 3 lies 4 mm before the previous surface along the light's path"],
    );
    let t = replace_line(&base, "SURF 3", "SURF 4");
    check(&t, "SURF 4", &["SURF 4 is out of order (expected SURF 3)"]);
    let t = replace_line(&base, "DISZ 30.5", "  DISZ INFINITY");
    let n = t
        .lines()
        .collect::<Vec<_>>()
        .iter()
        .rposition(|l| l.trim() == "DISZ INFINITY")
        .unwrap()
        + 1;
    check_n(
        &t,
        n,
        &["DISZ INFINITY is only allowed on the object surface"],
    );
    let t = replace_line(&base, "PARM 2 -2.5E-6", "  PARM 2 1e999");
    check(&t, "PARM 2 1e999", &["PARM 2"]);
    let t = replace_line(&base, "MODE SEQ", "MODE NSC");
    check(&t, "MODE NSC", &["sequential"]);
    let t = replace_line(&base, "UNIT MM", "UNIT FEET");
    check(&t, "UNIT FEET", &["UNIT FEET"]);
    let t = replace_line(&base, "PWAV 2", "PWAV 7");
    check(&t, "PWAV 7", &["the file has 3 wavelengths"]);
    let t = replace_line(&base, "WAVM 2", "WAVM 2 587.56 1");
    check(&t, "WAVM 2", &["micrometres"]);
    // Below 20 µm a glass is taken beyond its range, but not where its formula has no index
    // (N-BK7's Sellmeier at 8.5 µm: n² < 0; a fuzzed file loaded with NaN indices).
    let t = replace_line(&base, "WAVM 2", "WAVM 2 8.4861327 1");
    check(
        &t,
        "WAVM 2",
        &["wavelength 8.4861327 µm", "N-BK7", "has index NaN"],
    );
    let t = replace_line(&base, "DIAM 3 0", "  DIAM -2");
    check(&t, "DIAM -2", &["the image semi-diameter (DIAM) -2 mm"]);
    // Hard apertures that are not apertures, or two on one surface.
    let t = replace_line(&base, "FLAP 0 7 0", "  CLAP 5 3 0");
    check(
        &t,
        "CLAP 5 3 0",
        &["CLAP: hard aperture: annulus 5 to 3 mm"],
    );
    let t = replace_line(&base, "FLAP 0 7 0", "  SQAP 0 3 0");
    check(
        &t,
        "SQAP 0 3 0",
        &["SQAP: hard aperture: half-widths 0 x 3 mm"],
    );
    let t = replace_line(&base, "FLAP 0 7 0", "  FLAP 0 7 0\n  OBSC 0 1 0");
    check(
        &t,
        "OBSC 0 1 0",
        &["a second surface aperture (OBSC; the first, FLAP"],
    );
    let t = replace_line(&base, "FLAP 0 7 0", "  OBDC 0 1");
    check(
        &t,
        "OBDC 0 1",
        &["OBDC (aperture decenter) on a surface without an aperture"],
    );
    // A floating stop needs its size.
    let t = replace_line(&base, "ENPD 10", "FLOA");
    let t = replace_line(&t, "DIAM 5 1 0 0 1", "  COMM no size").replace("  FLAP 0 5 0\n", "");
    check(
        &t,
        "SURF 1",
        &["is the stop and the aperture floats by stop size"],
    );
    let t = replace_line(&base, "CURV 0.05", "  CURV 0.3");
    check(&t, "DIAM 7 0 0 0 1", &["exceeds the surface's rim"]);
    let t = replace_line(&base, "DISZ 4", "  DISZ -40");
    check(
        &t,
        "SURF 3",
        &["SURF 3 lies 40 mm before the previous surface"],
    );
    let t = replace_line(&base, "VERS", "CURV 1");
    check(&t, "CURV 1", &["CURV outside a SURF block"]);
    let t = replace_line(&base, "GLAS N-BK7", "  STOP");
    let n = t
        .lines()
        .collect::<Vec<_>>()
        .iter()
        .rposition(|l| l.trim() == "STOP")
        .unwrap()
        + 1;
    check_n(&t, n, &["a second STOP (the first is at line"]);
    // Coordinate breaks that tolray cannot represent.
    let cb = |parms: &str| {
        base.replace(
            "SURF 2\n",
            &format!("SURF 2\n  TYPE COORDBRK\n{parms}\nSURF 3\n"),
        )
        .replace("SURF 3\n  TYPE STANDARD", "SURF 4\n  TYPE STANDARD")
        .replace(
            "SURF 4\n  TYPE STANDARD\n  CURV 0\n  DISZ 0",
            "SURF 5\n  TYPE STANDARD\n  CURV 0\n  DISZ 0",
        )
    };
    // A small tilt before a lens surface and the image is fine now (the image plane keeps it);
    // one that turns the image plane past 90 degrees is not.
    parse(&cb("  PARM 3 1.5")).unwrap();
    let t = base.replace(
        "SURF 4\n",
        "SURF 4\n  TYPE COORDBRK\n  PARM 3 95\n  DISZ 0\nSURF 5\n",
    );
    check(
        &t,
        "TYPE COORDBRK",
        &["the image plane is turned by 90 degrees or more"],
    );
    let t = cb("  PARM 4 95");
    check(&t, "SURF 3", &["turned by 90 degrees or more"]);
    let t = cb("  STOP\n  PARM 2 0.5");
    check_n(
        &t,
        line_of(&t, "TYPE COORDBRK") + 1,
        &["a coordinate break cannot be the stop"],
    );
    let t = cb("  PARM 1 1.7e308\n  PARM 4 45\n  DISZ 1e308");
    check(&t, "TYPE COORDBRK", &["to infinity"]);
    // Whole-file problems.
    assert!(err("SURF 0\n DISZ INFINITY\nSURF 1\n").contains("a lens needs the object"));
    let e =
        zemax::read_file(Path::new("/no/such/file.zmx"), &GlassCatalogs::builtin()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Io);
    let dir = std::env::temp_dir().join(format!("tolray-zmx-err-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("broken.zmx");
    std::fs::write(&p, replace_line(&base, "CURV 0.05", "  CURV x")).unwrap();
    let e = Lens::load(p.to_str().unwrap()).unwrap_err();
    let n = line_of(&base, "CURV 0.05");
    assert!(
        e.message()
            .starts_with(&format!("{}: line {n}: CURV", p.display())),
        "{}",
        e.message()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn skipped_and_approximated_input_gives_warnings_that_name_the_line() {
    let base = text("asphere.zmx");
    let warn = |t: &str, start: &str, want: &str| {
        let z = parse(t).unwrap_or_else(|e| panic!("{start}: {e}"));
        let n = line_of(t, start);
        assert!(
            z.warnings
                .iter()
                .any(|w| w.starts_with(&format!("line {n}: ")) && w.contains(want)),
            "{start}: {:?}",
            z.warnings
        );
        z
    };
    let t = base.replace("GCAT SCHOTT\n", "GCAT SCHOTT\nFOOB 1 2 3\n");
    warn(
        &t,
        "FOOB",
        "1 unknown command skipped (tolray does not read them): FOOB (line",
    );
    // Unknown commands are one warning, however many there are.
    let t = base.replace("GCAT SCHOTT\n", "GCAT SCHOTT\nFOOB 1\nBARB 2\nFOOB 3\n");
    let z = warn(&t, "FOOB", "3 unknown commands skipped");
    assert_eq!(
        z.warnings
            .iter()
            .filter(|w| w.contains("unknown command"))
            .count(),
        1
    );
    let n = line_of(&t, "BARB");
    assert!(
        z.warnings
            .iter()
            .any(|w| w.contains(&format!("BARB (line {n})"))),
        "{:?}",
        z.warnings
    );
    let t = base.replace("  DISZ 4\n", "  DISZ 4\n  SPID 0 4 0\n");
    warn(&t, "SPID", "SPID (spider obscuration) ignored");
    // No semi-diameter (a surface, or the image): sized to the paraxial beam, never clipping.
    let t = replace_line(&base, "DIAM 3 0", "  COMM no image size");
    let t = replace_line(&t, "DIAM 7 0 0 0 1", "  COMM no size").replacen("  FLAP 0 7 0\n", "", 1);
    let z = warn(
        &t,
        "SURF 2",
        "no semi-diameter (DIAM) given; sized to the paraxial beam",
    );
    assert_eq!(z.lens.surfaces[1].aperture, None);
    assert!(z.lens.surfaces[1].semi_aperture_mm > 5.0 && z.lens.surfaces[1].semi_aperture_mm < 7.0);
    assert!(z
        .warnings
        .iter()
        .any(|w| w.contains("sensor half-diagonal")));
    // The image half-diagonal: the 5° chief ray's paraxial image height (EFL x tan 5°).
    let p = z.lens.paraxial(z.lens.primary_wavelength_nm).unwrap();
    let want = p.efl_mm.unwrap() * 5f64.to_radians().tan();
    assert!(
        rel(z.lens.sensor.half_diagonal_mm(), want) < 0.05,
        "{} vs {want}",
        z.lens.sensor.half_diagonal_mm()
    );
    let t = base.replace("  DISZ 4\n", "  DISZ 4\n  RAIM 0 1 1 1 0 0 0 0 0\n");
    let z = warn(&t, "RAIM", "paraxial ray aiming is done as real ray aiming");
    assert!(z.lens.ray_aiming);
    let t = replace_line(
        &base,
        "CURV -0.0083",
        "  CURV -0.008333333333333333\n  PARM 1 0.001",
    );
    warn(&t, "PARM 1 0.001", "a STANDARD surface has no parameters");
    let t = replace_line(&base, "TYPE STANDARD", "  TYPE TILTSURF");
    warn(&t, "TYPE TILTSURF", "object surface type TILTSURF ignored");
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS BK7");
    let z = warn(&t, "GLAS BK7", "using N-BK7");
    assert_eq!(
        z.lens.surfaces[1].material,
        Material::parse("N-BK7").unwrap()
    );
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS N-BK7 0 0 1.6 40");
    warn(&t, "GLAS N-BK7", "the file says n_d = 1.6");
    let t = replace_line(&base, "STOP", "  COMM no stop line");
    let z = warn(&t, "SURF 1", "no STOP line");
    assert_eq!(z.lens.stop_index(), Some(0));
    // Vignetting factors of fields tolray has no type for (OpticStudio's theodolite angles):
    // not applied, said once.
    let t = base
        .replace("FTYP 0 0 3", "FTYP 4 0 3")
        .replace("FWGN 1 1 1\n", "FWGN 1 1 1\nVDYN 0 0.1 0.2\n");
    let z = warn(
        &t,
        "VDYN",
        "vignetting factors not applied: tolray has no field of this file's type (FTYP 4)",
    );
    assert!(z.lens.fields.is_empty());
    // Image heights are fields of the lens, with their factors.
    let z = parse(&t.replace("FTYP 4 0 3", "FTYP 2 0 3")).unwrap();
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    let kinds: Vec<bool> = z
        .lens
        .fields
        .iter()
        .map(|p| matches!(p.field, Field::ImageHeightMm { .. }))
        .collect();
    assert_eq!(kinds, [true; 3]);
    assert_eq!(z.lens.fields[2].vignetting.decenter_y, 0.2);
    let t = base.replace("WAVM 1 0.4861327 1", "WAVM 1 0.25 1");
    warn(
        &t,
        "GLAS N-BK7",
        "glass N-BK7 is defined from 0.3 to 2.5 µm; 0.25 µm outside",
    );
    // A decentred and tilted image plane is kept (no warning): the same lens with that pose.
    let t = base.replace(
        "SURF 4\n",
        "SURF 4\n  TYPE COORDBRK\n  PARM 1 0.2\n  PARM 3 1.5\n  DISZ 0\nSURF 5\n",
    );
    let z = parse(&t).unwrap();
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    let mut want = read("asphere.zmx").lens;
    let a = 1.5f64.to_radians();
    want.image_plane = tolray::lens::ImagePlane {
        decenter_mm: [0.2, 0.0],
        normal: [0.0, -a.sin(), a.cos()],
        roll_deg: 0.0,
        ..Default::default()
    };
    assert_eq!(z.lens.surfaces, want.surfaces);
    let ip = z.lens.image_plane;
    assert_eq!(ip.decenter_mm, [0.2, 0.0]);
    assert!(ip.roll_deg.abs() < 1e-12, "{ip:?}");
    for k in 0..3 {
        assert!(
            (ip.normal[k] - want.image_plane.normal[k]).abs() < 1e-15,
            "{ip:?}"
        );
    }
    // The clean fixtures give no warnings at all.
    for (f, _) in FIXTURES {
        assert!(read(f).warnings.is_empty(), "{f}");
    }
}
