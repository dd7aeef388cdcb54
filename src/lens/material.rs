//! Optical materials: air, model glasses given by (n_d, V_d), catalog glasses (built in, or from
//! the user's Zemax AGF catalogs).

use super::agf::{AgfCatalog, AgfGlass};
use crate::error::{Error, Result};
use std::path::Path;
use std::sync::Arc;

/// The d line (helium), nm: the wavelength at which n_d is defined.
pub const LAMBDA_D_NM: f64 = 587.5618;
/// The F line (hydrogen), nm.
pub const LAMBDA_F_NM: f64 = 486.1327;
/// The C line (hydrogen), nm.
pub const LAMBDA_C_NM: f64 = 656.2725;

/// The wavelengths tolray accepts at its interfaces (CLI, C ABI, lens files), nm, exclusive
/// bounds: 100 nm (the vacuum ultraviolet) to 10 mm (millimetre-wave refractors). Whether a lens
/// can be traced at a wavelength is its materials' business: every medium must have an index
/// between 0.9 and 5 there ([`crate::Lens::check_indices`]), and a catalog glass used outside the
/// range its formula was fitted on is named in [`crate::Lens::warnings`].
pub const WAVELENGTH_RANGE_NM: (f64, f64) = (100.0, 1.0e7);

/// [`WAVELENGTH_RANGE_NM`] in words, for messages: "0.1 µm to 10 mm".
pub const WAVELENGTH_RANGE_TEXT: &str = "0.1 µm to 10 mm";

/// Beyond this wavelength (20 µm, nm) a lens is traced only where each of its media is defined
/// ([`Material::defined_at`]): air, constant indices, and catalog glasses whose formula's range
/// reaches it (millimetre-wave refractors of HDPE or PTFE given as constant indices, infrared
/// crystals). A dispersive model glass (a law fitted to the visible) or a glass fitted to 2.5 µm
/// is refused there, which also catches nanometres given where micrometres belong (`WAVM 587.56`).
pub const DEFINED_MEDIA_BEYOND_NM: f64 = 20_000.0;

/// Checks a wavelength given at an interface: finite and inside [`WAVELENGTH_RANGE_NM`] (which
/// catches micrometres given for nanometres).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] naming the value and the unit expected.
pub fn check_wavelength_nm(wavelength_nm: f64) -> Result<f64> {
    let (lo, hi) = WAVELENGTH_RANGE_NM;
    if wavelength_nm.is_finite() && wavelength_nm > lo && wavelength_nm < hi {
        Ok(wavelength_nm)
    } else {
        Err(Error::argument(format!(
            "wavelength {wavelength_nm} nm is outside {lo} to {hi:e} nm, {WAVELENGTH_RANGE_TEXT} (give nanometres, e.g. 587.56)"
        )))
    }
}

/// Whether a wavelength read from a lens file (µm, as DeepLens JSON and .zmx store them) lies in
/// [`WAVELENGTH_RANGE_NM`]: both readers use this, so that a file one writes the other opens.
pub fn wavelength_um_ok(um: f64) -> bool {
    check_wavelength_nm(um * 1e3).is_ok()
}

/// The wavelength in µm that reads back (times 1000) to exactly `nm` when such an `f64` exists
/// (`nm * 1e-3` is sometimes one unit in the last place off), else `nm / 1000`. Files store µm.
pub(crate) fn um_from_nm(nm: f64) -> f64 {
    let mut um = nm / 1e3;
    for _ in 0..4 {
        if um * 1e3 == nm || !um.is_finite() || um <= 0.0 {
            break;
        }
        let bits = um.to_bits();
        um = f64::from_bits(if um * 1e3 < nm { bits + 1 } else { bits - 1 });
    }
    if um * 1e3 == nm {
        um
    } else {
        nm / 1e3
    }
}

