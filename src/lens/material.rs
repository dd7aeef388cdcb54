//! Optical materials: air, model glasses given by (n_d, V_d), and catalog glasses.

use crate::error::{Error, Result};

/// The d line (helium), nm: the wavelength at which n_d is defined.
pub const LAMBDA_D_NM: f64 = 587.5618;
/// The F line (hydrogen), nm.
pub const LAMBDA_F_NM: f64 = 486.1327;
/// The C line (hydrogen), nm.
pub const LAMBDA_C_NM: f64 = 656.2725;

/// A dispersion formula of a catalog glass; wavelengths in micrometres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Dispersion {
    /// n² − 1 = Σ b_i λ² / (λ² − c_i), c in µm².
    Sellmeier3 {
        /// Numerator coefficients.
        b: [f64; 3],
        /// Resonance coefficients (µm²).
        c: [f64; 3],
    },
    /// Four-term Sellmeier, as [`Dispersion::Sellmeier3`].
    Sellmeier4 {
        /// Numerator coefficients.
        b: [f64; 4],
        /// Resonance coefficients (µm²).
        c: [f64; 4],
    },
    /// Schott formula: n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸.
    Schott {
        /// Coefficients a0..a5.
        a: [f64; 6],
    },
    /// Extended formula (Hikari): n² = a0 + a1 λ² + a2 λ⁴ + a3 λ⁻² + a4 λ⁻⁴ + a5 λ⁻⁶ + a6 λ⁻⁸
    /// + a7 λ⁻¹⁰ + a8 λ⁻¹².
    Extended {
        /// Coefficients a0..a8.
        a: [f64; 9],
    },
}

