//! Reading a .zmx file: its lines into raw surfaces and the header, glasses resolved by the file's catalogs.

use super::*;

/// Commands that change nothing tolray models: skipped without a warning.
pub(super) const SILENT: &[&str] = &[
    "VERS", "PFIL", "LANG", "ENVD", "GFAC", "PUSH", "SDMA", "ROPD", "PICB", "POLS", "GLRS", "GSTD",
    "NSCD", "COFN", "BLNK", "TOL", "TOLE", "MOFF", "CONF", "OPDX", "EFFL", "PUPD", "TCED", "DMFS",
    "ISNA", "ZVDX", "ZVDY", "ZVCX", "ZVCY", "ZVAN", "WWGN", "WAVN", "MNCA", "MNEA", "MNCG", "MNEG",
    "MXCA", "MXCG", "RGLA", "TRAC", "TCMM", "PMAG", "TOTR", "FIMP", "SCOL", "UDAD", "USAP", "EDGE",
    "OMMA", "HIDE", "MIRR", "SLAB", "POPS", "COMM", "MAZH", "PZUP", "PPAR", "VPAR", "VCON", "VDSZ",
    "COAT", "TCE", "PKUP", "SCTH", "CLAT", "BLAT",
];

/// The vignetting-factor commands, in the order of `Header::vign`.
pub(super) const VIGNETTING: [&str; 5] = ["VDXN", "VDYN", "VCXN", "VCYN", "VANN"];

/// Hard-aperture commands of a surface: clear and obscuring circles, rectangles and ellipses,
/// and the floating aperture (a circle of the semi-diameter).
pub(super) const APERTURES: &[&str] = &["CLAP", "OBSC", "SQAP", "OBSQ", "ELAP", "OBEL", "FLAP"];