/// A dispersion formula of a catalog glass; wavelengths λ in micrometres.
///
/// Each variant notes the Zemax AGF formula id it reads (see [`crate::lens::agf`]); Zemax's
/// "Sellmeier 2" and "Sellmeier 4" are not n-term Sellmeier sums, hence their own names.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Dispersion {
    /// Three-term Sellmeier, n² − 1 = Σ b_i λ² / (λ² − c_i), c in µm² (Zemax 2, "Sellmeier 1").
    Sellmeier3 {
        /// Numerator coefficients.
        b: [f64; 3],
        /// Resonance coefficients (µm²).
        c: [f64; 3],
    },
    /// Four-term Sellmeier, as [`Dispersion::Sellmeier3`] (Zemax 6, "Sellmeier 3").
    Sellmeier4 {
        /// Numerator coefficients.
        b: [f64; 4],
        /// Resonance coefficients (µm²).
        c: [f64; 4],
    },
    /// Five-term Sellmeier, as [`Dispersion::Sellmeier3`] (Zemax 11, "Sellmeier 5").
    Sellmeier5 {
        /// Numerator coefficients.
        b: [f64; 5],
        /// Resonance coefficients (µm²).
        c: [f64; 5],
    },
    /// Schott formula: n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ (Zemax 1).
    Schott {
        /// Coefficients a0..a5.
        a: [f64; 6],
    },
    /// Extended formula (Hikari; Zemax 13, "Extended 3"): n² = a0 + a1 λ² + a2 λ⁴ + a3 λ⁻²
    /// + a4 λ⁻⁴ + a5 λ⁻⁶ + a6 λ⁻⁸ + a7 λ⁻¹⁰ + a8 λ⁻¹².
    Extended {
        /// Coefficients a0..a8.
        a: [f64; 9],
    },
    /// Zemax 10, "Extended": n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ + a6 λ⁻¹⁰
    /// + a7 λ⁻¹².
    ExtendedSchott {
        /// Coefficients a0..a7.
        a: [f64; 8],
    },
    /// Zemax 12, "Extended 2": n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ + a6 λ⁴
    /// + a7 λ⁶.
    Extended2 {
        /// Coefficients a0..a7.
        a: [f64; 8],
    },
    /// Zemax 3, Herzberger: n = a0 + a1 L + a2 L² + a3 λ² + a4 λ⁴ + a5 λ⁶ with
    /// L = 1 / (λ² − 0.028).
    Herzberger {
        /// Coefficients a0..a5.
        a: [f64; 6],
    },
    /// Zemax 4, "Sellmeier 2": n² − 1 = A + B1 λ² / (λ² − λ1²) + B2 / (λ² − λ2²), coefficients
    /// `[A, B1, λ1, B2, λ2]` (λ1, λ2 in µm).
    ZemaxSellmeier2 {
        /// `[A, B1, λ1, B2, λ2]`.
        a: [f64; 5],
    },
    /// Zemax 5, Conrady: n = n0 + A / λ + B / λ^3.5, coefficients `[n0, A, B]`.
    Conrady {
        /// `[n0, A, B]`.
        a: [f64; 3],
    },
    /// Zemax 7, "Handbook of Optics 1": n² = A + B / (λ² − C) − D λ².
    Handbook1 {
        /// `[A, B, C, D]`.
        a: [f64; 4],
    },
    /// Zemax 8, "Handbook of Optics 2": n² = A + B λ² / (λ² − C) − D λ².
    Handbook2 {
        /// `[A, B, C, D]`.
        a: [f64; 4],
    },
    /// Zemax 9, "Sellmeier 4": n² = A + B λ² / (λ² − C) + D λ² / (λ² − E).
    ZemaxSellmeier4 {
        /// `[A, B, C, D, E]`.
        a: [f64; 5],
    },
    /// Measured indices, (λ µm, n) in increasing λ, without a formula (refractiveindex.info's
    /// "tabulated n", as the vendor's data sheet gives them: Schott B 270): linear in λ between
    /// points, the end values held beyond them (as optiland reads such pages; the range check
    /// warns there).
    Tabulated {
        /// The points, (λ µm, n), λ increasing.
        points: &'static [(f64, f64)],
    },
}

/// The index at `lambda_um` of a table of (λ, n) points, λ increasing: linear between points,
/// the end values beyond them (NaN for an empty table).
fn tabulated(points: &[(f64, f64)], lambda_um: f64) -> f64 {
    let (Some(&(l0, n0)), Some(&(l1, n1))) = (points.first(), points.last()) else {
        return f64::NAN;
    };
    if !(lambda_um > l0) {
        return if lambda_um.is_nan() { f64::NAN } else { n0 };
    }
    if lambda_um >= l1 {
        return n1;
    }
    // The first point beyond λ (exists: λ < l1) and the one before it (at or below λ: λ > l0),
    // so a tabulated wavelength gives its own index exactly.
    let k = points.partition_point(|p| p.0 <= lambda_um);
    let ((xa, ya), (xb, yb)) = (points[k - 1], points[k]);
    ya + (yb - ya) * (lambda_um - xa) / (xb - xa)
}

fn sellmeier(l2: f64, b: &[f64], c: &[f64]) -> f64 {
    1.0 + b.iter().zip(c).map(|(b, c)| b * l2 / (l2 - c)).sum::<f64>()
}

impl Dispersion {
    /// Refractive index at `lambda_um` micrometres (NaN where the formula has no real index).
    pub fn index(&self, lambda_um: f64) -> f64 {
        let l2 = lambda_um * lambda_um;
        let il2 = 1.0 / l2;
        // Negative powers a_k λ^-2k as a Horner polynomial in λ^-2.
        let neg = |a: &[f64]| a.iter().rev().fold(0.0, |acc, x| (acc + x) * il2);
        let n2 = match self {
            Dispersion::Sellmeier3 { b, c } => sellmeier(l2, b, c),
            Dispersion::Sellmeier4 { b, c } => sellmeier(l2, b, c),
            Dispersion::Sellmeier5 { b, c } => sellmeier(l2, b, c),
            Dispersion::Schott { a } => {
                a[0] + a[1] * l2 + il2 * (a[2] + il2 * (a[3] + il2 * (a[4] + il2 * a[5])))
            }
            Dispersion::Extended { a } => {
                let neg = il2
                    * (a[3]
                        + il2 * (a[4] + il2 * (a[5] + il2 * (a[6] + il2 * (a[7] + il2 * a[8])))));
                a[0] + l2 * (a[1] + l2 * a[2]) + neg
            }
            Dispersion::ExtendedSchott { a } => a[0] + a[1] * l2 + neg(&a[2..8]),
            Dispersion::Extended2 { a } => {
                a[0] + l2 * (a[1] + l2 * (a[6] + l2 * a[7])) + neg(&a[2..6])
            }
            Dispersion::Herzberger { a } => {
                let l = 1.0 / (l2 - 0.028);
                return a[0] + l * (a[1] + l * a[2]) + l2 * (a[3] + l2 * (a[4] + l2 * a[5]));
            }
            Dispersion::ZemaxSellmeier2 { a } => {
                1.0 + a[0] + a[1] * l2 / (l2 - a[2] * a[2]) + a[3] / (l2 - a[4] * a[4])
            }
            Dispersion::Conrady { a } => {
                return a[0] + a[1] / lambda_um + a[2] / lambda_um.powf(3.5);
            }
            Dispersion::Handbook1 { a } => a[0] + a[1] / (l2 - a[2]) - a[3] * l2,
            Dispersion::Handbook2 { a } => a[0] + a[1] * l2 / (l2 - a[2]) - a[3] * l2,
            Dispersion::ZemaxSellmeier4 { a } => {
                a[0] + a[1] * l2 / (l2 - a[2]) + a[3] * l2 / (l2 - a[4])
            }
            Dispersion::Tabulated { points } => return tabulated(points, lambda_um),
        };
        n2.sqrt()
    }
}

