//! Field points: where the light comes from ([`Field`]), and the field points a lens file
//! defines with their weights and vignetting factors ([`FieldPoint`], [`Vignetting`]). The
//! launch of a field's rays is in [`crate::trace`].

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// A field point. Positive values put the object above/right of the axis (rays then travel
/// toward -y/-x), as in the reference data.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Field {
    /// Field angles about the first vertex, degrees. For a finite object the object point is
    /// at `(d tan x, d tan y, -d)`.
    AngleDeg {
        /// Angle in the x-z plane.
        x: f64,
        /// Angle in the y-z plane (meridional).
        y: f64,
    },
    /// Object height, mm (finite objects only).
    HeightMm {
        /// Height along x.
        x: f64,
        /// Height along y.
        y: f64,
    },
    /// Fraction of the full field, linear in the tangent of the angle:
    /// `tan t = fraction * r_sensor / EFL`.
    Fraction {
        /// Fraction along x.
        x: f64,
        /// Fraction along y.
        y: f64,
    },
    /// Paraxial image height, mm (OpticStudio's field type 2): the field whose paraxial chief
    /// ray (through the centre of the paraxial entrance pupil, primary wavelength) meets the
    /// image plane at `(x, y)`. Unlike the other kinds its sign names the image's side.
    ImageHeightMm {
        /// Height along x.
        x: f64,
        /// Height along y.
        y: f64,
    },
    /// Real image height, mm (OpticStudio's field type 3): the field whose real chief ray at
    /// the primary wavelength meets the image plane at `(x, y)` (in the plane's own frame),
    /// found by Newton's method from the paraxial image height's field. The chief ray goes
    /// through the centre of the paraxial entrance pupil, or of the real stop when rays are
    /// aimed. Its sign names the image's side.
    RealImageHeightMm {
        /// Height along x.
        x: f64,
        /// Height along y.
        y: f64,
    },
}

impl Field {
    /// A meridional field given as an angle in degrees.
    pub fn angle(y_deg: f64) -> Field {
        Field::AngleDeg { x: 0.0, y: y_deg }
    }
    /// A meridional field given as a fraction of the full field.
    pub fn fraction(y: f64) -> Field {
        Field::Fraction { x: 0.0, y }
    }
    /// Parses `0.7` (fraction of the full field), `5deg` (angle), `2.5mm` (object height),
    /// `14mm@image` (paraxial image height) or `14mm@real-image` (real image height); `x,y`
    /// pairs are written `0.5:0.5`, `3deg:-2deg`.
    ///
    /// ```
    /// use tolray::trace::Field;
    /// assert_eq!(Field::parse("5deg").unwrap(), Field::angle(5.0));
    /// assert_eq!(
    ///     Field::parse("0:14mm@image").unwrap(),
    ///     Field::ImageHeightMm { x: 0.0, y: 14.0 }
    /// );
    /// assert!(Field::parse("1mm:2deg").is_err());
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] naming the text.
    pub fn parse(s: &str) -> Result<Field> {
        let t = s.trim();
        let (xs, ys) = match t.split_once(':') {
            Some((a, b)) => (a, b),
            None => ("0", t),
        };
        let unit = |v: &str| -> Result<(f64, u8)> {
            let v = v.trim();
            let (num, kind) = if let Some(n) = v.strip_suffix("deg") {
                (n, 1)
            } else if let Some(n) = v.strip_suffix("mm@image") {
                (n, 3)
            } else if let Some(n) = v.strip_suffix("mm@real-image") {
                (n, 4)
            } else if let Some(n) = v.strip_suffix("mm") {
                (n, 2)
            } else {
                (v, 0)
            };
            num.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .map(|x| (x, kind))
                .ok_or_else(|| Error::argument(format!("field \"{s}\": expected a fraction (0.7), an angle (5deg), an object height (2.5mm) or an image height (14mm@image paraxial, 14mm@real-image real)")))
        };
        let (x, kx) = unit(xs)?;
        let (y, ky) = unit(ys)?;
        let kind = if xs.trim() == "0" { ky } else { kx };
        if kx != ky && xs.trim() != "0" {
            return Err(Error::argument(format!(
                "field \"{s}\": both components need the same unit"
            )));
        }
        Ok(match kind {
            1 => Field::AngleDeg { x, y },
            2 => Field::HeightMm { x, y },
            3 => Field::ImageHeightMm { x, y },
            4 => Field::RealImageHeightMm { x, y },
            _ => Field::Fraction { x, y },
        })
    }

    /// The field's two values (x, y) in its own unit.
    pub fn xy(&self) -> (f64, f64) {
        match *self {
            Field::AngleDeg { x, y }
            | Field::HeightMm { x, y }
            | Field::Fraction { x, y }
            | Field::ImageHeightMm { x, y }
            | Field::RealImageHeightMm { x, y } => (x, y),
        }
    }

    /// Short label for tables (`0.700`, `5.000deg`, `2.500mm`, `14.000mm@image`), in the
    /// syntax [`Field::parse`] reads.
    pub fn label(&self) -> String {
        let (x, y, u) = match *self {
            Field::AngleDeg { x, y } => (x, y, "deg"),
            Field::HeightMm { x, y } => (x, y, "mm"),
            Field::Fraction { x, y } => (x, y, ""),
            Field::ImageHeightMm { x, y } => (x, y, "mm@image"),
            Field::RealImageHeightMm { x, y } => (x, y, "mm@real-image"),
        };
        if x == 0.0 {
            format!("{y:.3}{u}")
        } else {
            format!("{x:.3}{u}:{y:.3}{u}")
        }
    }
}

