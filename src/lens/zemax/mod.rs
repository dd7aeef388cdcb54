//! Zemax OpticStudio sequential lens files (.zmx): reading and writing.
//!
//! # Reading
//! The file is decoded from UTF-16 (little or big endian, with or without a byte-order mark, as
//! OpticStudio writes it), UTF-8 or ASCII. tolray reads:
//!
//! - `UNIT MM|CM|IN|METER` (lengths are converted to mm once, at load);
//! - `SURF` blocks with `TYPE STANDARD`, `EVENASPH`, `ODDASPHE`, `TOROIDAL`, `PARAXIAL`,
//!   `DGRATING`, `QED_TYPE` (the Q-type asphere of type 0, Forbes' Qbfs on a conic:
//!   [`super::Shape::Qbfs`], or type 1, Qcon: [`super::Shape::Qcon`]), `TILTSURF` (the plane
//!   z = x tan θx + y tan θy, PARM 1 and 2 the tangents: a flat surface turned against its frame,
//!   which the surfaces after it keep; on the image, a tilted image plane), `FZERNSAG` and
//!   `SZERNSAG` (Zernike Fringe and Standard sag: [`super::Shape::Zernike`]; PARM 0 Extrapolate,
//!   PARM 1..8 the r² .. r¹⁶ terms, PARM 9 and 10 the Zernike decenter, XDAT 1 the number of
//!   terms, XDAT 2 the normalization radius, XDAT 3.. the coefficients of Z1, Z2, ...) and
//!   `COORDBRK`; `CURV` (1/lens unit), `CONI`, `PARM` (even-asphere terms r² ..
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
//! `QED_TYPE`, `FZERNSAG`, `SZERNSAG` or `DGRATING`), with a `COORDBRK` pair around every surface that carries a decenter, a tilt or a
//! roll (the whole frame as tilts about x, y and z), so perturbed lenses survive the round trip,
//! and one more `COORDBRK` after a fold mirror (the axis' turn at its pivot).
//! Model
//! glasses are written as `___BLANK` model glasses (tolray's dispersion law between the lines
//! differs slightly from OpticStudio's model glass; n_d and V_d are exact), catalog glasses by
//! name. A `NOTE 0 tolray ...` line records what Zemax has no place for (the exact primary and
//! RGB wavelengths in nm and the sensor resolution), so JSON → .zmx → JSON is exact.

use super::field::{Field, FieldPoint, Vignetting};
use super::material::{GlassCatalogs, Material, LAMBDA_D_NM};
use super::text::decode;
use super::{
    Aperture, ApertureShape, Grating, ImagePlane, Lens, Object, Sensor, Shape, Surface,
    SurfaceRole, N_ASPH,
};
use crate::error::{Error, ErrorKind, Result};
use crate::math::{Mat3, Vec3};
use std::path::Path;

mod build;
mod frames;
mod read;
mod write;

use build::*;
use frames::*;
pub use read::from_str;
use read::*;
#[cfg(test)]
use write::*;
pub use write::{to_string, write_file};

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

/// The file's wavelengths, the primary index, and tolray's primary, RGB and sensor resolution.
struct Spectrum {
    wavelengths: Vec<ZmxWavelength>,
    primary: usize,
    primary_nm: f64,
    rgb_nm: [f64; 3],
    sensor_res: [u32; 2],
}

/// What tolray's own `NOTE 0 tolray ...` line records.
#[derive(Default)]
struct TolrayNote {
    primary_nm: Option<f64>,
    rgb_nm: Option<[f64; 3]>,
    sensor_res: Option<[u32; 2]>,
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