/// A glass from the built-in catalog.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CatalogGlass {
    /// Catalog name as the vendor writes it (e.g. `N-BK7`).
    pub name: &'static str,
    /// Vendor (Schott, CDGM, Ohara, Hikari, ...).
    pub vendor: &'static str,
    /// Dispersion formula.
    pub dispersion: Dispersion,
    /// Nominal catalog n_d.
    pub nd: f64,
    /// Nominal catalog Abbe number V_d.
    pub vd: f64,
    /// Valid wavelength range of the formula, µm.
    pub range_um: (f64, f64),
}

/// The medium that follows a surface.
#[derive(Clone, Debug, PartialEq)]
pub enum Material {
    /// Air, taken as n = 1 at every wavelength (as DeepLens and the reference tracers do).
    Air,
    /// A constant index at every wavelength.
    Constant(f64),
    /// A model glass with index exactly `nd` at the d line and Abbe number exactly `vd`,
    /// through the two-term Cauchy law n = A + B / λ² fitted to both.
    Model {
        /// Index at 587.5618 nm.
        nd: f64,
        /// Abbe number (n_d − 1) / (n_F − n_C).
        vd: f64,
    },
    /// A catalog glass.
    Catalog(&'static CatalogGlass),
    /// A glass from a user's Zemax AGF catalog (see [`GlassCatalogs`]).
    Agf(Arc<AgfGlass>),
    /// A glass with a tolerance applied: n(λ) = `nd_new` + (base(λ) − `nd`) · `scale`.
    Perturbed {
        /// The nominal glass.
        base: Box<Material>,
        /// The nominal glass' n_d.
        nd: f64,
        /// The perturbed n_d.
        nd_new: f64,
        /// Dispersion scale (perturbed n_F − n_C over nominal).
        scale: f64,
    },
    /// A gradient-index medium (OpticStudio's Gradient 1, 2 and 3): its index varies with
    /// position in the frame of the surface it follows; [`Material::index`] gives its index at
    /// that surface's vertex, at every wavelength.
    Gradient(Box<super::gradient::Gradient>),
}

/// Index of a model glass (n_d, V_d) at `wavelength_nm` by its Cauchy law `n = A + B / λ²`
/// through n_d at the d line with the Abbe number V_d = (n_d − 1) / (n_F − n_C), in any number
/// type: the one formula of [`Material::index`], of the tracer's indices and of the paraxial
/// launch, so that dual numbers carry glass derivatives with the same values.
///
/// ```
/// use tolray::lens::material::{model_index, Material, LAMBDA_D_NM};
/// let n: f64 = model_index(1.5168, 64.17, LAMBDA_D_NM);
/// assert!((n - 1.5168).abs() < 1e-15);
/// assert_eq!(n, Material::Model { nd: 1.5168, vd: 64.17 }.index(LAMBDA_D_NM));
/// ```
pub fn model_index<S: crate::real::Real>(nd: S, vd: S, wavelength_nm: f64) -> S {
    let inv2 = |l: f64| 1.0 / (l * l);
    let b = (nd - S::cst(1.0)) / vd / S::cst(inv2(LAMBDA_F_NM) - inv2(LAMBDA_C_NM));
    let a = nd - b * S::cst(inv2(LAMBDA_D_NM));
    a + b * S::cst(inv2(wavelength_nm))
}

impl Material {
    /// Refractive index at `wavelength_nm` nanometres.
    pub fn index(&self, wavelength_nm: f64) -> f64 {
        match self {
            Material::Air => 1.0,
            Material::Constant(n) => *n,
            Material::Model { nd, vd } => model_index(*nd, *vd, wavelength_nm),
            Material::Catalog(g) => g.dispersion.index(wavelength_nm * 1e-3),
            Material::Agf(g) => g.dispersion.index(wavelength_nm * 1e-3),
            Material::Perturbed {
                base,
                nd,
                nd_new,
                scale,
            } => nd_new + (base.index(wavelength_nm) - nd) * scale,
            Material::Gradient(g) => g.n0,
        }
    }

    /// True for air (the medium that separates elements).
    pub fn is_air(&self) -> bool {
        matches!(self, Material::Air)
    }

