//! AGF catalogs and glass resolution: user catalogs first, GCAT order, no silent substitute.

use super::*;

#[test]
fn agf_catalogs_read_and_agree_with_the_builtin_glasses() {
    let (cat, warnings) = AgfCatalog::read_file(&fixture("test-catalog.agf")).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(cat.name, "TEST-CATALOG");
    assert_eq!(cat.glasses.len(), 6);
    for (agf_name, builtin) in [
        ("N-BK7", "N-BK7"),
        ("F2", "F2"),
        ("H-ZK9A", "H-ZK9A"),
        ("J-BK7A", "J-BK7A"),
        ("NBK7-S5", "N-BK7"),
        ("F2-S3", "F2"),
    ] {
        let g = cat.find(agf_name).unwrap();
        let b = Material::parse(builtin).unwrap();
        let lo = g.range_um.0.max(0.37);
        for k in 0..=10 {
            let nm = 1e3 * (lo + (1.0 - lo) * k as f64 / 10.0);
            let (x, y) = (g.index(nm), b.index(nm));
            assert!((x - y).abs() <= 1e-15, "{agf_name} at {nm} nm: {x} vs {y}");
        }
        let nd = g.index(LAMBDA_D_NM);
        let vd = (nd - 1.0) / (g.index(LAMBDA_F_NM) - g.index(LAMBDA_C_NM));
        assert!(
            (nd - g.nd).abs() < 5e-5 && (vd - g.vd).abs() < 0.1,
            "{agf_name}"
        );
    }
    assert_eq!(cat.find("n-bk7").unwrap().range_um, (0.3, 2.5));
    // The same catalog saved as UTF-16, as OpticStudio writes catalogs.
    let bytes: Vec<u8> = [0xFF, 0xFE]
        .into_iter()
        .chain(
            text("test-catalog.agf")
                .encode_utf16()
                .flat_map(u16::to_le_bytes),
        )
        .collect();
    assert_eq!(
        AgfCatalog::from_bytes(&bytes, "TEST-CATALOG").unwrap().0,
        cat
    );
}

