//! Zemax OpticStudio sequential lens files (.zmx): reading and writing.
//!
//! # Reading
//! The file is decoded from UTF-16 (little or big endian, with or without a byte-order mark, as
//! OpticStudio writes it), UTF-8 or ASCII. tolray reads:
//!
//! - `UNIT MM|CM|IN|METER` (lengths are converted to mm once, at load);
//! - `SURF` blocks with `TYPE STANDARD`, `EVENASPH`, `ODDASPHE`, `TOROIDAL`, `PARAXIAL`,
//!   `DGRATING`, `QED_TYPE` (the Q-type asphere of type 0, Forbes' Qbfs on a conic:
//!   [`super::Shape::Qbfs`], or type 1, Qcon: [`super::Shape::Qcon`]) and `COORDBRK`; `CURV` (1/lens unit), `CONI`, `PARM` (even-asphere terms r² ..
//!   r¹⁶, odd-asphere terms r¹ .. r⁸, a toroid's radius of rotation and y² .. y¹⁴ terms, an ideal
//!   lens' focal length, a grating's lines per µm and order ([`super::Grating`]), or the
//!   coordinate break's decenters, tilts and order), a toroid's `XDAT` (Zernike
//!   terms are refused), a Q-type surface's `XDAT` (type, number of terms, normalization
//!   radius, coefficients),
//!   `DISZ` (a number, or `INFINITY` for the object), `DIAM` (the semi-diameter: the surface's
//!   size, which clips nothing, as in OpticStudio; `MEMA` when there is no `DIAM`; without
//!   either, the paraxial beam's size), hard apertures `CLAP`, `OBSC`, `SQAP`, `OBSQ`, `ELAP`,
//!   `OBEL` and `FLAP` (a circle of the semi-diameter) with `OBDC` decenters, which clip,
//!   `STOP`, `GLAS` (a catalog name, `___BLANK` model glasses with n_d and V_d, where V_d = 0
//!   means a constant index);
//! - the aperture `ENPD`, `FNUM`, `OBNA` or `FLOA`; fields `FTYP`, `XFLN`/`YFLN`/`FWGN` (or the
//!   older `XFLD`/`YFLD`/`FWGT`) with their vignetting factors `VDXN`/`VDYN`/`VCXN`/`VCYN`
//!   (a non-zero angle `VANN` is refused); wavelengths `WAVM` (or `WAVL`) and `PWAV`; `NAME`;
//!   `GCAT`; ray aiming `RAIM` (paraxial or real: [`Lens::ray_aiming`]). Angle and object-height
//!   fields become [`Lens::fields`] (see [`ZmxExtras::field_points`] for the angles' sign).
//!
//! SURF 0 is the object; the last SURF is the image plane, whose semi-diameter is the sensor's
//! half-diagonal (without one, the paraxial image height of the largest field). The stop clips
//! at its semi-diameter. tolray sizes the aperture by the stop's semi-aperture, so an `ENPD`, `FNUM` or
//! `OBNA` aperture is turned into the stop semi-diameter that gives that paraxial entrance pupil
//! at the primary wavelength (`FNUM` = EFL / EPD; `OBNA`: the marginal ray from the axial object
//! point has slope tan(asin NA)); with `FLOA` (or no aperture line) the stop's `DIAM` is used.
//!
//! Coordinate breaks are followed exactly as OpticStudio does (decenter x, y then tilt about x,
//! y, z with order flag 0; tilt z, y, x then decenter with order flag 1; right-handed, degrees;
//! the thickness is along the new z axis), and each lens surface's resulting vertex and axis
//! become its [`Surface::pos_xy_mm`] and [`Surface::vec_local`], and the frame's turn about
//! that axis its [`Surface::roll_deg`] where the surface is not symmetric about it. A mirror
//! tilted by 20° or more against the axis is a fold mirror, and so is any tilted mirror after
//! which the file's frame follows the reflected axis (coordinate break, mirror, coordinate
//! break: OpticStudio's way of writing an off-axis or fold mirror): the axis of everything after
//! it turns with the reflection, about the mirror's point on the axis ([`super::Fold`]), and the
//! lens stays described unfolded (so fold-mirror systems, periscopes included, open with the
//! paraxial model of their unfolded axis). A surface or an image plane turned by 90° or more
//! against the axis (other than by a fold mirror), and surfaces out of order along the axis,
//! cannot be represented and are errors; a decentred, tilted or rolled image plane is kept
//! ([`Lens::image_plane`]).
//! Flat `STANDARD` surfaces that change nothing (same medium on both sides, not the stop, no fixed
//! semi-diameter, no hard aperture) are the construction ("dummy") surfaces of coordinate-break sequences; they do
//! not become tolray surfaces (OpticStudio does not clip there either).
//!
//! Commands that change nothing tolray models (display, optimization, tolerancing, coatings,
//! ...) are skipped silently; unknown commands are skipped and listed in one warning (each with
//! its line);
//! surface types tolray cannot trace, mirrors, non-sequential files and malformed numbers are
//! errors naming the line.
//!
//! # Writing
//! [`to_string`] writes `UNIT MM`, the aperture (`ENPD` by default), fields, wavelengths, and a
//! `SURF` per tolray surface (`STANDARD`, `EVENASPH`, `ODDASPHE`, `TOROIDAL`, `PARAXIAL`,
//! `QED_TYPE` or `DGRATING`), with a `COORDBRK` pair around every surface that carries a decenter, a tilt or a
//! roll (the whole frame as tilts about x, y and z), so perturbed lenses survive the round trip,
//! and one more `COORDBRK` after a fold mirror (the axis' turn at its pivot).
//! Model
//! glasses are written as `___BLANK` model glasses (tolray's dispersion law between the lines
//! differs slightly from OpticStudio's model glass; n_d and V_d are exact), catalog glasses by
//! name. A `NOTE 0 tolray ...` line records what Zemax has no place for (the exact primary and
//! RGB wavelengths in nm and the sensor resolution), so JSON → .zmx → JSON is exact.

use super::material::{GlassCatalogs, Material, LAMBDA_D_NM};
use super::text::decode;
use super::{
    Aperture, ApertureShape, Grating, ImagePlane, Lens, Object, Sensor, Shape, Surface,
    SurfaceRole, N_ASPH,
};
use crate::error::{Error, ErrorKind, Result};
use crate::math::{Mat3, Vec3};
use super::field::{Field, FieldPoint, Vignetting};
use std::path::Path;

/// How a .zmx file defines the system aperture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ZmxAperture {
    /// `ENPD`: entrance pupil diameter, mm.
    EntrancePupilDiameter(f64),
    /// `FNUM`: image-space F-number, EFL / EPD.
    ImageSpaceFnum(f64),
    /// `OBNA`: object-space numerical aperture n sin θ of the marginal ray (finite objects).
    ObjectSpaceNa(f64),
    /// `FLOA`: float by stop size (the stop's semi-diameter).
    FloatByStop,
}