    /// The name DeepLens' JSON uses for this material (`air`, `n-bk7`, `1.5168/64.17`). A
    /// built-in glass whose bare name would be read as another vendor's glass of that name
    /// carries its vendor (`f2 (hikari)`: Hikari's F2, where `f2` is Schott's), which
    /// [`Material::parse`] reads back.
    ///
    /// ```
    /// use tolray::lens::Material;
    /// let hikari_f2 = Material::parse("F2 (Hikari)").unwrap();
    /// assert_eq!(hikari_f2.json_name(), "f2 (hikari)");
    /// assert_eq!(Material::parse("f2").unwrap().json_name(), "f2");
    /// assert_eq!(Material::parse(&hikari_f2.json_name()).unwrap(), hikari_f2);
    /// ```
    pub fn json_name(&self) -> String {
        match self {
            Material::Air => "air".to_string(),
            Material::Constant(n) => format!("{n}"),
            Material::Model { nd, vd } => format!("{nd}/{vd}"),
            Material::Catalog(g) => {
                let bare = g.name.to_ascii_lowercase();
                match GlassCatalogs::builtin().find(&bare) {
                    Some(Material::Catalog(h)) if h.vendor == g.vendor && h.name == g.name => bare,
                    _ => format!("{bare} ({})", g.vendor.to_ascii_lowercase()),
                }
            }
            Material::Agf(g) => g.name.to_ascii_lowercase(),
            // The vertex index: the whole medium is tolray's "gradient" key of the surface.
            Material::Gradient(g) => format!("{}", g.n0),
            Material::Perturbed { nd_new, .. } => {
                let disp = self.index(LAMBDA_F_NM) - self.index(LAMBDA_C_NM);
                let vd = (nd_new - 1.0) / disp;
                // A dispersion that rounds to nothing is a constant index, never "n/inf".
                if disp > 0.0 && vd.is_finite() {
                    format!("{nd_new}/{vd}")
                } else {
                    format!("{nd_new}")
                }
            }
        }
    }

    /// The catalog glass' name as its catalog writes it (`N-BK7`), or `None` for other materials.
    pub fn catalog_name(&self) -> Option<&str> {
        match self {
            Material::Catalog(g) => Some(g.name),
            Material::Agf(g) => Some(&g.name),
            _ => None,
        }
    }

    /// Whether the material has data at `wavelength_nm`: air and constant indices everywhere,
    /// a catalog or AGF glass inside its formula's range, a dispersive model glass (a law
    /// through the F, d and C lines) up to [`DEFINED_MEDIA_BEYOND_NM`].
    ///
    /// ```
    /// use tolray::lens::material::Material;
    /// assert!(Material::Constant(1.52).defined_at(3.0e6)); // HDPE at 3 mm
    /// assert!(!Material::parse("N-BK7").unwrap().defined_at(3.0e6));
    /// assert!(Material::parse("N-BK7").unwrap().defined_at(1550.0));
    /// ```
    pub fn defined_at(&self, wavelength_nm: f64) -> bool {
        let um = wavelength_nm * 1e-3;
        match self {
            Material::Air | Material::Constant(_) => true,
            Material::Model { .. } => wavelength_nm <= DEFINED_MEDIA_BEYOND_NM,
            Material::Perturbed { base, .. } => base.defined_at(wavelength_nm),
            _ => self
                .range_um()
                .is_some_and(|(lo, hi)| (lo..=hi).contains(&um)),
        }
    }

    /// The wavelength range, µm, in which a catalog glass' dispersion formula is valid (the
    /// catalog's stated range), or `None` for materials without one.
    pub fn range_um(&self) -> Option<(f64, f64)> {
        match self {
            Material::Catalog(g) => Some(g.range_um),
            Material::Agf(g) => Some(g.range_um),
            Material::Perturbed { base, .. } => base.range_um(),
            _ => None,
        }
    }

    /// Parses a material name as DeepLens writes it: `air` (also `vacuum`, `occluder`), a catalog
    /// name in any case (`n-bk7`, `N-BK7`), a model glass `"n_d/V_d"`, or a constant index `"1.5"`.
    /// Only the built-in catalog is searched; see [`Material::parse_with`].
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] for an unknown glass (with the closest catalog names), an
    /// index below [`MIN_INDEX`], or a negative Abbe number.
    pub fn parse(name: &str) -> Result<Material> {
        Material::parse_with(name, &GlassCatalogs::builtin())
    }

