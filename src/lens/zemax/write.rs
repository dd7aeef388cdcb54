//! Writing a [`Lens`] as a .zmx file.

use super::*;

/// A number as the shortest text that reads back to the same `f64`.
pub(super) fn fmt(x: f64) -> String {
    if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:E}")
    }
}

/// The catalog name Zemax's `GCAT` uses for a built-in vendor.
pub(super) fn gcat_name(vendor: &str) -> String {
    match vendor {
        "Hikari" => "NIKON-HIKARI".into(),
        v => v.to_ascii_uppercase(),
    }
}

/// The `GCAT` line's catalogs: `initial` (a file's own order), then every catalog a material
/// comes from, ordered so that each built-in glass name resolves to its own vendor's glass when
/// read back (the reader looks names up in `GCAT` order): a vendor moves before any other listed
/// vendor that has a glass of the same name (Hikari's F2 before Schott, which has an F2 too).
/// Two materials of one name from two vendors cannot both be named in a file; the first wins.
pub(super) fn gcat_order(lens: &Lens, initial: Vec<String>) -> Vec<String> {
    let mut gcat = initial;
    let media =
        std::iter::once(&lens.object_medium).chain(lens.surfaces.iter().map(|s| &s.material));
    let mut glasses = Vec::new();
    for m in media {
        let c = match m {
            Material::Catalog(g) => {
                glasses.push(*g);
                Some(gcat_name(g.vendor))
            }
            Material::Agf(g) => Some(g.catalog.clone()),
            _ => None,
        };
        if let Some(c) = c {
            if !gcat.iter().any(|x| x.eq_ignore_ascii_case(&c)) {
                gcat.push(c);
            }
        }
    }
    let vendor = |c: &String| crate::lens::material::vendor_of_gcat(c);
    // Each pass moves one vendor ahead of the first listed vendor that would take its glass;
    // a bounded number of passes ends a cycle (the same name wanted from two vendors).
    for _ in 0..gcat.len() * gcat.len() {
        let mut moved = false;
        for g in &glasses {
            let Some(own) = gcat.iter().position(|c| vendor(c) == Some(g.vendor)) else {
                continue;
            };
            let thief = gcat[..own].iter().position(|c| {
                vendor(c)
                    .is_some_and(|v| crate::lens::material::find_in_vendors(g.name, &[v]).is_some())
            });
            if let Some(t) = thief {
                let c = gcat.remove(own);
                gcat.insert(t, c);
                moved = true;
                break;
            }
        }
        if !moved {
            break;
        }
    }
    gcat
}

/// A `COORDBRK` surface's lines: thickness `t`, PARM 1..5 = decenter x, y and tilts about x,
/// y, z (degrees), PARM 6 the order flag.
pub(super) fn coordinate_break(t: f64, parms: [f64; 5], order: u8) -> Vec<String> {
    let mut l = vec!["TYPE COORDBRK".to_string(), format!("DISZ {}", fmt(t))];
    for (k, v) in parms.iter().enumerate() {
        l.push(format!("PARM {} {}", k + 1, fmt(*v)));
    }
    l.push(format!("PARM 6 {order}"));
    l
}

/// The tilts about x, the new y and the new z (degrees, a coordinate break with order flag 0:
/// `Rx(a) Ry(b) Rz(g)`) that give tolray's surface frame: +z turned onto `n` by the shortest arc,
/// after a roll of `roll_deg` about the axis.
pub(super) fn tilt_angles(n: [f64; 3], roll_deg: f64) -> (f64, f64, f64) {
    let [a, b, g] = angles_of(&crate::lens::system::frame_rotation(n, roll_deg));
    (a, b, g)
}