/// The field type of a .zmx file (`FTYP`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ZmxFieldType {
    /// 0: angle, degrees.
    AngleDeg,
    /// 1: object height, mm.
    ObjectHeightMm,
    /// 2: paraxial image height, mm.
    ParaxialImageHeightMm,
    /// 3: real image height, mm.
    RealImageHeightMm,
    /// Another OpticStudio field type, kept by number (its values are not converted).
    Other(i64),
}

impl ZmxFieldType {
    fn code(self) -> i64 {
        match self {
            ZmxFieldType::AngleDeg => 0,
            ZmxFieldType::ObjectHeightMm => 1,
            ZmxFieldType::ParaxialImageHeightMm => 2,
            ZmxFieldType::RealImageHeightMm => 3,
            ZmxFieldType::Other(c) => c,
        }
    }
    fn describe(self) -> String {
        match self {
            ZmxFieldType::AngleDeg => "angles".into(),
            ZmxFieldType::ObjectHeightMm => "object heights at an infinite object".into(),
            ZmxFieldType::ParaxialImageHeightMm => "paraxial image heights".into(),
            ZmxFieldType::RealImageHeightMm => "real image heights".into(),
            ZmxFieldType::Other(c) => format!("FTYP {c}"),
        }
    }
    fn is_length(self) -> bool {
        matches!(
            self,
            ZmxFieldType::ObjectHeightMm
                | ZmxFieldType::ParaxialImageHeightMm
                | ZmxFieldType::RealImageHeightMm
        )
    }
}

/// One field point of a .zmx file, in the units of its [`ZmxFieldType`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZmxField {
    /// x value.
    pub x: f64,
    /// y value.
    pub y: f64,
    /// Weight.
    pub weight: f64,
    /// Vignetting factors (`VDXN`, `VDYN`, `VCXN`, `VCYN`).
    pub vignetting: Vignetting,
}

/// One wavelength of a .zmx file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZmxWavelength {
    /// Wavelength, µm (as Zemax writes it).
    pub um: f64,
    /// Weight.
    pub weight: f64,
}

impl ZmxExtras {
    /// The file's field points as tolray fields, for commands to use when the user names none:
    /// angle fields as angles, object heights as heights (finite objects only), paraxial and
    /// real image heights as such. `None` for other field types (tolray has no such field), an
    /// object height at an infinite object, or a file without fields.
    ///
    /// # Examples
    /// ```
    /// use tolray::lens::material::GlassCatalogs;
    /// use tolray::lens::zemax;
    /// let text = std::fs::read_to_string(concat!(
    ///     env!("CARGO_MANIFEST_DIR"),
    ///     "/tests/data/zemax/cooke-triplet.zmx"
    /// ))?;
    /// let z = zemax::from_str(&text, &GlassCatalogs::builtin())?;
    /// let fields = z.extras.tolray_fields(&z.lens).unwrap();
    /// assert_eq!(fields.len(), z.extras.fields.len());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn tolray_fields(&self, lens: &Lens) -> Option<Vec<Field>> {
        self.field_points(lens)
            .map(|p| p.into_iter().map(|p| p.field).collect())
    }

    /// The file's field points as tolray field points (as [`ZmxExtras::tolray_fields`], with
    /// their weights and vignetting factors): what [`Lens::fields`] holds after reading.
    ///
    /// OpticStudio's positive field angle is a positive ray slope (the object below the axis);
    /// tolray's names the object's side ([`Field::AngleDeg`]), so an angle field is read with
    /// its signs changed: the file's +17° is tolray's -17°, the same rays. Object heights have
    /// the same sign in both.
    pub fn field_points(&self, lens: &Lens) -> Option<Vec<FieldPoint>> {
        field_points(self.field_type, &self.fields, lens)
    }
}

/// See [`ZmxExtras::field_points`].
fn field_points(
    field_type: ZmxFieldType,
    fields: &[ZmxField],
    lens: &Lens,
) -> Option<Vec<FieldPoint>> {
    if fields.is_empty() {
        return None;
    }
    let to = |f: &ZmxField| {
        let field = match field_type {
            // 0 - v, not -v: a zero stays +0 (labels print no "-0").
            ZmxFieldType::AngleDeg => Field::AngleDeg {
                x: 0.0 - f.x,
                y: 0.0 - f.y,
            },
            ZmxFieldType::ObjectHeightMm if lens.object != crate::Object::Infinite => {
                Field::HeightMm { x: f.x, y: f.y }
            }
            // Image heights name the image's side in both.
            ZmxFieldType::ParaxialImageHeightMm => Field::ImageHeightMm { x: f.x, y: f.y },
            ZmxFieldType::RealImageHeightMm => Field::RealImageHeightMm { x: f.x, y: f.y },
            _ => return None,
        };
        Some(FieldPoint {
            field,
            weight: f.weight,
            vignetting: f.vignetting,
        })
    };
    fields.iter().map(to).collect()
}

/// What a .zmx file holds beyond the [`Lens`]: kept so that a file read and written again keeps
/// its fields, wavelengths and aperture type.
#[derive(Clone, Debug, PartialEq)]
pub struct ZmxExtras {
    /// The aperture definition (`None` if the file has none).
    pub aperture: Option<ZmxAperture>,
    /// Field type.
    pub field_type: ZmxFieldType,
    /// Field points.
    pub fields: Vec<ZmxField>,
    /// Wavelengths.
    pub wavelengths: Vec<ZmxWavelength>,
    /// Index of the primary wavelength in `wavelengths` (from 0).
    pub primary: usize,
    /// Glass catalogs named by `GCAT`.
    pub glass_catalogs: Vec<String>,
    /// The file's `SURF` number of each tolray surface (dummy and coordinate-break surfaces have
    /// no tolray surface).
    pub surface_numbers: Vec<usize>,
    /// Where tolray's frame origin (the vertex of its surface 0) lies in the file's frame, whose
    /// origin is the vertex of `SURF 1`, mm: non-zero when dummy surfaces or coordinate breaks
    /// come first.
    pub first_vertex_mm: [f64; 3],
}

/// A lens read from a .zmx file, with the file's extras and the reader's warnings.
#[derive(Clone, Debug, PartialEq)]
pub struct ZmxLens {
    /// The lens.
    pub lens: Lens,
    /// Fields, wavelengths, aperture type and catalogs of the file.
    pub extras: ZmxExtras,
    /// Skipped commands and approximations, each naming its line.
    pub warnings: Vec<String>,
}

/// True if `path` ends in `.zmx` (any case).
pub fn is_zmx_path(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("zmx"))
}

/// Reads a .zmx file, looking glasses up in `catalogs`. Errors and warnings name the file.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path; otherwise as [`from_str`], prefixed with the path.
pub fn read_file(path: &Path, catalogs: &GlassCatalogs) -> Result<ZmxLens> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let mut z = from_bytes(&bytes, catalogs).map_err(|e| e.context(path.display()))?;
    for w in &mut z.warnings {
        *w = format!("{}: {w}", path.display());
    }
    Ok(z)
}

/// Parses the bytes of a .zmx file in any of the supported encodings.
///
/// # Errors
/// As [`from_str`].
pub fn from_bytes(bytes: &[u8], catalogs: &GlassCatalogs) -> Result<ZmxLens> {
    from_str(&decode(bytes), catalogs)
}