    /// As [`Material::parse`], looking glass names up in `catalogs` (the user's AGF catalogs
    /// first, then the built-in catalog).
    ///
    /// # Errors
    /// As [`Material::parse`].
    pub fn parse_with(name: &str, catalogs: &GlassCatalogs) -> Result<Material> {
        let s = name.trim();
        let lower = s.to_ascii_lowercase();
        if matches!(lower.as_str(), "air" | "vacuum" | "occluder") {
            return Ok(Material::Air);
        }
        if let Some((n, v)) = s.split_once('/') {
            let (n, v) = (n.trim().parse::<f64>(), v.trim().parse::<f64>());
            return match (n, v) {
                (Ok(nd), Ok(vd)) => Material::model(nd, vd),
                _ => Err(Error::invalid(format!(
                    "material \"{s}\": a model glass is written \"n_d/V_d\" with two numbers"
                ))),
            };
        }
        if let Ok(n) = s.parse::<f64>() {
            check_index(n, s)?;
            return Ok(Material::Constant(n));
        }
        if let Some(m) = catalogs.find(s) {
            return Ok(m);
        }
        // A built-in glass with its vendor: "F2 (Hikari)".
        if let Some((n, v)) = s.strip_suffix(')').and_then(|t| t.split_once(" (")) {
            let vendor = VENDOR_ORDER
                .iter()
                .copied()
                .find(|x| x.eq_ignore_ascii_case(v.trim()))
                .or_else(|| vendor_of_gcat(v.trim()));
            if let Some(g) = vendor.and_then(|v| find_in_vendors(n.trim(), &[v])) {
                return Ok(Material::Catalog(g));
            }
            return Err(Error::invalid(format!(
                "unknown glass \"{s}\": {} has no glass \"{}\" built in (vendors: {})",
                v.trim(),
                n.trim(),
                VENDOR_ORDER.join(", ")
            )));
        }
        let close = catalogs.suggest(s, 3);
        let hint = if close.is_empty() {
            String::new()
        } else {
            format!(" (did you mean {}?)", close.join(", "))
        };
        Err(Error::invalid(format!(
            "unknown glass \"{s}\"{hint}; use a catalog name, \"air\", or a model glass \"n_d/V_d\""
        )))
    }

    /// A model glass, checked. `vd` of 0 (OpticStudio) or at least 1e30 (DeepLens) means no
    /// dispersion: a constant index (air when `nd` is 1).
    ///
    /// ```
    /// use tolray::lens::Material;
    /// assert_eq!(Material::model(1.5, 0.0).unwrap(), Material::Constant(1.5));
    /// assert!(Material::model(0.8, 40.0).is_err() && Material::model(1.5, -1.0).is_err());
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] if `nd` is outside [`MIN_INDEX`] to [`MAX_INDEX`] (below 1
    /// for a glass that disperses: the model's dispersion (n_d - 1) / V_d would turn over),
    /// `vd` is negative, or either is NaN.
    pub fn model(nd: f64, vd: f64) -> Result<Material> {
        check_index(nd, &format!("{nd}/{vd}"))?;
        if !(vd >= 0.0) {
            return Err(Error::invalid(format!(
                "material \"{nd}/{vd}\": Abbe number must be positive (or 0 for no dispersion)"
            )));
        }
        if nd < 1.0 && vd > 0.0 && vd < 1e30 {
            return Err(Error::invalid(format!(
                "material \"{nd}/{vd}\": a model glass that disperses needs n_d of at least 1 \
                 (below 1 only a constant index, V_d 0, is accepted)"
            )));
        }
        // OpticStudio writes V_d = 0 and DeepLens 1e38 for a dispersion-free medium.
        if vd == 0.0 || vd >= 1e30 || !vd.is_finite() {
            return Ok(if nd == 1.0 {
                Material::Air
            } else {
                Material::Constant(nd)
            });
        }
        Ok(Material::Model { nd, vd })
    }
}

/// Where glass names are looked up: the user's Zemax AGF catalogs, searched first and in the
/// order given, then the built-in vendor catalogs, the `prefer`red vendors first (a .zmx file's
/// `GCAT` order), then in [`VENDOR_ORDER`] (with DeepLens' short aliases such as `bk7`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GlassCatalogs {
    /// User catalogs, searched in order before the built-in one.
    pub user: Vec<AgfCatalog>,
    /// Built-in vendors searched first, in order, by name as Zemax's `GCAT` writes them
    /// (`SCHOTT`, `OHARA`, `NIKON-HIKARI`, ...; case-insensitive); set from a .zmx file's `GCAT`.
    pub prefer: Vec<String>,
    /// When a .zmx `GLAS` names a glass no catalog has, use the n_d and V_d the line carries as a
    /// model glass (`--glass-fallback file-values`) instead of refusing the file.
    pub file_values_fallback: bool,
}

/// The built-in vendors in the order a glass name is resolved when a file does not say
/// (names shared by two vendors, such as Schott's and Hikari's `BAF10`, resolve to the first).
pub const VENDOR_ORDER: [&str; 10] = [
    "Schott",
    "Ohara",
    "Hoya",
    "CDGM",
    "Hikari",
    "Sumita",
    "Misc",
    "Infrared",
    "LightPath",
    "RPO",
];

/// The built-in vendor a Zemax `GCAT` catalog name stands for (`SCHOTT`, `OHARA`,
/// `NIKON-HIKARI`/`HIKARI`, `CDGM`, `HOYA`, `SUMITA`, `MISC`, `INFRARED`, `LIGHTPATH`, `RPO`;
/// case-insensitive).
pub fn vendor_of_gcat(name: &str) -> Option<&'static str> {
    let n = name.to_ascii_uppercase();
    let n = n.trim_end_matches(".AGF");
    match n {
        "NIKON-HIKARI" | "HIKARI" | "NIKON" => Some("Hikari"),
        "CDGM" | "CDGM-ZEMAX" => Some("CDGM"),
        _ => VENDOR_ORDER
            .iter()
            .copied()
            .find(|v| v.eq_ignore_ascii_case(n)),
    }
}

