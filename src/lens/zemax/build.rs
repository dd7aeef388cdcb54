//! From the raw surfaces to a [`Lens`]: object, fields, wavelengths, apertures and the stop.

use super::*;

/// The object distance in mm (`None` at infinity), checking what SURF 0 may hold.
pub(super) fn object_distance(
    obj: &RawSurf,
    scale: f64,
    catalogs: &GlassCatalogs,
    warnings: &mut Vec<String>,
) -> Result<(Option<f64>, Material)> {
    if let Some(t) = &obj.ty {
        if t.v != "STANDARD" {
            warnings.push(format!(
                "line {}: object surface type {} ignored (the object is a plane or at infinity)",
                t.line, t.v
            ));
        }
    }
    if let Some(l) = obj.stop {
        return Err(invalid(l, "the object surface cannot be the stop"));
    }
    // A glass on the object surface is the object space's medium (immersion optics).
    let medium = match &obj.glas {
        Some(g) => glass(&g.v, g.line, catalogs, warnings)?,
        None => Material::Air,
    };
    let distance = match &obj.disz {
        None => {
            return Err(invalid(
                obj.line,
                "SURF 0 has no DISZ (the object distance, or INFINITY)",
            ))
        }
        Some(At { v: None, .. }) => None,
        // A negative thickness is a virtual object behind the first surface; 0 the object on
        // the first surface's vertex plane.
        Some(At { v: Some(d), line })
            if !((d * scale).abs() <= crate::lens::MAX_OBJECT_DISTANCE_MM) =>
        {
            return Err(invalid(
                *line,
                format!("object distance {d}: it must be finite and at most 1e15 mm (or INFINITY; negative for a virtual object)"),
            ))
        }
        Some(At { v: Some(d), .. }) => Some(d * scale),
    };
    Ok((distance, medium))
}

/// Field type and points (lengths in mm), with their vignetting factors.
pub(super) fn fields(h: &Header, scale: f64) -> Result<(ZmxFieldType, Vec<ZmxField>)> {
    let field_type = match h.ftyp.as_ref().and_then(|f| f.v.first()).copied() {
        None | Some(0.0) => ZmxFieldType::AngleDeg,
        Some(1.0) => ZmxFieldType::ObjectHeightMm,
        Some(2.0) => ZmxFieldType::ParaxialImageHeightMm,
        Some(3.0) => ZmxFieldType::RealImageHeightMm,
        Some(x) => ZmxFieldType::Other(x as i64),
    };
    // FTYP's third number is the number of fields in use; the lists have spare slots.
    let n = h
        .ftyp
        .as_ref()
        .and_then(|f| f.v.get(2))
        .map(|&n| n.clamp(0.0, 1e6) as usize)
        .unwrap_or_else(|| h.yfln.as_ref().map_or(0, |y| y.v.len()));
    let s = if field_type.is_length() { scale } else { 1.0 };
    let at = |v: &Option<Vec<f64>>, i: usize, default: f64| {
        v.as_ref()
            .and_then(|v| v.get(i).copied())
            .unwrap_or(default)
    };
    let vig = |k: usize, i: usize| {
        h.vign[k]
            .as_ref()
            .and_then(|v| v.v.get(i).copied())
            .unwrap_or(0.0)
    };
    let mut list = Vec::with_capacity(n.min(1000));
    for i in 0..n {
        let Some(y) = h.yfln.as_ref().and_then(|y| y.v.get(i).copied()) else {
            break;
        };
        let vignetting = Vignetting {
            decenter_x: vig(0, i),
            decenter_y: vig(1, i),
            compress_x: vig(2, i),
            compress_y: vig(3, i),
        };
        let line = |k: usize| h.vign[k].as_ref().map_or(0, |v| v.line);
        if vig(4, i) != 0.0 {
            return Err(invalid(
                line(4),
                format!(
                    "field {}: vignetting angle (VANN) {}°: tolray applies the decenter and \
                     compression factors only, not a rotated vignetted pupil",
                    i + 1,
                    vig(4, i)
                ),
            ));
        }
        if let Err(e) = vignetting.check() {
            let k = if vignetting.compress_x >= 1.0 { 2 } else { 3 };
            return Err(invalid(
                line(k),
                format!("field {}: {}", i + 1, e.message()),
            ));
        }
        list.push(ZmxField {
            x: at(&h.xfln, i, 0.0) * s,
            y: y * s,
            weight: at(&h.fwgn, i, 1.0),
            vignetting,
        });
    }
    Ok((field_type, list))
}