fn parse_err(line: usize, msg: impl std::fmt::Display) -> Error {
    Error::new(ErrorKind::Parse, format!("line {line}: {msg}"))
}

fn invalid(line: usize, msg: impl std::fmt::Display) -> Error {
    Error::invalid(format!("line {line}: {msg}"))
}

/// A finite number, or an error naming the line and what it was.
fn number(tok: Option<&&str>, line: usize, what: &str) -> Result<f64> {
    let tok = tok.ok_or_else(|| parse_err(line, format!("{what}: missing number")))?;
    match tok.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(parse_err(
            line,
            format!("{what}: \"{tok}\" is not a finite number"),
        )),
    }
}

fn numbers(args: &[&str], line: usize, what: &str) -> Result<Vec<f64>> {
    args.iter().map(|t| number(Some(t), line, what)).collect()
}

/// A value with the line it came from.
#[derive(Clone, Debug)]
struct At<T> {
    v: T,
    line: usize,
}

fn at<T>(v: T, line: usize) -> Option<At<T>> {
    Some(At { v, line })
}

/// One `SURF` block as written.
#[derive(Clone, Debug, Default)]
struct RawSurf {
    line: usize,
    ty: Option<At<String>>,
    curv: Option<At<f64>>,
    coni: Option<At<f64>>,
    parm: Vec<(usize, f64, usize)>,
    /// Extra data (`XDAT`): number, value, line.
    xdat: Vec<(usize, f64, usize)>,
    /// `None` value: INFINITY.
    disz: Option<At<Option<f64>>>,
    /// Semi-diameter and whether it is fixed (solve type 1).
    diam: Option<At<(f64, bool)>>,
    mema: Option<At<f64>>,
    stop: Option<usize>,
    glas: Option<At<Vec<String>>>,
    /// Aperture commands (`CLAP`, `OBSC`, `SQAP`, `OBSQ`, `ELAP`, `OBEL`, `FLAP`) with their
    /// numbers, and the aperture decenter (`OBDC`).
    aperture: Option<At<(String, Vec<f64>)>>,
    aperture_decenter: Option<At<[f64; 2]>>,
}

impl RawSurf {
    /// The surface's hard aperture in mm (`None`: only a semi-diameter, which does not clip).
    fn hard_aperture(&self, scale: f64) -> Result<Option<Aperture>> {
        let Some(At {
            v: (cmd, nums),
            line,
        }) = &self.aperture
        else {
            if let Some(d) = &self.aperture_decenter {
                if d.v != [0.0; 2] {
                    return Err(invalid(
                        d.line,
                        "OBDC (aperture decenter) on a surface without an aperture",
                    ));
                }
            }
            return Ok(None);
        };
        let n = |i: usize| nums.get(i).copied().unwrap_or(0.0) * scale;
        let (a, b) = (n(0), n(1));
        let shape = match cmd.as_str() {
            "FLAP" => ApertureShape::SemiDiameter,
            "CLAP" | "OBSC" => ApertureShape::Circular {
                min_mm: a,
                max_mm: b,
            },
            "SQAP" | "OBSQ" => ApertureShape::Rectangular {
                half_x_mm: a,
                half_y_mm: b,
            },
            _ => ApertureShape::Elliptical {
                half_x_mm: a,
                half_y_mm: b,
            },
        };
        let ap = Aperture {
            shape,
            decenter_mm: self
                .aperture_decenter
                .as_ref()
                .map_or([0.0; 2], |d| [d.v[0] * scale, d.v[1] * scale]),
            obscuration: cmd.starts_with("OB"),
        };
        ap.validate()
            .map_err(|e| invalid(*line, format!("{cmd}: {}", e.full_message())))?;
        Ok(Some(ap))
    }
    fn type_name(&self) -> String {
        self.ty
            .as_ref()
            .map_or_else(|| "STANDARD".to_string(), |t| t.v.clone())
    }
    fn type_line(&self) -> usize {
        self.ty.as_ref().map_or(self.line, |t| t.line)
    }
    fn parm(&self, i: usize) -> f64 {
        self.parm
            .iter()
            .rev()
            .find(|p| p.0 == i)
            .map_or(0.0, |p| p.1)
    }
    fn thickness(&self) -> Result<f64> {
        match &self.disz {
            None => Ok(0.0),
            Some(At { v: Some(t), .. }) => Ok(*t),
            Some(At { v: None, line }) => Err(invalid(
                *line,
                "DISZ INFINITY is only allowed on the object surface (SURF 0)",
            )),
        }
    }
}

/// The header commands as written.
#[derive(Clone, Debug, Default)]
struct Header {
    unit: Option<At<f64>>,
    name: String,
    notes: Vec<At<String>>,
    aperture: Option<At<ZmxAperture>>,
    ftyp: Option<At<Vec<f64>>>,
    xfln: Option<Vec<f64>>,
    yfln: Option<At<Vec<f64>>>,
    fwgn: Option<Vec<f64>>,
    /// `VDXN`, `VDYN`, `VCXN`, `VCYN`, `VANN`: each field's vignetting factors.
    vign: [Option<At<Vec<f64>>>; 5],
    wavm: Vec<(usize, f64, f64, usize)>,
    wavl: Option<At<Vec<f64>>>,
    wwgt: Option<Vec<f64>>,
    pwav: Option<At<usize>>,
    gcat: Vec<String>,
    /// Ray aiming type: 0 off, 1 paraxial, 2 real.
    raim: Option<At<i64>>,
}

/// Commands that change nothing tolray models: skipped without a warning.
const SILENT: &[&str] = &[
    "VERS", "PFIL", "LANG", "ENVD", "GFAC", "PUSH", "SDMA", "ROPD", "PICB", "POLS", "GLRS", "GSTD",
    "NSCD", "COFN", "BLNK", "TOL", "TOLE", "MOFF", "CONF", "OPDX", "EFFL", "PUPD", "TCED", "DMFS",
    "ISNA", "ZVDX", "ZVDY", "ZVCX", "ZVCY", "ZVAN", "WWGN", "WAVN", "MNCA", "MNEA", "MNCG", "MNEG",
    "MXCA", "MXCG", "RGLA", "TRAC", "TCMM", "PMAG", "TOTR", "FIMP", "SCOL", "UDAD", "USAP", "EDGE",
    "OMMA", "HIDE", "MIRR", "SLAB", "POPS", "COMM", "MAZH", "PZUP", "PPAR", "VPAR", "VCON", "VDSZ",
    "COAT", "TCE", "PKUP", "SCTH", "CLAT", "BLAT",
];

/// The vignetting-factor commands, in the order of `Header::vign`.
const VIGNETTING: [&str; 5] = ["VDXN", "VDYN", "VCXN", "VCYN", "VANN"];

/// Hard-aperture commands of a surface: clear and obscuring circles, rectangles and ellipses,
/// and the floating aperture (a circle of the semi-diameter).
const APERTURES: &[&str] = &["CLAP", "OBSC", "SQAP", "OBSQ", "ELAP", "OBEL", "FLAP"];

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

fn in_surf<'a>(s: Option<&'a mut RawSurf>, line: usize, cmd: &str) -> Result<&'a mut RawSurf> {
    s.ok_or_else(|| parse_err(line, format!("{cmd} outside a SURF block")))
}