/// The vendor whose naming a glass name follows, when its prefix says (`N-`/`P-` Schott, `S-`
/// Ohara, `H-` CDGM, `J-` Hikari, `K-` Sumita, `E-`/`M-` Hoya).
fn vendor_of_prefix(name: &str) -> Option<&'static str> {
    let u = name.to_ascii_uppercase();
    [
        ("N-", "Schott"),
        ("P-", "Schott"),
        ("S-", "Ohara"),
        ("L-", "Ohara"),
        ("H-", "CDGM"),
        ("D-", "CDGM"),
        ("J-", "Hikari"),
        ("Q-", "Hikari"),
        ("K-", "Sumita"),
        ("E-", "Hoya"),
        ("M-", "Hoya"),
    ]
    .iter()
    .find(|(p, _)| u.starts_with(p))
    .map(|(_, v)| *v)
}

impl GlassCatalogs {
    /// Only the built-in catalog.
    pub fn builtin() -> GlassCatalogs {
        GlassCatalogs::default()
    }

    /// The built-in vendors in the order this lookup searches them.
    pub fn vendor_order(&self) -> Vec<&'static str> {
        let mut v: Vec<&'static str> = self
            .prefer
            .iter()
            .filter_map(|p| vendor_of_gcat(p))
            .collect();
        v.extend(VENDOR_ORDER);
        let mut seen = Vec::new();
        v.retain(|x| {
            let new = !seen.contains(x);
            seen.push(*x);
            new
        });
        v
    }

    /// Reads AGF catalog files (searched in the order given, before the built-in catalog).
    /// Returns the catalogs and the readers' warnings.
    ///
    /// # Errors
    /// As [`AgfCatalog::read_file`], naming the file and the line.
    pub fn from_files<P: AsRef<Path>>(paths: &[P]) -> Result<(GlassCatalogs, Vec<String>)> {
        let mut out = GlassCatalogs::default();
        let mut warnings = Vec::new();
        for p in paths {
            let (cat, w) = AgfCatalog::read_file(p.as_ref())?;
            warnings.extend(w);
            out.user.push(cat);
        }
        Ok((out, warnings))
    }

    /// Looks a glass up by name, ignoring case: user catalogs first, then the built-in catalog
    /// and its aliases.
    pub fn find(&self, name: &str) -> Option<Material> {
        self.find_exact(name)
            .or_else(|| find_glass(name).map(Material::Catalog))
    }

    /// As [`GlassCatalogs::find`] but without DeepLens' aliases (`bk7` is not `N-BK7` here).
    pub fn find_exact(&self, name: &str) -> Option<Material> {
        self.user
            .iter()
            .find_map(|c| c.find(name))
            .map(|g| Material::Agf(g.clone()))
            .or_else(|| find_in_vendors(name, &self.vendor_order()).map(Material::Catalog))
    }

    /// Up to `max` glass names closest to `name` (edit distance, case-insensitive): from the
    /// user's catalogs and the built-in vendor `name` belongs to (its prefix, as `S-` for Ohara,
    /// or else the `prefer`red vendors), or from every catalog when neither says.
    pub fn suggest(&self, name: &str, max: usize) -> Vec<String> {
        let q = name.to_ascii_uppercase();
        let vendors: Vec<&str> = match vendor_of_prefix(name) {
            Some(v) => vec![v],
            None => self
                .prefer
                .iter()
                .filter_map(|p| vendor_of_gcat(p))
                .collect(),
        };
        let names = self
            .user
            .iter()
            .flat_map(|c| c.glasses.iter().map(|g| g.name.clone()))
            .chain(
                catalog()
                    .iter()
                    .filter(|g| vendors.is_empty() || vendors.contains(&g.vendor))
                    .map(|g| format!("{} ({})", g.name, g.vendor)),
            );
        let mut scored: Vec<(usize, String)> = names
            .map(|n| {
                let bare = n.split(" (").next().unwrap_or(&n).to_ascii_uppercase();
                (name_distance(&q, &bare), n)
            })
            .filter(|(d, _)| *d <= 3.max(q.len() / 3))
            .collect();
        scored.sort();
        scored.dedup_by(|a, b| a.1.eq_ignore_ascii_case(&b.1));
        scored.into_iter().take(max).map(|(_, n)| n).collect()
    }
}

/// The smallest refractive index tolray accepts: indices are relative to air, so vacuum and
/// purge gases (as in lithography lenses) sit just below 1.
pub const MIN_INDEX: f64 = 0.9;

/// The largest refractive index tolray accepts (germanium, the densest common infrared
/// material, has about 4).
pub const MAX_INDEX: f64 = 5.0;

/// True for a refractive index tolray traces: a finite number from [`MIN_INDEX`] to
/// [`MAX_INDEX`] (NaN is not).
///
/// ```
/// use tolray::lens::material::is_usable_index;
/// assert!(is_usable_index(1.5) && is_usable_index(0.95));
/// assert!(!is_usable_index(0.5) && !is_usable_index(f64::NAN) && !is_usable_index(f64::INFINITY));
/// ```
#[must_use]
pub fn is_usable_index(n: f64) -> bool {
    (MIN_INDEX..=MAX_INDEX).contains(&n)
}

fn check_index(n: f64, s: &str) -> Result<()> {
    if !is_usable_index(n) {
        return Err(Error::invalid(format!(
            "material \"{s}\": refractive index {n} is not a number from {MIN_INDEX} to {MAX_INDEX}"
        )));
    }
    Ok(())
}