pub(super) fn spectrum(h: &Header, warnings: &mut Vec<String>) -> Result<Spectrum> {
    let (wavelengths, primary) = wavelengths(h, warnings)?;
    let note = tolray_note(h, warnings);
    let nm: Vec<f64> = wavelengths.iter().map(|w| w.um * 1e3).collect();
    // The NOTE's exact values count only while they still match the file's wavelengths.
    let primary_nm = note
        .primary_nm
        .filter(|p| nm.get(primary).is_some_and(|w| close(*w, *p)))
        .or_else(|| nm.get(primary).copied())
        .unwrap_or(LAMBDA_D_NM);
    let rgb_nm = match note.rgb_nm {
        Some(rgb) if rgb.iter().all(|c| nm.iter().any(|w| close(*w, *c))) => rgb,
        Some(_) => {
            warnings.push(
                "the tolray NOTE's RGB wavelengths are not among the file's wavelengths any more; RGB is taken from the wavelengths"
                    .into(),
            );
            rgb_from(&nm, primary_nm)
        }
        None => rgb_from(&nm, primary_nm),
    };
    Ok(Spectrum {
        wavelengths,
        primary,
        primary_nm,
        rgb_nm,
        sensor_res: note.sensor_res.unwrap_or([2000, 2000]),
    })
}