pub(super) fn glas_line(m: &Material) -> Option<String> {
    let model = |nd: f64, vd: f64| format!("GLAS ___BLANK 1 0 {} {} 0 0 0 0 0 0", fmt(nd), fmt(vd));
    match m {
        // The medium is the surface's type and parameters (GRINSUR1 to GRINSUR3).
        Material::Air | Material::Gradient(_) => None,
        Material::Constant(n) => Some(model(*n, 0.0)),
        Material::Model { nd, vd } => Some(model(*nd, *vd)),
        Material::Catalog(g) => Some(format!(
            "GLAS {} 0 0 {} {} 0 0 0 0 0 0",
            g.name,
            fmt(g.nd),
            fmt(g.vd)
        )),
        Material::Agf(g) => Some(format!(
            "GLAS {} 0 0 {} {} 0 0 0 0 0 0",
            g.name,
            fmt(g.nd),
            fmt(g.vd)
        )),
        Material::Perturbed { nd_new, .. } => {
            use crate::lens::material::{LAMBDA_C_NM, LAMBDA_F_NM};
            let disp = m.index(LAMBDA_F_NM) - m.index(LAMBDA_C_NM);
            // A dispersion that rounds to nothing is a constant index (V_d 0), never V_d inf.
            let vd = if disp > 0.0 {
                (nd_new - 1.0) / disp
            } else {
                0.0
            };
            Some(model(*nd_new, if vd.is_finite() { vd } else { 0.0 }))
        }
    }
}

/// µm text for a wavelength in nm that reads back (times 1000) to the same nm value when one
/// exists.
pub(super) fn um_text(nm: f64) -> String {
    fmt(crate::lens::material::um_from_nm(nm))
}