/// OpticStudio's vignetting factors of a field point: the pupil its rays fill is the unit disk
/// compressed by `compress` and moved by `decenter`, in normalized pupil coordinates:
/// `p' = decenter + p (1 - compress)` per axis (`VDX`, `VDY`, `VCX`, `VCY` of a .zmx file). The
/// chief ray goes through the moved centre, `p' = decenter`, as in OpticStudio. Zero factors
/// (the default) leave the pupil as it is.
///
/// # Examples
/// ```
/// use tolray::trace::Vignetting;
/// let v = Vignetting { decenter_y: 0.25, compress_y: 0.5, ..Vignetting::default() };
/// assert_eq!(v.apply([0.0, 1.0]), [0.0, 0.75]);   // the upper edge: 0.25 + 0.5
/// assert_eq!(v.apply([0.0, -1.0]), [0.0, -0.25]); // the lower edge: 0.25 - 0.5
/// assert_eq!(v.apply([0.0, 0.0]), [0.0, 0.25]);   // the chief ray's pupil point
/// assert!(Vignetting::default().is_none());
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vignetting {
    /// Pupil decenter along x, a fraction of the pupil radius (`VDX`).
    pub decenter_x: f64,
    /// Pupil decenter along y, a fraction of the pupil radius (`VDY`).
    pub decenter_y: f64,
    /// Pupil compression along x (`VCX`): 0 keeps the width, 0.2 makes it 80 %.
    pub compress_x: f64,
    /// Pupil compression along y (`VCY`).
    pub compress_y: f64,
}

impl Vignetting {
    /// True for zero factors (the pupil unchanged).
    pub fn is_none(&self) -> bool {
        *self == Vignetting::default()
    }

    /// The normalized pupil point `q` moved into the vignetted pupil, in any number type (the
    /// differentiable wavefront launches through it in dual numbers).
    pub fn apply<S: crate::real::Real>(&self, q: [S; 2]) -> [S; 2] {
        [
            S::cst(self.decenter_x) + q[0] * S::cst(1.0 - self.compress_x),
            S::cst(self.decenter_y) + q[1] * S::cst(1.0 - self.compress_y),
        ]
    }

    /// Checks that every factor is finite and each compression below 1 (a pupil of positive
    /// size).
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] naming the factor.
    pub fn check(&self) -> Result<()> {
        let all = [
            ("decenter x", self.decenter_x),
            ("decenter y", self.decenter_y),
            ("compression x", self.compress_x),
            ("compression y", self.compress_y),
        ];
        for (name, v) in all {
            if !v.is_finite() {
                return Err(Error::invalid(format!(
                    "vignetting {name} {v} is not finite"
                )));
            }
        }
        for (name, v) in [("x", self.compress_x), ("y", self.compress_y)] {
            if v >= 1.0 {
                return Err(Error::invalid(format!(
                    "vignetting compression {name} {v}: it must be below 1 (1 leaves no pupil)"
                )));
            }
        }
        Ok(())
    }
}

/// A field point a lens file defines (a row of OpticStudio's field data editor): the field,
/// its weight and its vignetting factors. A lens keeps its file's points in [`Lens::fields`](super::Lens::fields);
/// rays generated for a field equal to one of them fill its vignetted pupil.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldPoint {
    /// The field (an angle or an object height).
    pub field: Field,
    /// Weight (OpticStudio's `FWGN`; tolray's analyses weight fields equally).
    pub weight: f64,
    /// Vignetting factors.
    pub vignetting: Vignetting,
}