pub(super) fn build(
    h: Header,
    surfs: Vec<RawSurf>,
    catalogs: &GlassCatalogs,
    mut warnings: Vec<String>,
) -> Result<ZmxLens> {
    if surfs.len() < 3 {
        return Err(Error::invalid(format!(
            "the file has {} SURF blocks; a lens needs the object (SURF 0), at least one lens surface and the image surface",
            surfs.len()
        )));
    }
    let scale = h.unit.as_ref().map_or(1.0, |u| u.v);
    let last = surfs.len() - 1;
    // Glass names resolve in the file's GCAT order first (a name two vendors share is the one
    // of the catalog the file names).
    let with_gcat;
    let catalogs = if catalogs.prefer.is_empty() && !h.gcat.is_empty() {
        with_gcat = GlassCatalogs {
            prefer: h.gcat.clone(),
            ..catalogs.clone()
        };
        &with_gcat
    } else {
        catalogs
    };
    let (object, object_medium) = object_distance(&surfs[0], scale, catalogs, &mut warnings)?;

    let mut walk = Walker {
        origin: Vec3::cst(0.0, 0.0, 0.0),
        rot: Mat3::identity(),
        pending: object.unwrap_or(0.0),
        object_gap: None,
        first_vertex: Vec3::cst(0.0, 0.0, 0.0),
        dir: 1.0,
        medium: object_medium.clone(),
        last_cb_line: None,
        image_plane: ImagePlane::default(),
        leg_rot: Mat3::identity(),
        leg_t: Vec3::cst(0.0, 0.0, 0.0),
        folded: false,
        stop_line: None,
        built: Vec::new(),
        scale,
    };
    for (k, s) in surfs.iter().enumerate().take(last).skip(1) {
        match s.type_name().as_str() {
            "COORDBRK" => walk.coordinate_break(s, &mut warnings)?,
            "STANDARD" | "EVENASPH" | "ODDASPHE" | "TOROIDAL" | "PARAXIAL" | "DGRATING"
            | "QED_TYPE" | "TILTSURF" | "FZERNSAG" | "SZERNSAG" | "BINARY_2" | "GRINSUR1"
            | "GRINSUR2" | "GRINSUR3" => {
                // The frame in which the light leaves the surface: its own, or, when its
                // thickness is 0, that of the first coordinate break after it with a non-zero
                // thickness (or of the last one before the next surface).
                let mut frame_after = walk.rot;
                if s.thickness().is_ok_and(|t| t == 0.0) {
                    for t in surfs[k + 1..last].iter() {
                        if t.type_name() != "COORDBRK" {
                            break;
                        }
                        frame_after = snap(frame_after * cb_rotation(t));
                        if !t.thickness().is_ok_and(|d| d == 0.0) {
                            break;
                        }
                    }
                }
                walk.surface(k, s, frame_after, catalogs, &mut warnings)?
            }
            other => {
                // The dispersive gradient types take their data from OpticStudio's own files.
                let why = match other {
                    "GRINSUR9" => " (Gradient 9, SELFOC: its n0 and A come from OpticStudio's GRADIENT_9.DAT, which is not public)",
                    "GRINSUR5" | "GRINSU12" => " (a gradient whose dispersion comes from OpticStudio's SGRIN.DAT, which is not public)",
                    _ => "",
                };
                return Err(invalid(
                    s.type_line(),
                    format!(
                        "surface type {other}{why} (SURF {k}) is not supported: tolray reads STANDARD, EVENASPH, ODDASPHE, TOROIDAL, PARAXIAL, DGRATING, QED_TYPE, TILTSURF, FZERNSAG, SZERNSAG, BINARY_2, GRINSUR1 to GRINSUR3 (Gradient 1 to 3) and COORDBRK"
                    ),
                ));
            }
        }
    }
    let r_sensor = walk.image(&surfs[last])?;
    let first_vertex = walk.first_vertex;
    let image_plane = walk.image_plane;
    let mut built = walk.built;
    if walk.stop_line.is_none() {
        warnings.push(format!(
            "line {}: no STOP line; the first lens surface (SURF {}) is taken as the stop, as OpticStudio does",
            built[0].raw.line, built[0].index
        ));
        built[0].surface.is_stop = true;
    }
    let spec = spectrum(&h, &mut warnings)?;
    let (field_type, fields) = fields(&h, scale)?;

    let mut lens = Lens {
        info: h.name.clone(),
        surfaces: built.iter().map(|b| b.surface.clone()).collect(),
        object: match walk.object_gap {
            Some(d) if object.is_some() => Object::Finite { distance_mm: d },
            _ => Object::Infinite,
        },
        sensor: Sensor::from_half_diagonal(r_sensor.unwrap_or(1.0), spec.sensor_res),
        primary_wavelength_nm: spec.primary_nm,
        rgb_wavelengths_nm: spec.rgb_nm,
        ray_aiming: h.raim.as_ref().is_some_and(|r| r.v != 0),
        object_medium,
        fields: Vec::new(),
        image_plane,
    };
    // Beyond 20 µm every medium must be defined at each of the file's wavelengths (millimetre-wave
    // refractors in constant indices; `WAVM 587.56`, nanometres for micrometres, is refused);
    // below, a glass is taken beyond its formula's range as OpticStudio takes it, but not where
    // the formula gives no usable index (N-SK16's Sellmeier at 8.5 µm: n² < 0).
    for w in &spec.wavelengths {
        let nm = w.um * 1e3;
        let unusable = lens.check_indices(nm).is_err();
        if nm > crate::lens::material::DEFINED_MEDIA_BEYOND_NM || unusable {
            let line = h
                .wavm
                .iter()
                .find(|x| x.1 == w.um)
                .map(|x| x.3)
                .or(h.wavl.as_ref().map(|l| l.line))
                .unwrap_or(0);
            lens.check_indices(nm)
                .map_err(|e| invalid(line, format!("wavelength {} µm: {}", w.um, e.message())))?;
        }
    }

    // Each semi-diameter, checked with its line; then the stop is sized by the aperture.
    // Surfaces without one (no DIAM, MEMA or FLAP value) hold a placeholder until the paraxial
    // beam sizes them below.
    let stop = lens.stop_index().unwrap_or(0);
    let aperture = h.aperture.as_ref().map(|a| a.v);
    let sized = !matches!(aperture, None | Some(ZmxAperture::FloatByStop));
    let mut missing = Vec::new();
    for (i, b) in built.iter().enumerate() {
        let s = &mut lens.surfaces[i];
        let line = b.raw.diam.as_ref().map_or(b.raw.line, |d| d.line);
        if i == stop && sized {
            if !(s.semi_aperture_mm > 0.0) {
                s.semi_aperture_mm = 1e-3;
            }
            continue;
        }
        if !b.has_diam || !(s.semi_aperture_mm > 0.0) {
            if i == stop {
                return Err(invalid(
                    line,
                    format!(
                        "SURF {} is the stop and the aperture floats by stop size, so it needs a positive semi-diameter (DIAM)",
                        b.index
                    ),
                ));
            }
            s.semi_aperture_mm = 1e-3;
            missing.push(i);
            continue;
        }
        check_rim(s, line, b.index)?;
    }
    if let (Some(a), true) = (&h.aperture, sized) {
        let file_diam = built[stop]
            .has_diam
            .then_some(lens.surfaces[stop].semi_aperture_mm);
        let r = stop_semi_aperture(&lens, stop, a.v, scale, file_diam)
            .map_err(|e| e.context(format!("line {}", a.line)))?;
        lens.surfaces[stop].semi_aperture_mm = r;
        check_rim(&lens.surfaces[stop], a.line, built[stop].index).map_err(|e| {
            Error::invalid(format!(
                "{} (the stop semi-diameter that the aperture needs)",
                e.full_message()
            ))
        })?;
    }
    if !missing.is_empty() || r_sensor.is_none() {
        size_by_beam(
            &mut lens,
            &built,
            &missing,
            r_sensor.is_none(),
            field_type,
            &fields,
            &mut warnings,
        )?;
    }
    match field_points(field_type, &fields, &lens) {
        Some(points) => lens.fields = points,
        None => {
            if let Some(v) = h.vign[..4]
                .iter()
                .flatten()
                .find(|v| v.v.iter().take(fields.len()).any(|&x| x != 0.0))
            {
                warnings.push(format!(
                    "line {}: vignetting factors not applied: tolray has no field of this file's type ({}), so its commands trace fractions of the sensor over the whole pupil",
                    v.line,
                    field_type.describe()
                ));
            }
        }
    }
    lens.validate()?;

    // Wavelengths outside the catalog range of a glass.
    for (b, s) in built.iter().zip(&lens.surfaces) {
        let (Some((lo, hi)), Some(name)) = (s.material.range_um(), s.material.catalog_name())
        else {
            continue;
        };
        let out: Vec<String> = spec
            .wavelengths
            .iter()
            .filter(|w| w.um < lo || w.um > hi)
            .map(|w| format!("{} µm", w.um))
            .collect();
        if !out.is_empty() {
            let line = b.raw.glas.as_ref().map_or(b.raw.line, |g| g.line);
            warnings.push(format!(
                "line {line}: glass {name} is defined from {lo} to {hi} µm; {} outside that range",
                out.join(", ")
            ));
        }
    }

    let extras = ZmxExtras {
        aperture,
        field_type,
        fields,
        wavelengths: spec.wavelengths,
        primary: spec.primary,
        glass_catalogs: h.gcat,
        surface_numbers: built.iter().map(|b| b.index).collect(),
        first_vertex_mm: [first_vertex.x, first_vertex.y, first_vertex.z],
    };
    Ok(ZmxLens {
        lens,
        extras,
        warnings: group_warnings(warnings),
    })
}