/// The lens as .zmx text (ASCII, CRLF line ends, `UNIT MM`). `extras` (from [`read_file`])
/// keeps a file's fields, wavelengths and aperture type; without it the fields are 0, 0.5, 0.7
/// and 1 of the sensor's half-diagonal as paraxial image heights, the wavelengths are the lens'
/// RGB and primary, and the aperture is its paraxial entrance pupil diameter.
pub fn to_string(lens: &Lens, extras: Option<&ZmxExtras>) -> String {
    let mut out = String::new();
    let mut w = |s: String| {
        out.push_str(&s);
        out.push_str("\r\n");
    };
    let name: String = lens
        .info
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    w("VERS 190513".into());
    w("MODE SEQ".into());
    w(format!("NAME {}", name.trim()).trim_end().to_string());
    let [sw, sh] = lens.sensor.resolution;
    let [r, g, b] = lens.rgb_wavelengths_nm;
    w(format!(
        "NOTE 0 tolray primary_nm={} rgb_nm={r},{g},{b} sensor_res={sw},{sh}",
        lens.primary_wavelength_nm
    ));
    w("UNIT MM X W X CM MR CPMM".into());
    let para = lens.paraxial(lens.primary_wavelength_nm).ok();
    let kind = extras
        .and_then(|e| e.aperture)
        .unwrap_or(ZmxAperture::EntrancePupilDiameter(0.0));
    match (para, kind) {
        (Some(p), ZmxAperture::ImageSpaceFnum(_)) if p.efl_mm.is_some() => w(format!(
            "FNUM {} 0",
            fmt(p.efl_mm.unwrap_or(0.0).abs() / p.entrance_pupil_diameter_mm)
        )),
        (Some(p), ZmxAperture::ObjectSpaceNa(_))
            if matches!(lens.object, Object::Finite { .. }) =>
        {
            let d = match lens.object {
                Object::Finite { distance_mm } => distance_mm,
                Object::Infinite => 0.0,
            };
            // NA = n sin θ in the object medium, as the reader takes it.
            let u = 0.5 * p.entrance_pupil_diameter_mm / (p.entrance_pupil_z_mm + d);
            let n0 = lens.object_medium.index(lens.primary_wavelength_nm);
            w(format!("OBNA {} 0", fmt(n0 * u.atan().sin())))
        }
        // (An afocal lens has no F-number: its aperture is written as the pupil.)
        (Some(p), _) => w(format!("ENPD {}", fmt(p.entrance_pupil_diameter_mm))),
        _ => w("FLOA".into()),
    }
    w(format!(
        "RAIM 0 {} 1 1 0 0 0 0 0",
        if lens.ray_aiming { 2 } else { 0 }
    ));
    let gcat = gcat_order(
        lens,
        extras.map(|e| e.glass_catalogs.clone()).unwrap_or_default(),
    );
    if !gcat.is_empty() {
        w(format!("GCAT {}", gcat.join(" ")));
    }
    // Fields.
    // The lens' own field points first (angles back in OpticStudio's sign; validation keeps
    // them of one kind), then the file's (kinds a lens cannot hold), else paraxial image
    // heights at 0, 0.5, 0.7 and 1 of the sensor's half-diagonal (read back, they are the
    // lens' fields).
    let from_lens = |p: &FieldPoint| {
        let (x, y) = match p.field {
            Field::AngleDeg { x, y } => (0.0 - x, 0.0 - y),
            f => f.xy(),
        };
        ZmxField {
            x,
            y,
            weight: p.weight,
            vignetting: p.vignetting,
        }
    };
    let (ftype, fields) = match (lens.fields.first(), extras) {
        (Some(p), _) => (
            match p.field {
                Field::HeightMm { .. } => ZmxFieldType::ObjectHeightMm,
                Field::ImageHeightMm { .. } => ZmxFieldType::ParaxialImageHeightMm,
                Field::RealImageHeightMm { .. } => ZmxFieldType::RealImageHeightMm,
                _ => ZmxFieldType::AngleDeg,
            },
            lens.fields.iter().map(from_lens).collect::<Vec<_>>(),
        ),
        (None, Some(e)) if !e.fields.is_empty() => (e.field_type, e.fields.clone()),
        _ => {
            let rs = lens.sensor.half_diagonal_mm();
            (
                ZmxFieldType::ParaxialImageHeightMm,
                [0.0, 0.5, 0.7, 1.0]
                    .iter()
                    .map(|f| ZmxField {
                        x: 0.0,
                        y: f * rs,
                        weight: 1.0,
                        vignetting: Vignetting::default(),
                    })
                    .collect(),
            )
        }
    };
    // Wavelengths: the file's, plus the lens' RGB and primary when missing.
    let mut waves: Vec<(String, f64, f64)> = extras
        .map(|e| {
            e.wavelengths
                .iter()
                .map(|x| (fmt(x.um), x.um * 1e3, x.weight))
                .collect()
        })
        .unwrap_or_default();
    for nm in [r, g, b, lens.primary_wavelength_nm] {
        if !waves.iter().any(|x| close(x.1, nm)) {
            waves.push((um_text(nm), nm, 1.0));
        }
    }
    let primary = waves
        .iter()
        .position(|x| close(x.1, lens.primary_wavelength_nm))
        .unwrap_or(0);
    w(format!(
        "FTYP {} 0 {} {} 0 0 0",
        ftype.code(),
        fields.len(),
        waves.len()
    ));
    let join = |f: &dyn Fn(&ZmxField) -> f64| {
        fields
            .iter()
            .map(|x| fmt(f(x)))
            .collect::<Vec<_>>()
            .join(" ")
    };
    w(format!("XFLN {}", join(&|f| f.x)));
    w(format!("YFLN {}", join(&|f| f.y)));
    w(format!("FWGN {}", join(&|f| f.weight)));
    if fields.iter().any(|f| !f.vignetting.is_none()) {
        w(format!("VDXN {}", join(&|f| f.vignetting.decenter_x)));
        w(format!("VDYN {}", join(&|f| f.vignetting.decenter_y)));
        w(format!("VCXN {}", join(&|f| f.vignetting.compress_x)));
        w(format!("VCYN {}", join(&|f| f.vignetting.compress_y)));
        w(format!("VANN {}", join(&|_| 0.0)));
    }
    for (i, (um, _, wt)) in waves.iter().enumerate() {
        w(format!("WAVM {} {um} {}", i + 1, fmt(*wt)));
    }
    w(format!("PWAV {}", primary + 1));

    // Surfaces.
    let mut k = 0;
    let mut surf = |w: &mut dyn FnMut(String), lines: Vec<String>| {
        w(format!("SURF {k}"));
        for l in lines {
            w(format!("  {l}"));
        }
        k += 1;
    };
    let mut object = vec![
        "TYPE STANDARD".into(),
        "CURV 0".into(),
        match lens.object {
            Object::Infinite => "DISZ INFINITY".into(),
            Object::Finite { distance_mm } => format!("DISZ {}", fmt(distance_mm)),
        },
    ];
    object.extend(glas_line(&lens.object_medium));
    surf(&mut w, object);
    // With no marked stop, tolray's paraxial model takes the surface that limits the axial
    // beam; mark that one, or OpticStudio (and the reader) would take the first surface.
    let stop = lens.stop_index().or_else(|| {
        lens.paraxial(lens.primary_wavelength_nm)
            .ok()
            .map(|p| p.stop_surface)
    });
    for (i, s) in lens.surfaces.iter().enumerate() {
        let moved = is_moved(s);
        let (a, b, g) = if moved {
            tilt_angles(s.vec_local, s.roll_deg)
        } else {
            (0.0, 0.0, 0.0)
        };
        let [dx, dy] = s.pos_xy_mm;
        let cb = |sign: f64, order: u8, t: f64| {
            coordinate_break(t, [dx, dy, a, b, g].map(|v| sign * v), order)
        };
        if moved {
            surf(&mut w, cb(1.0, 0, 0.0));
        }
        let mut l: Vec<String> = Vec::new();
        if s.is_stop || stop == Some(i) {
            l.push("STOP".into());
        }
        let asph = s.is_aspheric();
        let grin = match &s.material {
            Material::Gradient(g) => Some(g),
            _ => None,
        };
        l.push(match grin {
            // (Validation keeps a gradient-index medium after a conic: no asphere PARMs.)
            Some(g) => format!("TYPE {}", g.zemax_type()),
            None => match s.shape {
                _ if s.grating.is_some() => "TYPE DGRATING",
                _ if s.phase.is_some() => "TYPE BINARY_2",
                Shape::Paraxial { .. } => "TYPE PARAXIAL",
                Shape::Odd => "TYPE ODDASPHE",
                Shape::Toroidal { .. } => "TYPE TOROIDAL",
                Shape::Qbfs { .. } | Shape::Qcon { .. } => "TYPE QED_TYPE",
                Shape::Zernike {
                    ordering: crate::math::zernike::Ordering::Fringe,
                    ..
                } => "TYPE FZERNSAG",
                Shape::Zernike { .. } => "TYPE SZERNSAG",
                Shape::Even if asph => "TYPE EVENASPH",
                Shape::Even => "TYPE STANDARD",
            }
            .into(),
        });
        l.push(format!("CURV {}", fmt(s.c)));
        if s.k != 0.0 || asph {
            l.push(format!("CONI {}", fmt(s.k)));
        }
        match s.shape {
            _ if grin.is_some() => {
                // PARM 1: Δt, 2: n0, 3..: the type's coefficients (mm).
                for (k, v) in grin.map(|g| g.zemax_parms()).unwrap_or_default() {
                    l.push(format!("PARM {k} {}", fmt(v)));
                }
            }
            _ if s.phase.is_some() => {
                // PARM 0: the diffraction order, 1..8: r² .. r¹⁶; XDAT 1: the number of
                // terms, 2: the normalization radius, 3..: A_1, A_2, ... (radians).
                if let Some(p) = &s.phase {
                    l.push(format!("PARM 0 {}", fmt(p.order)));
                    for (j, a) in s.asph.iter().enumerate() {
                        l.push(format!("PARM {} {}", j + 1, fmt(*a)));
                    }
                    l.push(format!("XDAT 1 {}", p.coefficients.len()));
                    l.push(format!("XDAT 2 {}", fmt(p.norm_radius_mm)));
                    for (j, a) in p.coefficients.iter().enumerate() {
                        l.push(format!("XDAT {} {}", j + 3, fmt(*a)));
                    }
                }
            }
            Shape::Paraxial { focal_mm } => {
                // PARM 1: the focal length; PARM 2: OpticStudio's OPD mode 1 (the default).
                l.push(format!("PARM 1 {}", fmt(focal_mm)));
                l.push("PARM 2 1".into());
            }
            Shape::Toroidal { c_rot } => {
                // PARM 1: the radius of rotation (0: none); PARM 2..8: y² .. y¹⁴.
                let r = if c_rot == 0.0 { 0.0 } else { 1.0 / c_rot };
                l.push(format!("PARM 1 {}", fmt(r)));
                for (j, a) in s.asph.iter().take(N_ASPH - 1).enumerate() {
                    l.push(format!("PARM {} {}", j + 2, fmt(*a)));
                }
            }
            Shape::Qbfs { norm_radius_mm } | Shape::Qcon { norm_radius_mm } => {
                // XDAT 1: type 0 (Qbfs) or 1 (Qcon), 2: the number of terms, 3: the
                // normalization radius, 4..: a_0, a_1, ...
                let n = s.asph.iter().rposition(|&a| a != 0.0).map_or(0, |j| j + 1);
                let ty = if matches!(s.shape, Shape::Qbfs { .. }) {
                    0
                } else {
                    1
                };
                l.push(format!("XDAT 1 {ty}"));
                l.push(format!("XDAT 2 {n}"));
                l.push(format!("XDAT 3 {}", fmt(norm_radius_mm)));
                for (j, a) in s.asph.iter().take(n).enumerate() {
                    l.push(format!("XDAT {} {}", j + 4, fmt(*a)));
                }
            }
            Shape::Zernike {
                norm_radius_mm,
                decenter_mm,
                extrapolate,
                ..
            } => {
                // PARM 0: Extrapolate, 1..8: r² .. r¹⁶, 9 and 10: the Zernike decenter; XDAT 1:
                // the number of terms, 2: the normalization radius, 3..: Z1, Z2, ...
                l.push(format!("PARM 0 {}", u8::from(extrapolate)));
                for (j, a) in s.asph.iter().enumerate() {
                    l.push(format!("PARM {} {}", j + 1, fmt(*a)));
                }
                l.push(format!("PARM 9 {}", fmt(decenter_mm[0])));
                l.push(format!("PARM 10 {}", fmt(decenter_mm[1])));
                l.push(format!("XDAT 1 {}", s.zernike.len()));
                l.push(format!("XDAT 2 {}", fmt(norm_radius_mm)));
                for (j, a) in s.zernike.iter().enumerate() {
                    l.push(format!("XDAT {} {}", j + 3, fmt(*a)));
                }
            }
            _ if asph => {
                for (j, a) in s.asph.iter().enumerate() {
                    l.push(format!("PARM {} {}", j + 1, fmt(*a)));
                }
            }
            _ => {}
        }
        if let Some(g) = s.grating {
            // Validation keeps gratings on conics: no asphere PARMs above.
            l.push(format!("PARM 1 {}", fmt(g.lines_per_um)));
            l.push(format!("PARM 2 {}", fmt(g.order)));
        }
        // A fold mirror: travel to the fold's pivot, turn the frame there, go on to the next
        // vertex along the turned axis.
        let to_next = match s.fold {
            Some(f) => f.pivot_mm,
            None => s.d_next_mm,
        };
        l.push(format!("DISZ {}", fmt(if moved { 0.0 } else { to_next })));
        if s.role == SurfaceRole::Mirror {
            l.push("GLAS MIRROR".into());
        } else if let Some(g) = glas_line(&s.material) {
            l.push(g);
        }
        l.push(format!("DIAM {} 1 0 0 1 \"\"", fmt(s.semi_aperture_mm)));
        l.extend(aperture_lines(s));
        surf(&mut w, l);
        if moved {
            surf(&mut w, cb(-1.0, 1, to_next));
        }
        // The travel written last for this surface: past the fold's pivot, or to the next.
        let mut last_gap = to_next;
        if let Some(f) = s.fold {
            let [a, b, g] = f.tilt_deg;
            last_gap = s.d_next_mm - f.pivot_mm;
            surf(&mut w, coordinate_break(last_gap, [0.0, 0.0, a, b, g], 0));
        }
        // The reader tells a fold mirror from a tilted one by the frame the coordinate breaks
        // after it leave, up to the first break that moves along the axis. When none does (the
        // next surface at the mirror's vertex), a flat dummy surface closes the mirror's breaks
        // before the next surface's (or the image plane's) own begin.
        if s.role == SurfaceRole::Mirror && last_gap == 0.0 {
            // (In the mirror's medium, which the light goes back through: a dummy.)
            let mut dummy = vec!["TYPE STANDARD".into(), "CURV 0".into(), "DISZ 0".into()];
            dummy.extend(glas_line(&s.material));
            surf(&mut w, dummy);
        }
    }
    // A decentred, tilted or rolled image plane: one coordinate break before it.
    let ip = &lens.image_plane;
    if ip.is_moved() {
        let (a, b, g) = tilt_angles(ip.normal, ip.roll_deg);
        let [dx, dy] = ip.decenter_mm;
        surf(&mut w, coordinate_break(0.0, [dx, dy, a, b, g], 0));
    }
    surf(
        &mut w,
        vec![
            "TYPE STANDARD".into(),
            format!("CURV {}", fmt(ip.curvature_per_mm)),
            format!("CONI {}", fmt(ip.conic)),
            "DISZ 0".into(),
            format!("DIAM {} 1 0 0 1 \"\"", fmt(lens.sensor.half_diagonal_mm())),
        ],
    );
    out
}