impl Dispersion {
    /// Refractive index at `lambda_um` micrometres.
    pub fn index(&self, lambda_um: f64) -> f64 {
        let l2 = lambda_um * lambda_um;
        let n2 = match self {
            Dispersion::Sellmeier3 { b, c } => {
                1.0 + (0..3).map(|i| b[i] * l2 / (l2 - c[i])).sum::<f64>()
            }
            Dispersion::Sellmeier4 { b, c } => {
                1.0 + (0..4).map(|i| b[i] * l2 / (l2 - c[i])).sum::<f64>()
            }
            Dispersion::Schott { a } => {
                let il2 = 1.0 / l2;
                a[0] + a[1] * l2 + il2 * (a[2] + il2 * (a[3] + il2 * (a[4] + il2 * a[5])))
            }
            Dispersion::Extended { a } => {
                let il2 = 1.0 / l2;
                let neg = il2
                    * (a[3]
                        + il2 * (a[4] + il2 * (a[5] + il2 * (a[6] + il2 * (a[7] + il2 * a[8])))));
                a[0] + l2 * (a[1] + l2 * a[2]) + neg
            }
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
}

impl Material {
    /// Refractive index at `wavelength_nm` nanometres.
    pub fn index(&self, wavelength_nm: f64) -> f64 {
        match self {
            Material::Air => 1.0,
            Material::Constant(n) => *n,
            Material::Model { nd, vd } => {
                let inv2 = |l: f64| 1.0 / (l * l);
                let b = (nd - 1.0) / vd / (inv2(LAMBDA_F_NM) - inv2(LAMBDA_C_NM));
                let a = nd - b * inv2(LAMBDA_D_NM);
                a + b * inv2(wavelength_nm)
            }
            Material::Catalog(g) => g.dispersion.index(wavelength_nm * 1e-3),
            Material::Perturbed {
                base,
                nd,
                nd_new,
                scale,
            } => nd_new + (base.index(wavelength_nm) - nd) * scale,
        }
    }

    /// True for air (the medium that separates elements).
    pub fn is_air(&self) -> bool {
        matches!(self, Material::Air)
    }

    /// The name DeepLens' JSON uses for this material (`air`, `n-bk7`, `1.5168/64.17`).
    pub fn json_name(&self) -> String {
        match self {
            Material::Air => "air".to_string(),
            Material::Constant(n) => format!("{n}"),
            Material::Model { nd, vd } => format!("{nd}/{vd}"),
            Material::Catalog(g) => g.name.to_ascii_lowercase(),
            Material::Perturbed { nd_new, scale, .. } => {
                let disp = self.index(LAMBDA_F_NM) - self.index(LAMBDA_C_NM);
                let _ = scale;
                format!("{nd_new}/{}", (nd_new - 1.0) / disp)
            }
        }
    }

    /// Parses a material name as DeepLens writes it: `air` (also `vacuum`, `occluder`), a catalog
    /// name in any case (`n-bk7`, `N-BK7`), a model glass `"n_d/V_d"`, or a constant index `"1.5"`.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] for an unknown glass (with the closest catalog names), an
    /// index below 1, or a non-positive Abbe number.
    pub fn parse(name: &str) -> Result<Material> {
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
        if let Some(g) = find_glass(s) {
            return Ok(Material::Catalog(g));
        }
        let close = suggest_glasses(s, 3);
        let hint = if close.is_empty() {
            String::new()
        } else {
            format!(" (did you mean {}?)", close.join(", "))
        };
        Err(Error::invalid(format!(
            "unknown glass \"{s}\"{hint}; use a catalog name, \"air\", or a model glass \"n_d/V_d\""
        )))
    }

    /// A model glass, checked.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] if `nd < 1`, `vd <= 0` or either is not finite.
    pub fn model(nd: f64, vd: f64) -> Result<Material> {
        check_index(nd, &format!("{nd}/{vd}"))?;
        if !(vd > 0.0) {
            return Err(Error::invalid(format!(
                "material \"{nd}/{vd}\": Abbe number must be positive"
            )));
        }
        // DeepLens writes 1e38 for a dispersion-free medium.
        if vd >= 1e30 || !vd.is_finite() {
            return Ok(if nd == 1.0 {
                Material::Air
            } else {
                Material::Constant(nd)
            });
        }
        Ok(Material::Model { nd, vd })
    }
}

fn check_index(n: f64, s: &str) -> Result<()> {
    if !(n >= 1.0) || !n.is_finite() {
        return Err(Error::invalid(format!(
            "material \"{s}\": refractive index {n} is below 1 or not finite"
        )));
    }
    Ok(())
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

/// Looks a glass up in the built-in catalog by name or DeepLens alias, ignoring case.
pub fn find_glass(name: &str) -> Option<&'static CatalogGlass> {
    let name = ALIASES
        .iter()
        .find(|(a, _)| a.eq_ignore_ascii_case(name))
        .map_or(name, |(_, g)| *g);
    crate::lens::catalog_data::CATALOG
        .iter()
        .find(|g| g.name.eq_ignore_ascii_case(name))
}

/// The built-in catalog.
pub fn catalog() -> &'static [CatalogGlass] {
    crate::lens::catalog_data::CATALOG
}

/// Up to `max` catalog names closest to `name` (edit distance, case-insensitive).
pub fn suggest_glasses(name: &str, max: usize) -> Vec<&'static str> {
    let q = name.to_ascii_uppercase();
    let mut scored: Vec<(usize, &'static str)> = catalog()
        .iter()
        .map(|g| (edit_distance(&q, &g.name.to_ascii_uppercase()), g.name))
        .filter(|(d, _)| *d <= 3.max(q.len() / 3))
        .collect();
    scored.sort();
    scored.into_iter().take(max).map(|(_, n)| n).collect()
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
    fn catalog_glasses_reproduce_their_nominal_nd_vd() {
        for g in catalog() {
            let m = Material::Catalog(g);
            let nd = m.index(LAMBDA_D_NM);
            let vd = (nd - 1.0) / (m.index(LAMBDA_F_NM) - m.index(LAMBDA_C_NM));
            assert!((nd - g.nd).abs() < 5e-5, "{}: n_d {nd} vs {}", g.name, g.nd);
            assert!((vd - g.vd).abs() < 0.1, "{}: V_d {vd} vs {}", g.name, g.vd);
        }
    }

    #[test]
    fn names_and_errors() {
        assert_eq!(Material::parse("AIR").unwrap(), Material::Air);
        assert!(matches!(
            Material::parse("n-bk7").unwrap(),
            Material::Catalog(_)
        ));
        let e = Material::parse("N-BK8").unwrap_err();
        assert!(e.message.contains("N-BK7"), "{}", e.message);
        assert!(Material::parse("0.9/50").is_err());
        assert!(Material::parse("1.5/-3").is_err());
        assert_eq!(Material::parse("1.5").unwrap(), Material::Constant(1.5));
        assert_eq!(Material::parse("1.0/1e38").unwrap(), Material::Air);
    }
}