/// Why a glass called `name` could not be named in a lens file: `Some` when [`Material::parse`]
/// would read the name as something else (a number, a model glass `n_d/V_d`, air), so a lens
/// written with it would read back with another medium.
pub fn unnameable_glass(name: &str) -> Option<&'static str> {
    let lower = name.trim().to_ascii_lowercase();
    if matches!(lower.as_str(), "air" | "vacuum" | "occluder") {
        Some("reads as air")
    } else if lower.parse::<f64>().is_ok() {
        Some("reads as a constant index")
    } else if lower.contains('/') {
        Some("reads as a model glass n_d/V_d")
    } else if lower.ends_with(')') && lower.contains(" (") {
        Some("reads as a built-in glass with its vendor")
    } else {
        None
    }
}

/// Short names DeepLens' material table accepts, and the catalog glass it uses for each
/// (DeepLens' "sk16" carries N-SK16's coefficients; no public data exists for the old SK16).
const ALIASES: [(&str, &str); 7] = [
    ("bk7", "N-BK7"),
    ("sk16", "N-SK16"),
    ("pc", "POLYCARB"),
    ("polycarbonate", "POLYCARB"),
    ("ps", "POLYSTYR"),
    ("polystyrene", "POLYSTYR"),
    ("fused_silica", "F_SILICA"),
];

/// Vendor names of fused silica whose maker publishes no dispersion formula of its own in a
/// public catalog, and the built-in glass that is the same material: Corning 7980 is the
/// renamed Corning 7940 whose index Malitson (1965) measured, the data behind `F_SILICA`
/// (Corning's data sheet gives n = 1.45702 at 632.8 nm; Malitson's formula 1.45702).
const SAME_MATERIAL: [(&str, &str, &str); 1] =
    [("C79-80", "F_SILICA", "Corning 7980 fused silica")];

/// A glass name that is the same material as a built-in glass under another name (see
/// `SAME_MATERIAL` in the source): the built-in glass and what the name is.
///
/// ```
/// let (g, what) = tolray::lens::material::same_material("c79-80").unwrap();
/// assert_eq!(g.name, "F_SILICA");
/// assert!(what.contains("Corning 7980"));
/// ```
pub fn same_material(name: &str) -> Option<(&'static CatalogGlass, &'static str)> {
    SAME_MATERIAL
        .iter()
        .find(|(n, _, _)| n.eq_ignore_ascii_case(name))
        .and_then(|(_, g, what)| find_in_vendors(g, &VENDOR_ORDER).map(|g| (g, *what)))
}

/// Looks a glass up in the built-in catalog by name or DeepLens alias, ignoring case; a name
/// two vendors share resolves in [`VENDOR_ORDER`].
pub fn find_glass(name: &str) -> Option<&'static CatalogGlass> {
    let name = ALIASES
        .iter()
        .find(|(a, _)| a.eq_ignore_ascii_case(name))
        .map_or(name, |(_, g)| *g);
    find_in_vendors(name, &VENDOR_ORDER)
}

/// The built-in glass `name` (ignoring case) of the first of `vendors` that has it.
pub fn find_in_vendors(name: &str, vendors: &[&str]) -> Option<&'static CatalogGlass> {
    let all = catalog();
    vendors.iter().find_map(|v| {
        all.iter()
            .find(|g| g.vendor == *v && g.name.eq_ignore_ascii_case(name))
    })
}

/// The built-in catalog: the table generated from the vendor pages (`catalog_data.rs`), the one
/// generated from Zemax AGF files (`catalog_agf.rs`: INFRARED, MISC, LightPath, RPO, Hoya's legacy
/// names) and the hand-kept glasses (`catalog_extra.rs`), sorted by vendor then name (ignoring
/// case).
///
/// ```
/// use tolray::lens::material::catalog;
/// let ge = catalog().iter().find(|g| g.name == "GERMANIUM").unwrap();
/// assert_eq!(ge.vendor, "Infrared");
/// assert!(catalog().iter().any(|g| g.name == "WATER" && g.vendor == "Misc"));
/// ```
pub fn catalog() -> &'static [CatalogGlass] {
    static ALL: std::sync::LazyLock<Vec<CatalogGlass>> = std::sync::LazyLock::new(|| {
        let mut all = [
            crate::lens::catalog_data::CATALOG,
            crate::lens::catalog_agf::AGF,
            crate::lens::catalog_extra::EXTRA,
        ]
        .concat();
        all.sort_by_cached_key(|g| (g.vendor.to_ascii_uppercase(), g.name.to_ascii_uppercase()));
        all
    });
    &ALL
}

/// Up to `max` catalog names closest to `name` (edit distance, case-insensitive).
pub fn suggest_glasses(name: &str, max: usize) -> Vec<&'static str> {
    let q = name.to_ascii_uppercase();
    let mut scored: Vec<(usize, &'static str)> = catalog()
        .iter()
        .map(|g| (name_distance(&q, &g.name.to_ascii_uppercase()), g.name))
        .filter(|(d, _)| *d <= 3.max(q.len() / 3))
        .collect();
    scored.sort();
    scored.into_iter().take(max).map(|(_, n)| n).collect()
}