/// The aperture lines of a surface (`FLAP` for a semi-diameter that clips, `CLAP`, `OBSC`,
/// `SQAP`, `OBSQ`, `ELAP`, `OBEL`, and `OBDC` for a decenter).
pub(super) fn aperture_lines(s: &Surface) -> Vec<String> {
    let Some(a) = s.aperture else {
        return Vec::new();
    };
    let ob = a.obscuration;
    let (cmd, x, y) = match a.shape {
        ApertureShape::SemiDiameter if !ob && a.decenter_mm == [0.0; 2] => {
            ("FLAP", 0.0, s.semi_aperture_mm)
        }
        ApertureShape::SemiDiameter => (if ob { "OBSC" } else { "CLAP" }, 0.0, s.semi_aperture_mm),
        ApertureShape::Circular { min_mm, max_mm } => {
            (if ob { "OBSC" } else { "CLAP" }, min_mm, max_mm)
        }
        ApertureShape::Rectangular {
            half_x_mm,
            half_y_mm,
        } => (if ob { "OBSQ" } else { "SQAP" }, half_x_mm, half_y_mm),
        ApertureShape::Elliptical {
            half_x_mm,
            half_y_mm,
        } => (if ob { "OBEL" } else { "ELAP" }, half_x_mm, half_y_mm),
    };
    let mut out = vec![format!("{cmd} {} {} 0", fmt(x), fmt(y))];
    if a.decenter_mm != [0.0; 2] {
        out.push(format!(
            "OBDC {} {}",
            fmt(a.decenter_mm[0]),
            fmt(a.decenter_mm[1])
        ));
    }
    out
}