/// The medium given by a `GLAS` line.
fn glass(
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
    if let Some((g, what)) = super::material::same_material(name) {
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

fn rotation_xyz_deg(a: f64, b: f64, g: f64) -> Mat3<f64> {
    super::system::rotation_xyz_deg([a, b, g])
}

/// The rotation of a coordinate break (PARM 3..5 degrees; PARM 6 = 0: about x, the new y, the
/// new z; otherwise about z, the new y, the new x).
fn cb_rotation(s: &RawSurf) -> Mat3<f64> {
    let (a, b, g) = (s.parm(3), s.parm(4), s.parm(5));
    if s.parm(6) == 0.0 {
        rotation_xyz_deg(a, b, g)
    } else {
        Mat3::from_tilt_deg(a, b, g)
    }
}

/// A mirror tilted by this much or more against the axis is a fold mirror (the axis of the
/// surfaces after it turns with the reflection) whatever the coordinate breaks after it say; a
/// mirror tilted less is one when the file's frame after it follows the reflected axis
/// (`Walker::follows_reflection`: an off-axis mirror written as OpticStudio writes a fold), and
/// otherwise a tilted mirror on the axis (a tolerance tilt, say).
const FOLD_MIN_DEG: f64 = 20.0;

/// The rotation turning the unit vector `u` onto the unit vector `v` by the shortest arc
/// (`None` when they are opposite).
fn turn_onto(u: Vec3<f64>, v: Vec3<f64>) -> Option<Mat3<f64>> {
    let k = u.cross(v);
    let (s, c) = (k.norm(), u.dot(v));
    if s <= 1e-12 {
        return (c > 0.0).then(Mat3::identity);
    }
    let k = k * (1.0 / s);
    // Rodrigues: R = I + sin K + (1 - cos) K², K the cross-product matrix of the unit axis.
    let kk = [[0.0, -k.z, k.y], [k.z, 0.0, -k.x], [-k.y, k.x, 0.0]];
    let mut rows = [[0.0; 3]; 3];
    for (i, row) in rows.iter_mut().enumerate() {
        for (j, e) in row.iter_mut().enumerate() {
            let k2: f64 = (0..3).map(|m| kk[i][m] * kk[m][j]).sum();
            *e = f64::from(u8::from(i == j)) + s * kk[i][j] + (1.0 - c) * k2;
        }
    }
    Some(Mat3 {
        rows: rows.map(|r| Vec3::cst(r[0], r[1], r[2])),
    })
}

/// The tilts about x, the new y and the new z (degrees, `Rx(a) Ry(b) Rz(g)`) of a rotation.
fn angles_of(r: &Mat3<f64>) -> [f64; 3] {
    // Rx(a) Ry(b) Rz(g) has third column (sin b, -sin a cos b, cos a cos b) and first row
    // (cos b cos g, -cos b sin g, sin b).
    let b = r.rows[0].z.clamp(-1.0, 1.0).asin();
    let a = (-r.rows[1].z).atan2(r.rows[2].z);
    let g = (-r.rows[0].y).atan2(r.rows[0].x);
    // (+ 0.0 turns a negative zero into zero.)
    [
        a.to_degrees() + 0.0,
        b.to_degrees() + 0.0,
        g.to_degrees() + 0.0,
    ]
}

/// Snaps a rotation within 1e-12 of the identity to it, so that a coordinate break and its exact
/// reverse leave no rounding residue.
fn snap(r: Mat3<f64>) -> Mat3<f64> {
    let i = Mat3::<f64>::identity();
    let close = r.rows.iter().zip(i.rows.iter()).all(|(a, b)| {
        (a.x - b.x).abs() <= 1e-12 && (a.y - b.y).abs() <= 1e-12 && (a.z - b.z).abs() <= 1e-12
    });
    if close {
        i
    } else {
        r
    }
}

fn finite_frame(o: &Vec3<f64>, r: &Mat3<f64>) -> bool {
    [o.x, o.y, o.z].iter().all(|v| v.is_finite())
        && r.rows
            .iter()
            .all(|v| v.x.is_finite() && v.y.is_finite() && v.z.is_finite())
}

fn is_identity(r: &Mat3<f64>) -> bool {
    *r == Mat3::identity()
}

/// A tolray surface being built, with the SURF it came from.
struct Built {
    surface: Surface,
    raw: RawSurf,
    index: usize,
    has_diam: bool,
}

/// Follows OpticStudio's coordinate system through the surfaces, collecting lens surfaces.
struct Walker {
    /// Origin and local-to-global axes of the current coordinate system (object frame, mm).
    origin: Vec3<f64>,
    rot: Mat3<f64>,
    /// Axial (global z) travel since the last lens surface: exact sums of the file's thicknesses
    /// whenever the frame is untilted.
    pending: f64,
    /// Travel from the object to the first lens surface.
    object_gap: Option<f64>,
    /// The origin when the first lens surface was placed.
    first_vertex: Vec3<f64>,
    /// Direction of travel along the axis: +1, flipped by each mirror.
    dir: f64,
    /// The medium the light is in.
    medium: Material,
    last_cb_line: Option<usize>,
    /// The image plane's pose, set when the image surface is reached.
    image_plane: ImagePlane,
    /// The current leg of the axis: tolray's unfolded coordinates to the file's frame (the
    /// identity rotation until a fold mirror turns it; see [`super::Fold`]).
    leg_rot: Mat3<f64>,
    leg_t: Vec3<f64>,
    /// True after the first fold.
    folded: bool,
    stop_line: Option<usize>,
    built: Vec<Built>,
    scale: f64,
}

impl Walker {
    fn axis(&self) -> Vec3<f64> {
        self.rot.apply(Vec3::cst(0.0, 0.0, 1.0))
    }

    /// Moves the origin by `d` (global) and counts its axial part (along the leg's axis).
    fn shift(&mut self, d: Vec3<f64>) {
        self.origin = self.origin + d;
        self.pending += self.leg_rot.apply_t(d).z;
    }

    /// The current frame in unfolded coordinates: origin, axes and axis. Tiny residues of a
    /// fold's turn (under 1e-12) are dropped, so a surface on the folded axis is untilted.
    fn unfolded(&self) -> (Vec3<f64>, Mat3<f64>, Vec3<f64>) {
        if !self.folded {
            return (self.origin, self.rot, self.axis());
        }
        let tiny = |v: f64| if v.abs() <= 1e-12 { 0.0 } else { v };
        let o = self.leg_rot.apply_t(self.origin - self.leg_t);
        let r = snap(self.leg_rot.transpose() * self.rot);
        let a = r.apply(Vec3::cst(0.0, 0.0, 1.0));
        (Vec3::cst(tiny(o.x), tiny(o.y), o.z), r, a)
    }

    /// After the fold mirror just placed (tilted by [`FOLD_MIN_DEG`] or more against the leg's
    /// axis): the axis turns by the mirror's reflection of it, about the mirror's point on the
    /// axis. Returns the fold kept on the mirror.
    fn fold(&mut self, n: Vec3<f64>, dir_before: f64) -> Option<super::Fold> {
        let n = n.normalized();
        let d_in = Vec3::cst(0.0, 0.0, dir_before);
        let v = d_in - n * (2.0 * d_in.dot(n));
        let u = Vec3::cst(0.0, 0.0, -dir_before);
        let r = super::system::clean_rotation(turn_onto(u, v)?);
        let fold = super::Fold {
            tilt_deg: angles_of(&r),
            pivot_mm: 0.0,
        };
        let r = fold.rotation();
        let z = self.leg_rot.apply_t(self.origin - self.leg_t).z;
        let p = Vec3::cst(0.0, 0.0, z);
        self.leg_t = self.leg_t + self.leg_rot.apply(p - r.apply(p));
        self.leg_rot = self.leg_rot * r;
        self.folded = true;
        // The travel to the next surface counts from the fold's pivot: a mirror off the axis
        // lies off the pivot along the turned axis too.
        self.pending = self.leg_rot.apply_t(self.origin - self.leg_t).z - z;
        Some(fold)
    }

    /// True when the mirror with unfolded normal `n` is tilted against the leg's axis and the
    /// file's frame `frame_after` (global) after it has its z axis along the reflected light,
    /// against the direction of travel after the mirror, as thicknesses after a mirror are
    /// negative.
    fn follows_reflection(&self, n: Vec3<f64>, frame_after: Mat3<f64>) -> bool {
        let n = n.normalized();
        if n.z.abs() >= 1.0 - 1e-15 {
            return false;
        }
        let d_in = Vec3::cst(0.0, 0.0, self.dir);
        let v = d_in - n * (2.0 * d_in.dot(n));
        let after = self
            .leg_rot
            .apply_t(frame_after.apply(Vec3::cst(0.0, 0.0, 1.0)));
        (v + after * self.dir).norm() <= 1e-9
    }

    /// Travels `t` mm along the current z axis.
    fn travel(&mut self, t: f64, line: usize) -> Result<()> {
        self.shift(self.axis() * t);
        if !finite_frame(&self.origin, &self.rot) || !self.pending.is_finite() {
            return Err(invalid(
                line,
                "this moves the coordinate system to infinity",
            ));
        }
        Ok(())
    }

    fn coordinate_break(&mut self, s: &RawSurf, warnings: &mut Vec<String>) -> Result<()> {
        if let Some(l) = s.stop {
            return Err(invalid(l, "a coordinate break cannot be the stop"));
        }
        if let Some(g) = &s.glas {
            warnings.push(format!(
                "line {}: GLAS on a coordinate break ignored (the medium continues)",
                g.line
            ));
        }
        let decenter = Vec3::cst(s.parm(1) * self.scale, s.parm(2) * self.scale, 0.0);
        if s.parm(6) == 0.0 {
            // Decenter, then tilt about x, the new y, the new z.
            self.shift(self.rot.apply(decenter));
            self.rot = snap(self.rot * cb_rotation(s));
        } else {
            // Tilt about z, the new y, the new x, then decenter.
            self.rot = snap(self.rot * cb_rotation(s));
            self.shift(self.rot.apply(decenter));
        }
        self.last_cb_line = Some(s.type_line());
        self.travel(s.thickness()? * self.scale, s.type_line())
    }

    /// The Forbes polynomials of a `QED_TYPE` surface (OpticStudio's Q-type asphere) into
    /// `asph`: XDAT 1 the type (0: Qbfs, 1: Qcon; others are refused), XDAT 2 the number of terms,
    /// XDAT 3 the normalization radius, XDAT 4.. the coefficients a_0, a_1, ... (lens units).
    fn q_type(
        &self,
        s: &RawSurf,
        asph: &mut [f64; N_ASPH],
        warnings: &mut Vec<String>,
    ) -> Result<Shape> {
        let get = |n: usize| s.xdat.iter().rev().find(|x| x.0 == n);
        let line_of = |n: usize| get(n).map_or(s.type_line(), |x| x.2);
        let value = |n: usize| get(n).map_or(0.0, |x| x.1);
        let ty = value(1);
        if ty != 0.0 && ty != 1.0 {
            return Err(invalid(
                line_of(1),
                format!(
                    "XDAT 1 = {ty}: Q-type asphere type {ty}; tolray reads type 0 (Forbes' Qbfs polynomials) and type 1 (Qcon), each on a conic"
                ),
            ));
        }
        let terms = value(2);
        if !((0.0..=1000.0).contains(&terms) && terms.fract() == 0.0) {
            return Err(invalid(
                line_of(2),
                format!("XDAT 2 = {terms}: the number of Q terms must be a whole number"),
            ));
        }
        let terms = terms as usize;
        let norm = value(3) * self.scale;
        for m in 0..terms {
            let v = value(4 + m);
            if m >= N_ASPH {
                if v != 0.0 {
                    return Err(invalid(
                        line_of(4 + m),
                        format!(
                            "XDAT {} = {v}: Q term a_{m}; tolray traces Q terms a_0 to a_{}",
                            4 + m,
                            N_ASPH - 1
                        ),
                    ));
                }
                continue;
            }
            // A departure: lens units to mm.
            asph[m] = v * self.scale;
        }
        if asph.iter().any(|&a| a != 0.0) && !(norm > 0.0 && norm.is_finite()) {
            return Err(invalid(
                line_of(3),
                format!(
                    "XDAT 3 = {}: the Q terms need a positive normalization radius",
                    value(3)
                ),
            ));
        }
        if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.0 >= 4 + terms && x.1 != 0.0) {
            warnings.push(format!(
                "line {line}: XDAT {n} = {v} ignored: beyond the {terms} Q terms of XDAT 2"
            ));
        }
        let norm_radius_mm = if norm > 0.0 { norm } else { 1.0 };
        Ok(if ty == 0.0 {
            Shape::Qbfs { norm_radius_mm }
        } else {
            Shape::Qcon { norm_radius_mm }
        })
    }

    /// A STANDARD or EVENASPH surface: a lens surface, or a dummy that only moves the frame.
    ///
    /// `frame_after`: the file's frame after the coordinate breaks that follow the surface
    /// (global), which tells whether a tilted mirror is a fold mirror.
    fn surface(
        &mut self,
        k: usize,
        s: &RawSurf,
        frame_after: Mat3<f64>,
        catalogs: &GlassCatalogs,
        warnings: &mut Vec<String>,
    ) -> Result<()> {
        let ty = s.type_name();
        let scale = self.scale;
        let c = s.curv.as_ref().map_or(0.0, |c| c.v) / scale;
        let mut asph = [0.0; N_ASPH];
        let mut shape = Shape::Even;
        let mut grating = Grating {
            lines_per_um: 0.0,
            order: 0.0,
        };
        for &(p, v, line) in &s.parm {
            match ty.as_str() {
                "EVENASPH" if (1..=N_ASPH).contains(&p) => {
                    // a_{2p} ρ^{2p}: lens units^{1-2p} to mm^{1-2p}.
                    asph[p - 1] = v * scale.powi(1 - 2 * p as i32);
                }
                "ODDASPHE" if (1..=N_ASPH).contains(&p) => {
                    // β_p ρ^p: lens units^{1-p} to mm^{1-p}.
                    shape = Shape::Odd;
                    asph[p - 1] = v * scale.powi(1 - p as i32);
                }
                "TOROIDAL" if p == 1 => {
                    // The radius of rotation; 0 means none (a cylinder).
                    let r = v * scale;
                    let c_rot = if r == 0.0 { 0.0 } else { 1.0 / r };
                    if !c_rot.is_finite() {
                        return Err(invalid(line, format!("PARM 1 = {v}: radius of rotation")));
                    }
                    shape = Shape::Toroidal { c_rot };
                }
                "PARAXIAL" if p == 1 => {
                    if v == 0.0 {
                        return Err(invalid(
                            line,
                            "PARM 1 = 0: a PARAXIAL surface needs a focal length",
                        ));
                    }
                    shape = Shape::Paraxial {
                        focal_mm: v * scale,
                    };
                }
                // The OPD mode changes how OpticStudio computes optical path, not rays.
                "PARAXIAL" if p == 2 => {}
                // Lines per µm (whatever the lens unit) and the diffraction order.
                "DGRATING" if p == 1 => grating.lines_per_um = v,
                "DGRATING" if p == 2 => grating.order = v,
                "TOROIDAL" if (2..=N_ASPH).contains(&p) => {
                    // α_{p-1} y^{2(p-1)}.
                    let j = p - 1;
                    asph[j - 1] = v * scale.powi(1 - 2 * j as i32);
                }
                _ if v != 0.0 => {
                    let what = match ty.as_str() {
                        "EVENASPH" => "tolray reads even-asphere terms r^2 to r^16 (PARM 1 to 8)",
                        "ODDASPHE" => "tolray reads odd-asphere terms r^1 to r^8 (PARM 1 to 8)",
                        "TOROIDAL" => {
                            "tolray reads the radius of rotation (PARM 1) and y^2 to y^14 (PARM 2 to 8)"
                        }
                        "PARAXIAL" => "a PARAXIAL surface has a focal length (PARM 1) and an OPD mode (PARM 2)",
                        "DGRATING" => "a DGRATING surface has lines per µm (PARM 1) and an order (PARM 2)",
                        "QED_TYPE" => "a Q-type surface keeps its data in XDAT",
                        _ => "a STANDARD surface has no parameters",
                    };
                    warnings.push(format!("line {line}: PARM {p} = {v} ignored: {what}"));
                }
                _ => {}
            }
        }
        if ty == "ODDASPHE" {
            shape = Shape::Odd;
        }
        if ty == "PARAXIAL" {
            if !matches!(shape, Shape::Paraxial { .. }) {
                return Err(invalid(
                    s.type_line(),
                    "a PARAXIAL surface needs its focal length (PARM 1)",
                ));
            }
            if c != 0.0 || s.coni.as_ref().is_some_and(|k| k.v != 0.0) {
                let l = s.curv.as_ref().map_or(s.line, |c| c.line);
                return Err(invalid(
                    l,
                    "a PARAXIAL surface is flat (CURV and CONI must be 0)",
                ));
            }
        }
        if ty == "TOROIDAL" {
            if !matches!(shape, Shape::Toroidal { .. }) {
                shape = Shape::Toroidal { c_rot: 0.0 };
            }
            // XDAT 1: the number of Zernike terms, XDAT 2: their normalization radius, XDAT 3..:
            // the coefficients.
            let terms = s.xdat.iter().rev().find(|x| x.0 == 1).map_or(0.0, |x| x.1);
            if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.0 >= 3 && x.1 != 0.0) {
                if terms > 0.0 {
                    return Err(invalid(
                        line,
                        format!(
                            "XDAT {n} = {v}: a Zernike term on a TOROIDAL surface; tolray traces toroids without Zernike terms"
                        ),
                    ));
                }
            }
        } else if ty == "QED_TYPE" {
            shape = self.q_type(s, &mut asph, warnings)?;
        } else if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.1 != 0.0) {
            warnings.push(format!(
                "line {line}: XDAT {n} = {v} (extra surface data) ignored: a {ty} surface has none tolray reads"
            ));
        }
        let mirror = s.glas.as_ref().is_some_and(|g| {
            g.v.first()
                .is_some_and(|n| n.eq_ignore_ascii_case("MIRROR"))
        });
        // A mirror sends the light back through the medium it came in.
        let material = match &s.glas {
            _ if mirror => self.medium.clone(),
            Some(g) => glass(&g.v, g.line, catalogs, warnings)?,
            None => Material::Air,
        };
        let diam = s.diam.as_ref().map(|d| (d.v.0 * scale, d.v.1));
        let aperture = s.hard_aperture(scale)?;
        let dummy = ty == "STANDARD"
            && !mirror
            && c == 0.0
            && s.stop.is_none()
            && material == self.medium
            && aperture.is_none()
            && !diam.is_some_and(|d| d.1);
        if !dummy {
            let (origin, rot, axis) = self.unfolded();
            if axis.z <= 1e-9 {
                return Err(invalid(
                    s.line,
                    format!(
                        "SURF {k} is turned by 90 degrees or more against the axis by coordinate breaks; tolray turns the axis only at a fold mirror (a mirror tilted {FOLD_MIN_DEG} degrees or more)"
                    ),
                ));
            }
            // (Before the first surface, a negative travel is a virtual object's distance.)
            if self.pending * self.dir < 0.0 && !self.built.is_empty() {
                return Err(invalid(
                    s.line,
                    format!(
                        "SURF {k} lies {} mm before the previous surface along the light's path; tolray needs the surfaces in order along the axis (thicknesses are negative after a mirror)",
                        self.pending.abs()
                    ),
                ));
            }
            match self.built.last_mut() {
                Some(prev) => prev.surface.d_next_mm = self.pending,
                None => {
                    self.object_gap = Some(self.pending);
                    self.first_vertex = self.origin;
                    self.leg_t = Vec3::cst(0.0, 0.0, self.origin.z);
                }
            }
            self.pending = 0.0;
            if let Some(l) = s.stop {
                if let Some(first) = self.stop_line {
                    return Err(invalid(
                        l,
                        format!("a second STOP (the first is at line {first})"),
                    ));
                }
                self.stop_line = Some(l);
            }
            // The semi-diameter: DIAM, else MEMA, else a floating aperture's own value (FLAP's
            // second number); surfaces without one get the paraxial beam's size later.
            let flap = s
                .aperture
                .as_ref()
                .filter(|a| a.v.0 == "FLAP")
                .and_then(|a| a.v.1.get(1))
                .map(|r| r * scale);
            let semi = diam
                .map(|d| d.0)
                .filter(|&d| d > 0.0)
                .or_else(|| s.mema.as_ref().map(|m| m.v * scale).filter(|&m| m > 0.0))
                .or(flap.filter(|&r| r > 0.0));
            let is_stop = s.stop.is_some();
            // A flat stop in air is a bare aperture (DeepLens' "Aperture").
            let role = if mirror {
                SurfaceRole::Mirror
            } else if is_stop
                && ty == "STANDARD"
                && c == 0.0
                && self.medium.is_air()
                && material.is_air()
            {
                SurfaceRole::Aperture
            } else {
                SurfaceRole::Refractive
            };
            let vec_local = if is_identity(&rot) {
                [0.0, 0.0, 1.0]
            } else {
                [axis.x, axis.y, axis.z]
            };
            let mut surface = Surface {
                role,
                c,
                k: s.coni.as_ref().map_or(0.0, |c| c.v),
                asph,
                shape,
                semi_aperture_mm: semi.unwrap_or(0.0),
                aperture,
                d_next_mm: 0.0,
                material: material.clone(),
                is_stop,
                pos_xy_mm: [origin.x, origin.y],
                vec_local,
                roll_deg: 0.0,
                grating: (ty == "DGRATING").then_some(grating),
                fold: None,
            };
            // A coordinate break that rolls the frame about the surface's axis matters where
            // the surface is not symmetric about it (toroid, grating, a non-circular or
            // decentred aperture); elsewhere it changes nothing and is dropped.
            let roll = super::system::roll_of(&rot, surface.vec_local);
            if roll != 0.0 && !surface.is_axially_symmetric() {
                surface.roll_deg = roll;
            }
            // A mirror tilted far enough against the axis is a fold mirror, and so is any
            // tilted mirror after which the file's frame follows the reflected axis (OpticStudio's
            // coordinate break, mirror, coordinate break): the surfaces after it are placed on
            // the reflected axis, so the unfolded model's gaps are the file's thicknesses and
            // its paraxial model that of OpticStudio, which ignores the coordinate breaks.
            if mirror
                && (axis.z < FOLD_MIN_DEG.to_radians().cos()
                    || self.follows_reflection(axis, frame_after))
            {
                surface.fold = self.fold(axis, self.dir);
                if surface.fold.is_none() {
                    return Err(invalid(
                        s.line,
                        format!("SURF {k} is a mirror at grazing incidence to the axis"),
                    ));
                }
            }
            self.built.push(Built {
                surface,
                raw: s.clone(),
                index: k,
                has_diam: semi.is_some(),
            });
            if mirror {
                self.dir = -self.dir;
            }
        }
        self.medium = material;
        let line = s.disz.as_ref().map_or(s.line, |d| d.line);
        self.travel(s.thickness()? * scale, line)
    }

    /// The image surface closes the last gap and gives the sensor's half-diagonal (`None`
    /// without a `DIAM`: the caller sizes it by the fields).
    fn image(&mut self, img: &RawSurf) -> Result<Option<f64>> {
        let ty = img.type_name();
        if !matches!(ty.as_str(), "STANDARD" | "EVENASPH") {
            return Err(invalid(
                img.type_line(),
                format!("image surface type {ty} is not supported: the image is a plane"),
            ));
        }
        if img.curv.as_ref().is_some_and(|c| c.v != 0.0)
            || (ty == "EVENASPH" && img.parm.iter().any(|p| p.1 != 0.0))
        {
            let l = img.curv.as_ref().map_or(img.line, |c| c.line);
            return Err(invalid(
                l,
                "the image surface is curved; tolray's image is a plane",
            ));
        }
        if let Some(l) = img.stop {
            return Err(invalid(l, "the image surface cannot be the stop"));
        }
        // A tilted, rolled or decentred image plane keeps its pose (in the current leg of the
        // axis); one turned by 90 degrees or more against that leg is not a plane the light
        // reaches along it.
        let (origin, rot, axis) = self.unfolded();
        if axis.z <= 1e-9 {
            return Err(invalid(
                self.last_cb_line.unwrap_or(img.line),
                format!("the image plane is turned by 90 degrees or more against the axis by coordinate breaks (the last one is here); tolray turns the axis only at a fold mirror (a mirror tilted {FOLD_MIN_DEG} degrees or more)"),
            ));
        }
        let normal = if is_identity(&rot) {
            [0.0, 0.0, 1.0]
        } else {
            [axis.x, axis.y, axis.z]
        };
        self.image_plane = ImagePlane {
            decenter_mm: [origin.x, origin.y],
            normal,
            roll_deg: super::system::roll_of(&rot, normal),
        };
        // An image surface before the last lens surface along the light's path is a virtual
        // image (OpticStudio's negative image thickness): the rays are extended backwards to it.
        let Some(last) = self.built.last_mut() else {
            return Err(Error::invalid(
                "the file has no lens surface between the object and the image",
            ));
        };
        last.surface.d_next_mm = self.pending;
        let r_sensor = img.diam.as_ref().map_or(0.0, |d| d.v.0 * self.scale);
        if r_sensor < 0.0 || !r_sensor.is_finite() {
            return Err(invalid(
                img.diam.as_ref().map_or(img.line, |d| d.line),
                format!("the image semi-diameter (DIAM) {r_sensor} mm must be positive"),
            ));
        }
        Ok((r_sensor > 0.0).then_some(r_sensor))
    }
}