/// Warnings that say the same thing on several lines become one (`lines 97, 116, 135: ...`), so
/// a glass used twenty times is reported once.
pub(super) fn group_warnings(warnings: Vec<String>) -> Vec<String> {
    let mut out: Vec<(Vec<String>, String)> = Vec::new();
    for w in warnings {
        let (line, body) = match w.strip_prefix("line ").and_then(|r| r.split_once(": ")) {
            Some((n, body)) if n.bytes().all(|b| b.is_ascii_digit()) => {
                (Some(n.to_string()), body.to_string())
            }
            _ => (None, w.clone()),
        };
        match (line, out.iter_mut().find(|(_, b)| *b == body)) {
            (Some(n), Some((lines, _))) if !lines.is_empty() => lines.push(n),
            (Some(n), None) => out.push((vec![n], body)),
            _ => out.push((Vec::new(), w)),
        }
    }
    out.into_iter()
        .map(|(lines, body)| match lines.len() {
            0 => body,
            1 => format!("line {}: {body}", lines[0]),
            _ => format!("lines {}: {body}", lines.join(", ")),
        })
        .collect()
}

/// Sizes the surfaces in `missing` (and the sensor when `sensor`) by the paraxial beam of the
/// file's largest field, as OpticStudio computes semi-diameters that a file does not fix. These
/// sizes are drawn and reported; they never clip.
pub(super) fn size_by_beam(
    lens: &mut Lens,
    built: &[Built],
    missing: &[usize],
    sensor: bool,
    field_type: ZmxFieldType,
    fields: &[ZmxField],
    warnings: &mut Vec<String>,
) -> Result<()> {
    use crate::lens::paraxial::{beam_semi_diameters, ParaxialField};
    let max = fields.iter().map(|f| f.x.hypot(f.y)).fold(0.0, f64::max);
    let field = match field_type {
        ZmxFieldType::AngleDeg => ParaxialField::AngleDeg(max),
        ZmxFieldType::ObjectHeightMm if matches!(lens.object, Object::Finite { .. }) => {
            ParaxialField::ObjectHeightMm(max)
        }
        ZmxFieldType::ParaxialImageHeightMm | ZmxFieldType::RealImageHeightMm => {
            ParaxialField::ImageHeightMm(max)
        }
        _ => ParaxialField::AngleDeg(0.0),
    };
    let r = beam_semi_diameters(lens, lens.primary_wavelength_nm, field)
        .map_err(|e| e.context("sizing the surfaces without a semi-diameter (DIAM)"))?;
    let mut sized = Vec::new();
    for &i in missing {
        let s = &mut lens.surfaces[i];
        // Inside a conic's rim, and never zero (a beam focused on a surface).
        let rim2 = (1.0 + s.k) * s.c * s.c;
        let rim = if rim2 > 0.0 {
            0.999 / rim2.sqrt()
        } else {
            f64::INFINITY
        };
        s.semi_aperture_mm = r[i].min(rim).max(1e-6);
        sized.push(format!(
            "SURF {} {:.4} mm",
            built[i].index, s.semi_aperture_mm
        ));
    }
    if sensor {
        // The image height of the largest field; with only an on-axis field, the beam's size at
        // the last surface (a sensor of the lens' own size).
        let n = r.len();
        let h = if max > 0.0 { r[n - 1] } else { r[n - 2] };
        if !(h > 0.0) {
            return Err(Error::invalid(
                "the image surface has no semi-diameter (DIAM) and the fields give no image height to size the sensor by",
            ));
        }
        lens.sensor.r_mm = h;
        sized.push(format!("sensor half-diagonal {h:.4} mm"));
    }
    let line = missing
        .first()
        .map_or(built.last().map_or(0, |b| b.raw.line), |&i| {
            built[i].raw.line
        });
    warnings.push(format!(
        "line {line}: no semi-diameter (DIAM) given; sized to the paraxial beam of the largest field (these sizes do not clip rays): {}",
        sized.join(", ")
    ));
    Ok(())
}