#[test]
fn user_catalogs_are_searched_before_the_builtin_glasses() {
    let (catalogs, _) = GlassCatalogs::from_files(&[fixture("test-catalog.agf")]).unwrap();
    let t = text("asphere.zmx").replace("GLAS N-BK7 0 0 1.5168 64.17", "GLAS NBK7-S5");
    let e = parse(&t).unwrap_err();
    assert!(
        e.message().contains("unknown glass \"NBK7-S5\""),
        "{}",
        e.message()
    );
    let z = zemax::from_str(&t, &catalogs).unwrap();
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    assert!(matches!(&z.lens.surfaces[1].material, Material::Agf(g) if g.name == "NBK7-S5"));
    // Same indices as the built-in N-BK7, so the same paraxial data and spots.
    let builtin = read("asphere.zmx").lens;
    assert_paraxial_equal(&z.lens, &builtin, "NBK7-S5");
    // N-BK7 itself now comes from the user's catalog.
    let z = zemax::from_str(&text("asphere.zmx"), &catalogs).unwrap();
    assert!(
        matches!(&z.lens.surfaces[1].material, Material::Agf(g) if g.catalog == "TEST-CATALOG")
    );
    // Round trips keep the user glass: .zmx and JSON.
    let back = zemax::from_str(&zemax::to_string(&z.lens, Some(&z.extras)), &catalogs).unwrap();
    assert_eq!(back.lens, z.lens);
    assert!(zemax::to_string(&z.lens, None).contains("GCAT TEST-CATALOG"));
    assert_eq!(
        json::from_str_with(&json::to_string(&z.lens), &catalogs).unwrap(),
        z.lens
    );
    // JSON lenses can use user glasses too, and Lens::warnings flags wavelengths outside the
    // catalog's range.
    let mut v: serde_json::Value = serde_json::from_str(&text("asphere.json")).unwrap();
    v["surfaces"][1]["mat2"] = "h-zk9a".into();
    let mut l = json::from_value_with(&v, &catalogs).unwrap();
    assert!(l.warnings().is_empty(), "{:?}", l.warnings());
    l.rgb_wavelengths_nm[0] = 1064.0;
    let w = l.warnings();
    assert!(
        w.len() == 1
            && w[0].contains("surface 1: glass H-ZK9A is defined from 0.365 to 1.014 µm; 1064 nm"),
        "{w:?}"
    );
    let (l2, w) =
        Lens::load_with_catalogs(fixture("asphere.zmx").to_str().unwrap(), &catalogs).unwrap();
    assert!(w.is_empty() && matches!(l2.surfaces[1].material, Material::Agf(_)));
    // Catalog errors name the file and the line.
    let dir = std::env::temp_dir().join(format!("tolray-agf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("bad.agf");
    std::fs::write(
        &p,
        text("test-catalog.agf").replace("NM F2 2 ", "NM F2 21 "),
    )
    .unwrap();
    let e = GlassCatalogs::from_files(&[&p]).unwrap_err();
    assert!(
        e.message().starts_with(&format!(
            "{}: line 13: glass F2: unknown dispersion formula 21",
            p.display()
        )),
        "{}",
        e.message()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Glass names resolve in the built-in vendor catalogs in the file's GCAT order; a glass in no
/// catalog is an error naming the line, the glass and the fallback, unless the user opts into
/// the line's n_d / V_d; OpticStudio's 1.5 / 40 placeholder is never data.
#[test]
fn glasses_resolve_by_gcat_and_never_silently_fall_back() {
    let base = text("asphere.zmx");
    let material = |z: &ZmxLens| z.lens.surfaces[1].material.clone();
    let vendor = |m: &Material| match m {
        Material::Catalog(g) => g.vendor,
        other => panic!("not a catalog glass: {other:?}"),
    };
    // Ohara's S-LAH64 (not in the catalog before this release): the catalog glass, no warning
    // about it, and its catalog n_d.
    let t = replace_line(
        &base,
        "GLAS N-BK7",
        "  GLAS S-LAH64 0 0 1.788 47.37 0 0 0 0 0 0",
    );
    let z = parse(&t).unwrap();
    let m = material(&z);
    assert_eq!(vendor(&m), "Ohara");
    assert!((m.index(LAMBDA_D_NM) - 1.788001).abs() < 2e-6);
    assert!(
        !z.warnings.iter().any(|w| w.contains("S-LAH64")),
        "{:?}",
        z.warnings
    );
    // BAF10 is both Hoya's and Hikari's: GCAT decides; without GCAT, the default vendor order.
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS BAF10");
    assert_eq!(vendor(&material(&parse(&t).unwrap())), "Hoya");
    let hikari = t.replace("GCAT SCHOTT\n", "GCAT NIKON-HIKARI SCHOTT\n");
    let (a, b) = (
        material(&parse(&t).unwrap()),
        material(&parse(&hikari).unwrap()),
    );
    assert_eq!(vendor(&b), "Hikari");
    assert!(
        (a.index(LAMBDA_D_NM) - b.index(LAMBDA_D_NM)).abs() > 1e-7
            || (a.index(LAMBDA_F_NM) - b.index(LAMBDA_F_NM)).abs() > 1e-7,
        "two vendors' BAF10 differ"
    );
    // A glass in no catalog: refused, naming the line and the way out.
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS NOT-A-GLASS 0 0 1.52 64 0 0 0");
    let n = line_of(&t, "GLAS NOT-A-GLASS");
    let e = err(&t);
    for want in [
        format!("line {n}"),
        "unknown glass \"NOT-A-GLASS\"".to_string(),
        "--glass-catalog".to_string(),
        "--glass-fallback file-values".to_string(),
        "n_d = 1.52, V_d = 64".to_string(),
    ] {
        assert!(e.contains(&want), "missing {want:?} in: {e}");
    }
    // Suggestions come from the vendor the name belongs to.
    let t2 = replace_line(&base, "GLAS N-BK7", "  GLAS S-LAH99");
    let e = err(&t2);
    assert!(e.contains("(Ohara)") && !e.contains("(Schott)"), "{e}");
    // A variant suffix (a moulded glass, as Ohara's S-BSL7_MOLD) names its base glass first.
    let t2 = replace_line(&base, "GLAS N-BK7", "  GLAS S-BSL7_MOLD");
    let e = err(&t2);
    assert!(e.contains("(closest: S-BSL7 (Ohara)"), "{e}");
    // A legacy Schott glass names its lead-free successors first.
    let e = err(&replace_line(&base, "GLAS N-BK7", "  GLAS BAK1"));
    assert!(e.contains("(closest: N-BAK1 (Schott)"), "{e}");
    let e = err(&replace_line(&base, "GLAS N-BK7", "  GLAS LAK33"));
    assert!(
        e.contains("(closest: N-LAK33A (Schott), N-LAK33B (Schott)"),
        "{e}"
    );
    // Opted in: the line's values as a model glass, with a warning on that line.
    let fallback = GlassCatalogs {
        file_values_fallback: true,
        ..GlassCatalogs::builtin()
    };
    let z = zemax::from_str(&t, &fallback).unwrap();
    assert_eq!(material(&z), Material::Model { nd: 1.52, vd: 64.0 });
    assert!(
        z.warnings
            .iter()
            .any(|w| w.starts_with(&format!("line {n}: ")) && w.contains("--glass-fallback")),
        "{:?}",
        z.warnings
    );
    // The placeholder is refused even then.
    let t = replace_line(&base, "GLAS N-BK7", "  GLAS NOT-A-GLASS 0 0 1.5 40 0 0 0");
    let e = zemax::from_str(&t, &fallback)
        .unwrap_err()
        .message()
        .to_string();
    assert!(
        e.contains("placeholder") && e.contains(&format!("line {n}")),
        "{e}"
    );
}

/// The catalogs read from AGF files (INFRARED, MISC, LightPath, RPO, Hoya's legacy names):
/// `GCAT` names them, their materials agree with independent measurements to within the spread
/// between sources, and a germanium singlet at 10 µm has its closed-form focal length.
/// Independent values: refractiveindex.info (CC0), H. H. Li, J. Phys. Chem. Ref. Data 9, 561
/// (1980), germanium at 293 K (`main/Ge/nk/Li-293K.yml`); M. Daimon and A. Masumura, Appl. Opt.
/// 46, 3811 (2007), distilled water at 20 °C (`main/H2O/nk/Daimon-20.0C.yml`, Sellmeier terms).
#[test]
fn infrared_misc_and_moulded_glass_catalogs_open_files_that_name_them() {
    let find = |name: &str, vendor: &str| {
        tolray::lens::material::catalog()
            .iter()
            .find(|g| g.name == name && g.vendor == vendor)
            .unwrap_or_else(|| panic!("{name} ({vendor}) not built in"))
    };
    // Germanium: Zemax's INFRARED fit against Li's 293 K table (the two differ by up to 1.9e-3,
    // the spread between germanium measurements; a wrong formula mapping would be off by >0.1).
    let ge = Material::Catalog(find("GERMANIUM", "Infrared"));
    for (um, li) in [
        (4.0, 4.0242),
        (5.0, 4.0149),
        (8.0, 4.0048),
        (10.0, 4.0025),
        (12.0, 4.0012),
    ] {
        let n = ge.index(um * 1e3);
        assert!(
            (n - li).abs() < 2.5e-3,
            "germanium at {um} µm: {n} vs Li {li}"
        );
    }
    // Water: MISC's fit (Handbook of Optics) against Daimon and Masumura at 20 °C: the fit sits
    // 3.6e-4 lower across the visible (the index water loses in about 4 K), with the same
    // dispersion to 1e-5.
    let water = Material::Catalog(find("WATER", "Misc"));
    let daimon = |um: f64| {
        let l2 = um * um;
        let (b, c) = (
            [
                5.684027565e-1,
                1.726177391e-1,
                2.086189578e-2,
                1.130748688e-1,
            ],
            [
                5.101829712e-3,
                1.821153936e-2,
                2.620722293e-2,
                1.069792721e1,
            ],
        );
        (1.0 + (0..4).map(|i| b[i] * l2 / (l2 - c[i])).sum::<f64>()).sqrt()
    };
    for um in [0.45, LAMBDA_D_NM * 1e-3, 0.65] {
        let (n, d) = (water.index(um * 1e3), daimon(um));
        assert!(
            (n - d + 3.6e-4).abs() < 2e-5,
            "water at {um} µm: {n} vs Daimon {d}"
        );
    }
    let fc = water.index(LAMBDA_F_NM) - water.index(LAMBDA_C_NM);
    let fc_daimon = daimon(LAMBDA_F_NM * 1e-3) - daimon(LAMBDA_C_NM * 1e-3);
    assert!(
        (fc - fc_daimon).abs() < 2e-5,
        "water n_F - n_C {fc} vs {fc_daimon}"
    );
    // Every moulded and legacy glass reproduces its catalog n_d (the unit test checks them all;
    // these are the ones real files in tests/data/zemax/real name).
    for (name, vendor) in [
        ("D-ZK3M", "LightPath"),
        ("L-TIM28_MOLD", "RPO"),
        ("FD10", "Hoya"),
    ] {
        let g = find(name, vendor);
        let nd = Material::Catalog(g).index(LAMBDA_D_NM);
        assert!((nd - g.nd).abs() < 5e-5, "{name}: {nd} vs {}", g.nd);
    }
    // A germanium singlet (R1 50, R2 70 mm, 6 mm thick) at 10 µm, GCAT INFRARED: thick-lens EFL.
    let zmx = "VERS 190513 80 0\nMODE SEQ\nNAME germanium singlet\nUNIT MM X W X CM MR CPMM\n\
        ENPD 10\nGCAT INFRARED\nFTYP 0 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nFWGN 1\nWAVM 1 10 1\nPWAV 1\n\
        SURF 0\n  CURV 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  CURV 0.02\n  DISZ 6\n  GLAS GERMANIUM\n\
        SURF 2\n  CURV 0.0142857142857142857\n  DISZ 100\nSURF 3\n  CURV 0\n  DISZ 0\n";
    let z = zemax::from_str(zmx, &GlassCatalogs::builtin()).unwrap();
    assert!(
        z.warnings.iter().all(|w| !w.contains("glass")),
        "{:?}",
        z.warnings
    );
    assert_eq!(
        z.lens.surfaces[0].material.catalog_name(),
        Some("GERMANIUM")
    );
    let n = ge.index(10_000.0);
    let (c1, c2, t) = (0.02, 1.0 / 70.0, 6.0);
    let want = 1.0 / ((n - 1.0) * (c1 - c2 + (n - 1.0) * t * c1 * c2 / n));
    let efl = z.lens.paraxial(10_000.0).unwrap().efl_mm.unwrap();
    assert!(rel(efl, want) < 1e-12, "EFL {efl} vs {want}");
    // The .zmx writer names the catalog, and the file reads back as the same glass.
    let written = zemax::to_string(&z.lens, None);
    assert!(written.contains("GCAT INFRARED"), "{written}");
    let back = zemax::from_str(&written, &GlassCatalogs::builtin()).unwrap();
    assert_eq!(back.lens.surfaces[0].material, z.lens.surfaces[0].material);
}