/// Parses .zmx text, looking glass names up in `catalogs`.
///
/// # Errors
/// [`ErrorKind::Parse`] naming the line for malformed lines (a bad number, a truncated `GLAS`,
/// `SURF` blocks out of order); [`ErrorKind::Invalid`] naming the line for what tolray cannot
/// model (an unsupported surface type, a mirror, a tilted image plane, an unknown glass) or an
/// invalid prescription.
#[allow(clippy::should_implement_trait)]
pub fn from_str(text: &str, catalogs: &GlassCatalogs) -> Result<ZmxLens> {
    let mut h = Header::default();
    let mut surfs: Vec<RawSurf> = Vec::new();
    let mut warnings = Vec::new();
    // Commands tolray does not know, reported together in one warning (they are many in files
    // of newer OpticStudio versions, and would bury the warnings that change numbers).
    let mut unknown: Vec<(usize, String)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let trimmed = raw.trim();
        let toks: Vec<&str> = trimmed.split_whitespace().collect();
        let Some(first) = toks.first() else { continue };
        let cmd = first.to_ascii_uppercase();
        let args = &toks[1..];
        // The text after the command, for NAME and NOTE.
        let rest = trimmed.get(first.len()..).unwrap_or("").trim();
        let surf = surfs.last_mut();
        let need_surf = |s| in_surf(s, line, &cmd);
        match cmd.as_str() {
            "SURF" => {
                let n = args
                    .first()
                    .and_then(|t| t.parse::<usize>().ok())
                    .ok_or_else(|| parse_err(line, "SURF needs a surface number"))?;
                if n != surfs.len() {
                    return Err(parse_err(
                        line,
                        format!("SURF {n} is out of order (expected SURF {})", surfs.len()),
                    ));
                }
                surfs.push(RawSurf {
                    line,
                    ..RawSurf::default()
                });
            }
            "TYPE" => {
                let s = need_surf(surf)?;
                let t = args
                    .first()
                    .ok_or_else(|| parse_err(line, "TYPE needs a surface type"))?;
                s.ty = at(t.to_ascii_uppercase(), line);
            }
            "CURV" => need_surf(surf)?.curv = at(number(args.first(), line, "CURV")?, line),
            "CONI" => need_surf(surf)?.coni = at(number(args.first(), line, "CONI")?, line),
            "PARM" => {
                let s = need_surf(surf)?;
                let k = args
                    .first()
                    .and_then(|t| t.parse::<usize>().ok())
                    .ok_or_else(|| parse_err(line, "PARM needs a parameter number"))?;
                let v = number(args.get(1), line, &format!("PARM {k}"))?;
                s.parm.push((k, v, line));
            }
            "DISZ" => {
                let s = need_surf(surf)?;
                let v = match args.first() {
                    Some(t) if t.eq_ignore_ascii_case("INFINITY") => None,
                    t => Some(number(t, line, "DISZ")?),
                };
                s.disz = at(v, line);
            }
            "DIAM" => {
                let s = need_surf(surf)?;
                let v = number(args.first(), line, "DIAM")?;
                s.diam = at((v, args.get(1) == Some(&"1")), line);
            }
            "MEMA" => need_surf(surf)?.mema = at(number(args.first(), line, "MEMA")?, line),
            "STOP" => need_surf(surf)?.stop = Some(line),
            "GLAS" => {
                let s = need_surf(surf)?;
                if args.is_empty() {
                    return Err(parse_err(line, "GLAS needs a glass name"));
                }
                s.glas = at(args.iter().map(|t| t.to_string()).collect(), line);
            }
            "MODE" => {
                let m = args.first().copied().unwrap_or("");
                if !m.eq_ignore_ascii_case("SEQ") {
                    return Err(invalid(
                        line,
                        format!("MODE {m}: tolray reads sequential files (MODE SEQ) only"),
                    ));
                }
            }
            "UNIT" => {
                let u = args.first().copied().unwrap_or("");
                let scale = match u.to_ascii_uppercase().as_str() {
                    "MM" => 1.0,
                    "CM" => 10.0,
                    "IN" | "INCH" => 25.4,
                    "METER" | "M" => 1000.0,
                    _ => {
                        return Err(invalid(
                            line,
                            format!("UNIT {u}: tolray reads MM, CM, IN and METER"),
                        ))
                    }
                };
                h.unit = at(scale, line);
            }
            "NAME" => h.name = rest.trim_matches('"').trim().to_string(),
            "NOTE" => h.notes.push(At {
                v: rest.to_string(),
                line,
            }),
            "ENPD" => {
                let v = number(args.first(), line, "ENPD")?;
                h.aperture = at(ZmxAperture::EntrancePupilDiameter(v), line);
            }
            "FNUM" => {
                let v = number(args.first(), line, "FNUM")?;
                h.aperture = at(ZmxAperture::ImageSpaceFnum(v), line);
            }
            "OBNA" => {
                let v = number(args.first(), line, "OBNA")?;
                h.aperture = at(ZmxAperture::ObjectSpaceNa(v), line);
            }
            "FLOA" => h.aperture = at(ZmxAperture::FloatByStop, line),
            "FTYP" => h.ftyp = at(numbers(args, line, "FTYP")?, line),
            "XFLN" | "XFLD" => h.xfln = Some(numbers(args, line, &cmd)?),
            "YFLN" | "YFLD" => h.yfln = at(numbers(args, line, &cmd)?, line),
            "FWGN" | "FWGT" => h.fwgn = Some(numbers(args, line, &cmd)?),
            "VDXN" | "VDYN" | "VCXN" | "VCYN" | "VANN" => {
                let k = VIGNETTING.iter().position(|c| *c == cmd).unwrap_or(0);
                h.vign[k] = at(numbers(args, line, &cmd)?, line);
            }
            "WAVM" => {
                let k = args
                    .first()
                    .and_then(|t| t.parse::<usize>().ok())
                    .ok_or_else(|| parse_err(line, "WAVM needs a wavelength number"))?;
                let w = number(args.get(1), line, &format!("WAVM {k}"))?;
                let wt = match args.get(2) {
                    Some(t) => number(Some(t), line, &format!("WAVM {k} weight"))?,
                    None => 1.0,
                };
                h.wavm.push((k, w, wt, line));
            }
            "WAVL" => h.wavl = at(numbers(args, line, "WAVL")?, line),
            "WWGT" => h.wwgt = Some(numbers(args, line, "WWGT")?),
            "PWAV" => {
                let k = args
                    .first()
                    .and_then(|t| t.parse::<usize>().ok())
                    .ok_or_else(|| parse_err(line, "PWAV needs a wavelength number"))?;
                h.pwav = at(k, line);
            }
            "GCAT" => h.gcat = args.iter().map(|t| t.to_string()).collect(),
            "RAIM" => {
                // RAIM's second number is the ray aiming type: 0 off, 1 paraxial, 2 real.
                let v = numbers(args, line, "RAIM")?;
                let ty = v.get(1).copied().unwrap_or(0.0);
                if ty == 1.0 {
                    warnings.push(format!(
                        "line {line}: paraxial ray aiming is done as real ray aiming (tolray aims real rays at the stop)"
                    ));
                }
                h.raim = at(ty as i64, line);
            }
            "MNUM" => {
                if args.first().and_then(|t| t.parse::<f64>().ok()).unwrap_or(1.0) > 1.0 {
                    warnings.push(format!(
                        "line {line}: multi-configuration data ignored; the lens data as written (the current configuration) is read"
                    ));
                }
            }
            "XDAT" if surf.is_some() => {
                let s = need_surf(surf)?;
                let k = args.first().and_then(|t| t.parse::<usize>().ok());
                let v = args.get(1).and_then(|t| t.parse::<f64>().ok());
                if let (Some(k), Some(v)) = (k, v) {
                    s.xdat.push((k, v, line));
                }
            }
            "XDAT" | "YDAT" => {
                if args.get(1).and_then(|t| t.parse::<f64>().ok()).unwrap_or(0.0) != 0.0 {
                    warnings.push(format!("line {line}: {cmd} (extra surface data) ignored"));
                }
            }
            c if APERTURES.contains(&c) => {
                let s = need_surf(surf)?;
                let v = numbers(args, line, c)?;
                if let Some(prev) = &s.aperture {
                    return Err(invalid(
                        line,
                        format!(
                            "a second surface aperture ({c}; the first, {}, is at line {}): OpticStudio keeps one per surface",
                            prev.v.0, prev.line
                        ),
                    ));
                }
                s.aperture = at((c.to_string(), v), line);
            }
            "OBDC" => {
                let s = need_surf(surf)?;
                let v = numbers(args, line, "OBDC")?;
                s.aperture_decenter = at([v.first().copied().unwrap_or(0.0), v.get(1).copied().unwrap_or(0.0)], line);
            }
            "SPID" => warnings.push(format!(
                "line {line}: SPID (spider obscuration) ignored: tolray traces circular, rectangular and elliptical apertures and obscurations only"
            )),
            c if SILENT.contains(&c) => {}
            c => unknown.push((line, c.to_string())),
        }
    }
    if let Some(&(first, _)) = unknown.first() {
        let list: Vec<String> = unknown
            .iter()
            .map(|(l, c)| format!("{c} (line {l})"))
            .collect();
        warnings.push(format!(
            "line {first}: {} unknown command{} skipped (tolray does not read them): {}",
            unknown.len(),
            if unknown.len() == 1 { "" } else { "s" },
            list.join(", ")
        ));
    }
    build(h, surfs, catalogs, warnings)
}