pub(super) fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * b.abs()
}

pub(super) fn check_rim(s: &Surface, line: usize, index: usize) -> Result<()> {
    let r = s.semi_aperture_mm;
    if (1.0 + s.k) * s.c * s.c * r * r > 1.0 {
        return Err(invalid(
            line,
            format!(
                "SURF {index}: semi-diameter {r} mm exceeds the surface's rim (radius {} mm, conic {})",
                1.0 / s.c,
                s.k
            ),
        ));
    }
    Ok(())
}

/// The stop semi-aperture that gives the file's paraxial aperture. The entrance pupil scales
/// linearly with the stop, so one paraxial analysis with a trial radius suffices. A file
/// semi-diameter that agrees to 1e-9 is kept as written (so tolray's own files round-trip
/// exactly).
pub(super) fn stop_semi_aperture(
    lens: &Lens,
    stop: usize,
    aperture: ZmxAperture,
    scale: f64,
    file_diam: Option<f64>,
) -> Result<f64> {
    let mut trial = lens.clone();
    let r0 = file_diam.filter(|&d| d > 0.0).unwrap_or(1e-3);
    trial.surfaces[stop].semi_aperture_mm = r0;
    if check_rim(&trial.surfaces[stop], 0, 0).is_err() {
        trial.surfaces[stop].semi_aperture_mm = 1e-3;
    }
    let r0 = trial.surfaces[stop].semi_aperture_mm;
    let p = trial.paraxial(lens.primary_wavelength_nm)?;
    let epd = match aperture {
        ZmxAperture::EntrancePupilDiameter(d) => d * scale,
        ZmxAperture::ImageSpaceFnum(f) => {
            if !(f > 0.0) {
                return Err(Error::invalid(format!("FNUM {f} must be positive")));
            }
            p.focal_length_for("FNUM (EFL / entrance pupil diameter)")?
                .abs()
                / f
        }
        ZmxAperture::ObjectSpaceNa(na) => {
            let Object::Finite { distance_mm } = lens.object else {
                return Err(Error::invalid(
                    "OBNA (object-space NA) needs an object at a finite distance",
                ));
            };
            // NA = n sin θ in the object medium.
            let n0 = lens.object_medium.index(lens.primary_wavelength_nm);
            if !(na > 0.0 && na < n0) {
                return Err(Error::invalid(format!(
                    "OBNA {na} must be between 0 and the object medium's index {n0}"
                )));
            }
            2.0 * (na / n0).asin().tan() * (p.entrance_pupil_z_mm + distance_mm)
        }
        ZmxAperture::FloatByStop => p.entrance_pupil_diameter_mm,
    };
    let r = r0 * epd / p.entrance_pupil_diameter_mm;
    if !(r >= 1e-9 && r.is_finite()) {
        return Err(Error::invalid(format!(
            "the aperture gives an entrance pupil diameter of {epd:e} mm and a stop semi-diameter of {r:e} mm; both must be positive (at least 1e-9 mm) and finite"
        )));
    }
    Ok(match file_diam {
        Some(d) if (r - d).abs() <= 1e-9 * d => d,
        _ => r,
    })
}