/// How far apart a glass name `q` asked for and a catalog name `name` are (both upper case):
/// their edit distance, but 0 (first among the suggestions) for its nearest relatives: `q` with a variant suffix after `_` or
/// a space (Ohara's `L-TIM28_MOLD`, a moulded `L-TIM28`), and Schott's lead-free successor of
/// a legacy glass, `N-` or `P-` before its name and at most one letter after it (`LAK33` ->
/// `N-LAK33A`, `N-LAK33B`; `BAK1` -> `N-BAK1`).
fn name_distance(q: &str, name: &str) -> usize {
    let d = edit_distance(q, name);
    let variant = q
        .strip_prefix(name)
        .is_some_and(|rest| rest.starts_with(['_', ' ']));
    let successor = ["N-", "P-"].iter().any(|p| {
        name.strip_prefix(p)
            .and_then(|rest| rest.strip_prefix(q))
            .is_some_and(|tail| tail.len() <= 1 && tail.chars().all(|c| c.is_ascii_alphabetic()))
    });
    if variant || successor {
        0
    } else {
        d
    }
}

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != *cb);
            cur[j + 1] = sub.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        prev = cur;
    }
    prev[b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_glass_is_exact_at_d_and_in_abbe_number() {
        let m = Material::parse("1.62041/60.323649").unwrap();
        let (nd, nf, nc) = (
            m.index(LAMBDA_D_NM),
            m.index(LAMBDA_F_NM),
            m.index(LAMBDA_C_NM),
        );
        assert!((nd - 1.62041).abs() < 1e-15);
        assert!(((nd - 1.0) / (nf - nc) - 60.323649).abs() < 1e-9);
    }

    #[test]
    fn tabulated_indices_are_linear_between_points_and_held_beyond() {
        let b270 = find_glass("B270").unwrap();
        let Dispersion::Tabulated { points } = b270.dispersion else {
            panic!("{b270:?}")
        };
        // Each tabulated wavelength gives its own index, bit for bit.
        for &(l, n) in points {
            assert_eq!(b270.dispersion.index(l), n);
        }
        // Halfway between 0.54607 (1.5251) and 0.58756 (1.5230) µm.
        let mid = b270.dispersion.index(0.5 * (0.54607 + 0.58756));
        assert!((mid - 1.52405).abs() < 1e-12, "{mid}");
        // The d line sits 1.8e-6 µm past 0.58756: 1.5230 + 1.8e-6 (1.5229 - 1.5230) / 1.73e-3.
        let d = Material::Catalog(b270).index(LAMBDA_D_NM);
        let want = 1.523 + (0.5875618 - 0.58756) * (1.5229 - 1.523) / (0.58929 - 0.58756);
        assert!((d - want).abs() < 1e-15, "{d} vs {want}");
        // Beyond the table: the end values (the C line is 2.5e-6 µm past the last point).
        assert_eq!(b270.dispersion.index(0.40), 1.5341);
        assert_eq!(b270.dispersion.index(LAMBDA_C_NM * 1e-3), 1.5203);
        assert!(b270.dispersion.index(f64::NAN).is_nan());
        assert!(tabulated(&[], 0.5).is_nan());
    }

    #[test]
    fn catalog_glasses_reproduce_their_nominal_nd_vd() {
        let (mut infrared, mut bad) = (0, Vec::new());
        for g in catalog() {
            let m = Material::Catalog(g);
            if g.range_um.0 > LAMBDA_F_NM * 1e-3 || g.range_um.1 < LAMBDA_C_NM * 1e-3 - 1e-5 {
                // An infrared material (germanium: 2 to 15 µm): a real index across its range.
                infrared += 1;
                let (lo, hi) = g.range_um;
                for um in [lo, (lo * hi).sqrt(), hi] {
                    let n = m.index(um * 1e3);
                    if !(1.0..=MAX_INDEX).contains(&n) {
                        bad.push(format!("{} ({}): n({um} µm) = {n}", g.name, g.vendor));
                    }
                }
                continue;
            }
            let nd = m.index(LAMBDA_D_NM);
            let dispersion = m.index(LAMBDA_F_NM) - m.index(LAMBDA_C_NM);
            if g.vd == 0.0 {
                // A catalog's V_d 0 is a constant index (MISC's N15).
                if (nd - g.nd).abs() >= 5e-5 || dispersion != 0.0 {
                    bad.push(format!("{} ({}): not constant", g.name, g.vendor));
                }
                continue;
            }
            let vd = (nd - 1.0) / dispersion;
            if (nd - g.nd).abs() >= 5e-5 || (vd - g.vd).abs() >= 0.1 {
                bad.push(format!(
                    "{} ({}): n_d {nd}, V_d {vd}; catalog {}, {}",
                    g.name, g.vendor, g.nd, g.vd
                ));
            }
        }
        assert!(bad.is_empty(), "{bad:#?}");
        assert!(infrared >= 20, "{infrared} infrared-only materials");
    }

    #[test]
    fn names_and_errors() {
        assert_eq!(Material::parse("AIR").unwrap(), Material::Air);
        assert!(matches!(
            Material::parse("n-bk7").unwrap(),
            Material::Catalog(_)
        ));
        let e = Material::parse("N-BK8").unwrap_err();
        assert!(e.message().contains("N-BK7"), "{}", e.message());
        assert!(Material::parse("0.8/50").is_err());
        assert_eq!(
            Material::parse("0.9997/0").unwrap(),
            Material::Constant(0.9997)
        );
        assert!(Material::parse("1.5/-3").is_err());
        assert_eq!(Material::parse("1.5").unwrap(), Material::Constant(1.5));
        assert_eq!(Material::parse("1.0/1e38").unwrap(), Material::Air);
    }
}