pub(super) fn in_surf<'a>(
    s: Option<&'a mut RawSurf>,
    line: usize,
    cmd: &str,
) -> Result<&'a mut RawSurf> {
    s.ok_or_else(|| parse_err(line, format!("{cmd} outside a SURF block")))
}

/// The medium given by a `GLAS` line.
pub(super) fn glass(
    args: &[String],
    line: usize,
    catalogs: &GlassCatalogs,
    warnings: &mut Vec<String>,
) -> Result<Material> {
    let name = args
        .first()
        .ok_or_else(|| parse_err(line, "GLAS needs a glass name"))?;
    let upper = name.to_ascii_uppercase();
    let num = |k: usize| args.get(k).and_then(|t| t.parse::<f64>().ok());
    if upper == "MIRROR" {
        // Lens surfaces read MIRROR themselves (Walker::surface); the object cannot be one.
        return Err(invalid(
            line,
            "GLAS MIRROR: the object surface cannot be a mirror",
        ));
    }
    if upper == "___BLANK" {
        let arg = |k| args.get(k).map(String::as_str);
        if arg(3).is_none() || arg(4).is_none() {
            return Err(parse_err(
                line,
                "a model glass needs n_d and V_d: GLAS ___BLANK 1 0 n_d V_d ...",
            ));
        }
        let nd = number(arg(3).as_ref(), line, "GLAS ___BLANK n_d")?;
        let vd = number(arg(4).as_ref(), line, "GLAS ___BLANK V_d")?;
        // Zemax treats V_d = 0 as a dispersion-free medium (Material::model does too).
        return Material::model(nd, vd).map_err(|e| e.context(format!("line {line}")));
    }
    if name.len() == 6 && name.bytes().all(|b| b.is_ascii_digit()) {
        // A six-digit glass code: n_d = 1.abc, V_d = de.f.
        let code: f64 = name.parse().unwrap_or(0.0);
        let nd = 1.0 + (code / 1000.0).floor() / 1000.0;
        let vd = (code % 1000.0) / 10.0;
        warnings.push(format!(
            "line {line}: glass code {name} read as a model glass n_d = {nd}, V_d = {vd}"
        ));
        return Material::model(nd, vd).map_err(|e| e.context(format!("line {line}")));
    }
    if let Some(m) = catalogs.find_exact(name) {
        if let (Some(nd_file), Some(g)) = (num(3), m.catalog_name()) {
            let nd = m.index(LAMBDA_D_NM);
            // OpticStudio writes 1.5 / 40 where it has no data: a placeholder, not a claim.
            let placeholder = nd_file == 1.5 && num(4) == Some(40.0);
            if nd_file > 1.0 && !placeholder && (nd - nd_file).abs() > 1e-3 {
                warnings.push(format!(
                    "line {line}: glass {g}: the file says n_d = {nd_file}, the catalog gives {nd:.6}"
                ));
            }
        }
        return Ok(m);
    }
    if let Some(m) = catalogs.find(name) {
        warnings.push(format!(
            "line {line}: glass {name} is not in the catalogs; using {} (its DeepLens alias)",
            m.catalog_name().unwrap_or("?")
        ));
        return Ok(m);
    }
    if let Some((g, what)) = crate::lens::material::same_material(name) {
        warnings.push(format!(
            "line {line}: glass {name} ({what}) is read as the built-in {} (the same material)",
            g.name
        ));
        return Ok(Material::Catalog(g));
    }
    let file_values = match (num(3), num(4)) {
        (Some(nd), Some(vd)) if nd >= 1.0 && vd > 0.0 && nd.is_finite() && vd.is_finite() => {
            Some((nd, vd))
        }
        _ => None,
    };
    // OpticStudio writes 1.5 / 40 on a GLAS line whose glass it has no data for.
    let placeholder = |nd: f64, vd: f64| nd == 1.5 && vd == 40.0;
    if catalogs.file_values_fallback {
        match file_values {
            // OpticStudio writes 1.5 / 40 on a GLAS line whose glass it has no data for: a
            // placeholder, never a glass.
            Some((nd, vd)) if placeholder(nd, vd) => {
                return Err(invalid(
                    line,
                    format!("glass \"{name}\" is in no catalog, and the line's n_d 1.5, V_d 40 is OpticStudio's placeholder, not data; give its catalog with --glass-catalog FILE.agf"),
                ));
            }
            Some((nd, vd)) => {
                warnings.push(format!(
                    "line {line}: glass {name} is in no catalog; using a model glass with the file's n_d = {nd}, V_d = {vd} (--glass-fallback file-values)"
                ));
                return Material::model(nd, vd).map_err(|e| e.context(format!("line {line}")));
            }
            None => {}
        }
    }
    let close = catalogs.suggest(name, 3);
    let hint = if close.is_empty() {
        String::new()
    } else {
        format!(" (closest: {})", close.join(", "))
    };
    let searched = catalogs.vendor_order().join(", ");
    let fallback = match file_values {
        Some((nd, vd)) if !(catalogs.file_values_fallback || placeholder(nd, vd)) => format!(
            ", or use the line's n_d = {nd}, V_d = {vd} as a model glass with --glass-fallback file-values"
        ),
        _ => String::new(),
    };
    Err(invalid(
        line,
        format!("unknown glass \"{name}\"{hint}: not in the built-in catalogs ({searched}) or the given AGF files; give its catalog with --glass-catalog FILE.agf{fallback}"),
    ))
}