/// The file's wavelengths and primary index.
pub(super) fn wavelengths(
    h: &Header,
    warnings: &mut Vec<String>,
) -> Result<(Vec<ZmxWavelength>, usize)> {
    let n_max = h
        .ftyp
        .as_ref()
        .and_then(|f| f.v.get(3))
        .map(|&n| n.clamp(0.0, 1e6) as usize);
    let mut list: Vec<(ZmxWavelength, usize)> = if !h.wavm.is_empty() {
        let mut w = h.wavm.clone();
        w.sort_by_key(|x| x.0);
        w.dedup_by_key(|x| x.0);
        w.into_iter()
            .filter(|x| x.0 >= 1 && n_max.is_none_or(|n| x.0 <= n))
            .map(|(_, um, weight, line)| (ZmxWavelength { um, weight }, line))
            .collect()
    } else if let Some(w) = &h.wavl {
        w.v.iter()
            .enumerate()
            .map(|(i, &um)| {
                let weight = h
                    .wwgt
                    .as_ref()
                    .and_then(|g| g.get(i).copied())
                    .unwrap_or(1.0);
                (ZmxWavelength { um, weight }, w.line)
            })
            .collect()
    } else {
        Vec::new()
    };
    for (w, line) in &list {
        if !crate::lens::material::wavelength_um_ok(w.um) {
            return Err(invalid(
                *line,
                format!(
                    "wavelength {} µm: give micrometres, {}",
                    w.um,
                    crate::lens::material::WAVELENGTH_RANGE_TEXT
                ),
            ));
        }
    }
    if list.is_empty() {
        warnings.push(
            "no wavelengths (WAVM) in the file; using tolray's defaults (d line primary, RGB 656/587/486 nm)"
                .into(),
        );
        list = [0.656, 0.587, 0.486, LAMBDA_D_NM * 1e-3]
            .iter()
            .map(|&um| (ZmxWavelength { um, weight: 1.0 }, 0))
            .collect();
        return Ok((list.into_iter().map(|x| x.0).collect(), 3));
    }
    let primary = match &h.pwav {
        None => 0,
        Some(p) if p.v >= 1 && p.v <= list.len() => p.v - 1,
        Some(p) => {
            return Err(invalid(
                p.line,
                format!("PWAV {}: the file has {} wavelengths", p.v, list.len()),
            ))
        }
    };
    Ok((list.into_iter().map(|x| x.0).collect(), primary))
}