/// The object distance in mm (`None` at infinity), checking what SURF 0 may hold.
fn object_distance(
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
        // A negative thickness is a virtual object behind the first surface.
        Some(At { v: Some(d), line }) if *d == 0.0 || !d.is_finite() => {
            return Err(invalid(
                *line,
                format!("object distance {d}: it must be finite and not 0 (or INFINITY; negative for a virtual object)"),
            ))
        }
        Some(At { v: Some(d), .. }) => Some(d * scale),
    };
    Ok((distance, medium))
}

/// Field type and points (lengths in mm), with their vignetting factors.
fn fields(h: &Header, scale: f64) -> Result<(ZmxFieldType, Vec<ZmxField>)> {
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

/// The file's wavelengths, the primary index, and tolray's primary, RGB and sensor resolution.
struct Spectrum {
    wavelengths: Vec<ZmxWavelength>,
    primary: usize,
    primary_nm: f64,
    rgb_nm: [f64; 3],
    sensor_res: [u32; 2],
}

fn spectrum(h: &Header, warnings: &mut Vec<String>) -> Result<Spectrum> {
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

fn build(
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
            | "QED_TYPE" => {
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
                return Err(invalid(
                    s.type_line(),
                    format!(
                        "surface type {other} (SURF {k}) is not supported: tolray reads STANDARD, EVENASPH, ODDASPHE, TOROIDAL, PARAXIAL, DGRATING, QED_TYPE and COORDBRK"
                    ),
                ))
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
    if let Object::Finite { distance_mm } = lens.object {
        if distance_mm == 0.0 {
            return Err(invalid(
                built[0].raw.line,
                "the first lens surface lies on the object plane",
            ));
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
fn group_warnings(warnings: Vec<String>) -> Vec<String> {
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
fn size_by_beam(
    lens: &mut Lens,
    built: &[Built],
    missing: &[usize],
    sensor: bool,
    field_type: ZmxFieldType,
    fields: &[ZmxField],
    warnings: &mut Vec<String>,
) -> Result<()> {
    use super::paraxial::{beam_semi_diameters, ParaxialField};
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

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * b.abs()
}

fn check_rim(s: &Surface, line: usize, index: usize) -> Result<()> {
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
fn stop_semi_aperture(
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
fn wavelengths(h: &Header, warnings: &mut Vec<String>) -> Result<(Vec<ZmxWavelength>, usize)> {
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
            .filter(|x| x.0 >= 1 && n_max.map_or(true, |n| x.0 <= n))
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
                    "wavelength {} µm: give micrometres between 0.1 and 20",
                    w.um
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
fn rgb_from(wl: &[f64], primary: f64) -> [f64; 3] {
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

/// What tolray's own `NOTE 0 tolray ...` line records.
#[derive(Default)]
struct TolrayNote {
    primary_nm: Option<f64>,
    rgb_nm: Option<[f64; 3]>,
    sensor_res: Option<[u32; 2]>,
}

fn tolray_note(h: &Header, warnings: &mut Vec<String>) -> TolrayNote {
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

/// A number as the shortest text that reads back to the same `f64`.
fn fmt(x: f64) -> String {
    if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:E}")
    }
}

/// The catalog name Zemax's `GCAT` uses for a built-in vendor.
fn gcat_name(vendor: &str) -> String {
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
fn gcat_order(lens: &Lens, initial: Vec<String>) -> Vec<String> {
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
    let vendor = |c: &String| super::material::vendor_of_gcat(c);
    // Each pass moves one vendor ahead of the first listed vendor that would take its glass;
    // a bounded number of passes ends a cycle (the same name wanted from two vendors).
    for _ in 0..gcat.len() * gcat.len() {
        let mut moved = false;
        for g in &glasses {
            let Some(own) = gcat.iter().position(|c| vendor(c) == Some(g.vendor)) else {
                continue;
            };
            let thief = gcat[..own].iter().position(|c| {
                vendor(c).is_some_and(|v| super::material::find_in_vendors(g.name, &[v]).is_some())
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
fn coordinate_break(t: f64, parms: [f64; 5], order: u8) -> Vec<String> {
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
fn tilt_angles(n: [f64; 3], roll_deg: f64) -> (f64, f64, f64) {
    let [a, b, g] = angles_of(&super::system::frame_rotation(n, roll_deg));
    (a, b, g)
}

fn glas_line(m: &Material) -> Option<String> {
    let model = |nd: f64, vd: f64| format!("GLAS ___BLANK 1 0 {} {} 0 0 0 0 0 0", fmt(nd), fmt(vd));
    match m {
        Material::Air => None,
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
            use super::material::{LAMBDA_C_NM, LAMBDA_F_NM};
            let disp = m.index(LAMBDA_F_NM) - m.index(LAMBDA_C_NM);
            Some(model(*nd_new, (nd_new - 1.0) / disp))
        }
    }
}

/// µm text for a wavelength in nm that reads back (times 1000) to the same nm value when one
/// exists.
fn um_text(nm: f64) -> String {
    fmt(super::material::um_from_nm(nm))
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
        let v = s.vec_local;
        let moved = s.pos_xy_mm != [0.0, 0.0] || v[0] != 0.0 || v[1] != 0.0 || s.roll_deg != 0.0;
        let (a, b, g) = if moved {
            tilt_angles(v, s.roll_deg)
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
        l.push(
            match s.shape {
                _ if s.grating.is_some() => "TYPE DGRATING",
                Shape::Paraxial { .. } => "TYPE PARAXIAL",
                Shape::Odd => "TYPE ODDASPHE",
                Shape::Toroidal { .. } => "TYPE TOROIDAL",
                Shape::Qbfs { .. } | Shape::Qcon { .. } => "TYPE QED_TYPE",
                Shape::Even if asph => "TYPE EVENASPH",
                Shape::Even => "TYPE STANDARD",
            }
            .into(),
        );
        l.push(format!("CURV {}", fmt(s.c)));
        if s.k != 0.0 || asph {
            l.push(format!("CONI {}", fmt(s.k)));
        }
        match s.shape {
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
        if let Some(f) = s.fold {
            let [a, b, g] = f.tilt_deg;
            surf(
                &mut w,
                coordinate_break(s.d_next_mm - f.pivot_mm, [0.0, 0.0, a, b, g], 0),
            );
        }
    }
    // A decentred, tilted or rolled image plane: one coordinate break before it.
    let ip = &lens.image_plane;
    if !ip.is_default() {
        let (a, b, g) = tilt_angles(ip.normal, ip.roll_deg);
        let [dx, dy] = ip.decenter_mm;
        surf(&mut w, coordinate_break(0.0, [dx, dy, a, b, g], 0));
    }
    surf(
        &mut w,
        vec![
            "TYPE STANDARD".into(),
            "CURV 0".into(),
            "DISZ 0".into(),
            format!("DIAM {} 1 0 0 1 \"\"", fmt(lens.sensor.half_diagonal_mm())),
        ],
    );
    out
}

/// The aperture lines of a surface (`FLAP` for a semi-diameter that clips, `CLAP`, `OBSC`,
/// `SQAP`, `OBSQ`, `ELAP`, `OBEL`, and `OBDC` for a decenter).
fn aperture_lines(s: &Surface) -> Vec<String> {
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
        .filter_map(|c| super::material::vendor_of_gcat(c))
        .collect();
    order.extend(super::material::VENDOR_ORDER);
    for (i, s) in lens.surfaces.iter().enumerate() {
        if let Material::Catalog(g) = s.material {
            let found = super::material::find_in_vendors(g.name, &order);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_round_trip_through_their_text() {
        for x in [
            0.045433893684688774,
            -435.76000000000005,
            1e-5,
            -2.5e-12,
            1e300,
            0.0,
            3.26,
            60.323649,
        ] {
            assert_eq!(fmt(x).parse::<f64>().unwrap(), x, "{x}");
        }
        for nm in [
            656.0,
            587.0,
            486.0,
            587.5618,
            0.656 * 1e3,
            0.587 * 1e3,
            0.486 * 1e3,
        ] {
            assert_eq!(um_text(nm).parse::<f64>().unwrap() * 1e3, nm, "{nm}");
        }
    }

    #[test]
    fn tilt_angles_reproduce_the_frame() {
        let n = [0.01, -0.02, (1.0f64 - 0.0005).sqrt()];
        for roll in [0.0, 30.0, -90.0, 179.0] {
            let (a, b, g) = tilt_angles(n, roll);
            let r = rotation_xyz_deg(a, b, g);
            let want = crate::lens::system::rotation_to(n) * Mat3::rot_z(f64::to_radians(roll));
            for (x, y) in r.rows.iter().zip(want.rows.iter()) {
                assert!(
                    (*x - *y).norm() < 1e-15,
                    "roll {roll}: {r:?} against {want:?}"
                );
            }
            // The reader recovers the roll from the frame.
            assert!(
                (crate::lens::system::roll_of(&r, n) - roll).abs() < 1e-12,
                "roll {roll}"
            );
        }
    }

    #[test]
    fn rgb_heuristics() {
        assert_eq!(
            rgb_from(&[486.1, 587.6, 656.3], 587.6),
            [656.3, 587.6, 486.1]
        );
        assert_eq!(rgb_from(&[550.0], 550.0), [550.0; 3]);
        assert_eq!(rgb_from(&[500.0, 600.0], 600.0), [600.0, 600.0, 500.0]);
    }
}