/// Writes the lens as a .zmx file, atomically.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path.
///
/// # Errors
/// A gradient-index medium bounded by a decentred, tilted or rolled surface is refused (the
/// coordinate breaks of a moved surface would end OpticStudio's medium early).
///
/// A lens with two built-in glasses of one name from two vendors that no `GCAT` order tells
/// apart (Schott's F2 with Hikari's SF5: each name is in both catalogs) is refused, naming them,
/// since the file would be read back with another glass; and any error of the write.
pub fn write_file(lens: &Lens, extras: Option<&ZmxExtras>, path: &Path) -> Result<()> {
    let gcat = gcat_order(
        lens,
        extras.map(|e| e.glass_catalogs.clone()).unwrap_or_default(),
    );
    let mut order: Vec<&str> = gcat
        .iter()
        .filter_map(|c| crate::lens::material::vendor_of_gcat(c))
        .collect();
    order.extend(crate::lens::material::VENDOR_ORDER);
    for (i, s) in lens.surfaces.iter().enumerate() {
        if let Some(m) = gradient_unwritable(lens, i) {
            return Err(Error::invalid(format!(
                "{}: surface {i}: {m}",
                path.display()
            )));
        }
        if let Material::Catalog(g) = s.material {
            let found = crate::lens::material::find_in_vendors(g.name, &order);
            if let Some(h) = found.filter(|h| h.vendor != g.vendor) {
                return Err(Error::invalid(format!(
                    "{}: surface {i}: {}'s glass {} cannot be named in this .zmx file: with the other glasses' catalogs listed, GCAT finds {}'s {} first",
                    path.display(),
                    g.vendor,
                    g.name,
                    h.vendor,
                    h.name
                )));
            }
        }
    }
    crate::files::write_atomic(path, to_string(lens, extras).as_bytes())
}

/// Why the gradient-index medium around surface `i` cannot be written as OpticStudio's
/// Gradient 1 to 3 (`None` when it can, or when there is none).
fn gradient_unwritable(lens: &Lens, i: usize) -> Option<String> {
    let s = &lens.surfaces[i];
    let starts = matches!(s.material, Material::Gradient(_));
    let ends = i > 0 && matches!(lens.surfaces[i - 1].material, Material::Gradient(_));
    if (starts || ends) && is_moved(s) {
        Some("a decentred, tilted or rolled surface bounds a gradient-index medium; its coordinate breaks would end the medium in a .zmx file".into())
    } else {
        None
    }
}

/// True when the surface is decentred, tilted or rolled: written between coordinate breaks.
fn is_moved(s: &Surface) -> bool {
    let v = s.vec_local;
    s.pos_xy_mm != [0.0, 0.0] || v[0] != 0.0 || v[1] != 0.0 || s.roll_deg != 0.0
}