/// RGB from a list of wavelengths: the longest, a middle one (the primary if it lies between),
/// the shortest.
pub(super) fn rgb_from(wl: &[f64], primary: f64) -> [f64; 3] {
    if wl.is_empty() {
        return [656.0, 587.0, 486.0];
    }
    let r = wl.iter().copied().fold(f64::MIN, f64::max);
    let b = wl.iter().copied().fold(f64::MAX, f64::min);
    let inner: Vec<f64> = wl.iter().copied().filter(|&w| w > b && w < r).collect();
    let g = if inner.is_empty() || inner.contains(&primary) {
        primary
    } else {
        inner
            .iter()
            .copied()
            .min_by(|x, y| (x - primary).abs().total_cmp(&(y - primary).abs()))
            .unwrap_or(primary)
    };
    [r, g, b]
}

pub(super) fn tolray_note(h: &Header, warnings: &mut Vec<String>) -> TolrayNote {
    let mut out = TolrayNote::default();
    for n in &h.notes {
        let toks: Vec<&str> = n.v.split_whitespace().collect();
        let Some(pos) = toks.iter().position(|t| *t == "tolray") else {
            continue;
        };
        for t in &toks[pos + 1..] {
            let Some((key, val)) = t.split_once('=') else {
                continue;
            };
            let vals: Option<Vec<f64>> = val
                .split(',')
                .map(|x| x.parse::<f64>().ok().filter(|v| v.is_finite()))
                .collect();
            match (key, vals.as_deref()) {
                ("primary_nm", Some([p])) => out.primary_nm = Some(*p),
                ("rgb_nm", Some([r, g, b])) => out.rgb_nm = Some([*r, *g, *b]),
                ("sensor_res", Some([w, hh]))
                    if *w >= 1.0 && *hh >= 1.0 && *w <= 1e9 && *hh <= 1e9 =>
                {
                    out.sensor_res = Some([*w as u32, *hh as u32])
                }
                _ => warnings.push(format!(
                    "line {}: tolray note entry \"{t}\" not understood",
                    n.line
                )),
            }
        }
    }
    out
}
