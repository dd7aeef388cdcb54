//! Zemax AGF glass catalogs, so users can bring their vendors' catalogs.
//!
//! An AGF file is a sequence of records, one line each, named by a two-letter mnemonic. tolray
//! reads the three that define an index:
//!
//! - `NM name formula MIL n_d V_d exclude status [melt-frequency]` starts a glass;
//! - `CD c1 c2 ... c10` gives the dispersion coefficients of the formula;
//! - `LD min max` gives the wavelength range (µm) in which the formula is valid.
//!
//! Every other record (`CC`, `GC`, `ED`, `TD`, `OD`, `IT`, `MD`, `BD`, ...) and `!` comment lines
//! are skipped: they hold thermal, mechanical, cost and transmission data that the tracer does not
//! use. Formula ids: 1 Schott, 2 Sellmeier 1, 3 Herzberger, 4 Sellmeier 2, 5 Conrady, 6 Sellmeier 3,
//! 7 Handbook of Optics 1, 8 Handbook of Optics 2, 9 Sellmeier 4, 10 Extended, 11 Sellmeier 5,
//! 12 Extended 2, 13 Extended 3 (see [`Dispersion`] for each formula). Indices are relative to
//! air, like every index in tolray, and no temperature or pressure correction is applied.
//!
//! Files may be ASCII, UTF-8 (with or without a byte-order mark) or UTF-16 (as OpticStudio
//! writes them). Every error names the line; [`AgfCatalog::read_file`] adds the file name.

use super::material::{Dispersion, LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};
use super::text::decode;
use crate::error::{Error, ErrorKind, Result};
use std::path::Path;
use std::sync::Arc;

/// A glass read from an AGF catalog.
#[derive(Clone, Debug, PartialEq)]
pub struct AgfGlass {
    /// Name as the catalog writes it (e.g. `N-BK7`).
    pub name: String,
    /// Name of the catalog it came from (the file name without extension, upper case).
    pub catalog: String,
    /// Zemax dispersion formula id (1 to 13).
    pub formula: u32,
    /// The dispersion formula with its coefficients.
    pub dispersion: Dispersion,
    /// The catalog's nominal n_d.
    pub nd: f64,
    /// The catalog's nominal Abbe number V_d.
    pub vd: f64,
    /// Wavelength range of the formula, µm (`(0, inf)` when the catalog gives none).
    pub range_um: (f64, f64),
}

impl AgfGlass {
    /// Refractive index at `wavelength_nm` nanometres.
    pub fn index(&self, wavelength_nm: f64) -> f64 {
        self.dispersion.index(wavelength_nm * 1e-3)
    }
}

/// The first of 65 wavelengths spread over the glass' range (within the wavelengths tolray
/// traces; 0.38–0.78 µm when the catalog gives no range) where its formula gives no usable index
/// (not finite, or outside [`MIN_INDEX`](super::material::MIN_INDEX) to 5), as (µm, index).
pub fn broken_in_range(g: &AgfGlass) -> Option<(f64, f64)> {
    let (lo_nm, hi_nm) = super::material::WAVELENGTH_RANGE_NM;
    let (lo, hi) = if g.range_um.1.is_finite() {
        (
            g.range_um.0.max(lo_nm * 1e-3),
            g.range_um.1.min(hi_nm * 1e-3),
        )
    } else {
        (0.38, 0.78)
    };
    if !(lo <= hi) {
        return None;
    }
    (0..=64).find_map(|k| {
        let um = lo + (hi - lo) * k as f64 / 64.0;
        let n = g.dispersion.index(um);
        (!super::material::is_usable_index(n)).then_some((um, n))
    })
}

/// A glass catalog read from an AGF file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AgfCatalog {
    /// Catalog name (the file name without extension, upper case, as Zemax's `GCAT` names it).
    pub name: String,
    /// The glasses in file order.
    pub glasses: Vec<Arc<AgfGlass>>,
}

/// A glass being read: its `NM` line and whatever followed.
struct Pending {
    line: usize,
    name: String,
    formula: u32,
    nd: f64,
    vd: f64,
    cd: Option<Vec<f64>>,
    range_um: (f64, f64),
}

fn parse_err(line: usize, msg: impl std::fmt::Display) -> Error {
    Error::new(ErrorKind::Parse, format!("line {line}: {msg}"))
}

fn number(tok: &str, line: usize, what: &str) -> Result<f64> {
    match tok.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(parse_err(
            line,
            format!("{what}: \"{tok}\" is not a finite number"),
        )),
    }
}

/// The [`Dispersion`] of Zemax formula `id` with coefficients `c` (missing ones are 0).
pub fn dispersion_from_agf(id: u32, c: &[f64]) -> Option<Dispersion> {
    let k = |i: usize| c.get(i).copied().unwrap_or(0.0);
    let arr = |n: usize| -> Vec<f64> { (0..n).map(k).collect() };
    let pairs = |n: usize| -> (Vec<f64>, Vec<f64>) {
        (
            (0..n).map(|i| k(2 * i)).collect(),
            (0..n).map(|i| k(2 * i + 1)).collect(),
        )
    };
    fn fixed<const N: usize>(v: &[f64]) -> [f64; N] {
        let mut out = [0.0; N];
        for (o, x) in out.iter_mut().zip(v) {
            *o = *x;
        }
        out
    }
    Some(match id {
        1 => Dispersion::Schott { a: fixed(&arr(6)) },
        2 => {
            let (b, c) = pairs(3);
            Dispersion::Sellmeier3 {
                b: fixed(&b),
                c: fixed(&c),
            }
        }
        3 => Dispersion::Herzberger { a: fixed(&arr(6)) },
        4 => Dispersion::ZemaxSellmeier2 { a: fixed(&arr(5)) },
        5 => Dispersion::Conrady { a: fixed(&arr(3)) },
        6 => {
            let (b, c) = pairs(4);
            Dispersion::Sellmeier4 {
                b: fixed(&b),
                c: fixed(&c),
            }
        }
        7 => Dispersion::Handbook1 { a: fixed(&arr(4)) },
        8 => Dispersion::Handbook2 { a: fixed(&arr(4)) },
        9 => Dispersion::ZemaxSellmeier4 { a: fixed(&arr(5)) },
        10 => Dispersion::ExtendedSchott { a: fixed(&arr(8)) },
        11 => {
            let (b, c) = pairs(5);
            Dispersion::Sellmeier5 {
                b: fixed(&b),
                c: fixed(&c),
            }
        }
        12 => Dispersion::Extended2 { a: fixed(&arr(8)) },
        13 => Dispersion::Extended { a: fixed(&arr(9)) },
        _ => return None,
    })
}

impl AgfCatalog {
    /// Reads an AGF file. The catalog is named after the file (`SCHOTT.AGF` → `SCHOTT`).
    /// Returns the catalog and warnings (duplicate names, a formula that does not reproduce the
    /// catalog's n_d).
    ///
    /// # Errors
    /// [`ErrorKind::Io`] naming the path, or [`ErrorKind::Parse`] naming the path and the line.
    pub fn read_file(path: &Path) -> Result<(AgfCatalog, Vec<String>)> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().to_ascii_uppercase())
            .unwrap_or_default();
        let (cat, warnings) =
            AgfCatalog::from_bytes(&bytes, &name).map_err(|e| e.context(path.display()))?;
        let warnings = warnings
            .into_iter()
            .map(|w| format!("{}: {w}", path.display()))
            .collect();
        Ok((cat, warnings))
    }

    /// Parses AGF bytes in any of the supported encodings.
    ///
    /// # Errors
    /// As [`AgfCatalog::from_str`].
    pub fn from_bytes(bytes: &[u8], name: &str) -> Result<(AgfCatalog, Vec<String>)> {
        AgfCatalog::from_str(&decode(bytes), name)
    }

    /// Parses AGF text into a catalog called `name`.
    ///
    /// # Errors
    /// [`ErrorKind::Parse`] naming the line: a number that does not parse, an unknown formula
    /// id, a `CD` or `LD` line before any `NM`, a glass without a `CD` line, a file without glasses.
    #[allow(clippy::should_implement_trait)]
    pub fn from_str(text: &str, name: &str) -> Result<(AgfCatalog, Vec<String>)> {
        let mut glasses: Vec<Arc<AgfGlass>> = Vec::new();
        let mut warnings = Vec::new();
        let mut pending: Option<Pending> = None;
        let mut finish = |p: Pending, glasses: &mut Vec<Arc<AgfGlass>>| -> Result<()> {
            let cd = p.cd.ok_or_else(|| {
                parse_err(
                    p.line,
                    format!("glass {} has no CD line (dispersion coefficients)", p.name),
                )
            })?;
            let dispersion = dispersion_from_agf(p.formula, &cd).ok_or_else(|| {
                parse_err(
                    p.line,
                    format!("glass {}: unknown formula {}", p.name, p.formula),
                )
            })?;
            let glass = AgfGlass {
                name: p.name,
                catalog: name.to_string(),
                formula: p.formula,
                dispersion,
                nd: p.nd,
                vd: p.vd,
                range_um: p.range_um,
            };
            let nd = glass.index(LAMBDA_D_NM);
            let vd = (nd - 1.0) / (glass.index(LAMBDA_F_NM) - glass.index(LAMBDA_C_NM));
            if !(nd.is_finite() && (nd - glass.nd).abs() <= 1e-3) && glass.nd > 0.0 {
                warnings.push(format!(
                    "line {}: glass {}: formula {} gives n_d = {nd:.6}, the catalog says {} (check the coefficients)",
                    p.line, glass.name, glass.formula, glass.nd
                ));
            } else if glass.vd > 0.0 && !((vd - glass.vd).abs() <= 0.5) {
                warnings.push(format!(
                    "line {}: glass {}: formula {} gives V_d = {vd:.3}, the catalog says {} (check the coefficients)",
                    p.line, glass.name, glass.formula, glass.vd
                ));
            }
            if let Some(why) = super::material::unnameable_glass(&glass.name) {
                warnings.push(format!(
                    "line {}: glass \"{}\" {why} in a lens file, so no lens could name it; \
                     the glass is skipped (rename it in the catalog)",
                    p.line, glass.name
                ));
            } else if let Some((um, n)) = broken_in_range(&glass) {
                warnings.push(format!(
                    "line {}: glass {}: formula {} gives n = {n} at {um:.4} µm, inside its range \
                     {}–{} µm; the glass is skipped (check the coefficients)",
                    p.line, glass.name, glass.formula, glass.range_um.0, glass.range_um.1
                ));
            } else if glasses
                .iter()
                .any(|g| g.name.eq_ignore_ascii_case(&glass.name))
            {
                warnings.push(format!(
                    "line {}: glass {} appears twice; the first one is used",
                    p.line, glass.name
                ));
            } else {
                glasses.push(Arc::new(glass));
            }
            Ok(())
        };
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let mut toks = raw.split_whitespace();
            let Some(code) = toks.next() else { continue };
            let rest: Vec<&str> = toks.collect();
            match code.to_ascii_uppercase().as_str() {
                "NM" => {
                    if let Some(p) = pending.take() {
                        finish(p, &mut glasses)?;
                    }
                    let gname = rest
                        .first()
                        .ok_or_else(|| parse_err(line, "NM needs a glass name and a formula id"))?;
                    let f = rest.get(1).ok_or_else(|| {
                        parse_err(line, format!("NM {gname}: missing the formula id"))
                    })?;
                    let f = number(f, line, &format!("NM {gname}: formula id"))?;
                    if f.fract() != 0.0 || !(1.0..=13.0).contains(&f) {
                        return Err(parse_err(
                            line,
                            format!(
                                "glass {gname}: unknown dispersion formula {f} (tolray reads Zemax formulas 1 to 13)"
                            ),
                        ));
                    }
                    let opt = |k: usize, what: &str| -> Result<f64> {
                        match rest.get(k) {
                            Some(t) => number(t, line, &format!("NM {gname}: {what}")),
                            None => Ok(0.0),
                        }
                    };
                    pending = Some(Pending {
                        line,
                        name: gname.to_string(),
                        formula: f as u32,
                        nd: opt(3, "n_d")?,
                        vd: opt(4, "V_d")?,
                        cd: None,
                        range_um: (0.0, f64::INFINITY),
                    });
                }
                "CD" => {
                    let p = pending
                        .as_mut()
                        .ok_or_else(|| parse_err(line, "CD before any NM line"))?;
                    let cd = rest
                        .iter()
                        .enumerate()
                        .map(|(k, t)| number(t, line, &format!("CD coefficient {}", k + 1)))
                        .collect::<Result<Vec<f64>>>()?;
                    p.cd = Some(cd);
                }
                "LD" => {
                    let p = pending
                        .as_mut()
                        .ok_or_else(|| parse_err(line, "LD before any NM line"))?;
                    if rest.len() < 2 {
                        return Err(parse_err(line, "LD needs two wavelengths (min max, µm)"));
                    }
                    let lo = number(rest[0], line, "LD minimum wavelength")?;
                    let hi = number(rest[1], line, "LD maximum wavelength")?;
                    if !(lo < hi) {
                        return Err(parse_err(
                            line,
                            format!("LD {lo} {hi}: the minimum must be below the maximum"),
                        ));
                    }
                    p.range_um = (lo, hi);
                }
                _ => {}
            }
        }
        if let Some(p) = pending.take() {
            finish(p, &mut glasses)?;
        }
        if glasses.is_empty() {
            return Err(Error::new(
                ErrorKind::Parse,
                "no glass found (an AGF catalog has NM lines)",
            ));
        }
        Ok((
            AgfCatalog {
                name: name.to_string(),
                glasses,
            },
            warnings,
        ))
    }

    /// The glass called `name` (case-insensitive), if present.
    pub fn find(&self, name: &str) -> Option<&Arc<AgfGlass>> {
        self.glasses
            .iter()
            .find(|g| g.name.eq_ignore_ascii_case(name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(formula: u32, cd: &str) -> AgfGlass {
        let text = format!("CC test\nNM G {formula} 0 0 0 0 1\nCD {cd}\nLD 0.3 2.5\n");
        let (c, _) = AgfCatalog::from_str(&text, "T").unwrap();
        (*c.glasses[0]).clone()
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-14 * b.abs()
    }

    /// Each formula reduces to a simpler one with some coefficients zero, or is checked against
    /// its equation written out; this pins the coefficient order of every formula id.
    #[test]
    fn every_formula_reads_its_coefficients_in_zemax_order() {
        let s1 = one(
            2,
            "1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002 1.01046945 1.03560653E+002",
        );
        let s3 = one(6, "1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002 1.01046945 1.03560653E+002 0 0");
        let s5 = one(11, "1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002 1.01046945 1.03560653E+002 0 0 0 0");
        let schott = one(1, "2.27 -0.0101 0.0106 0.00029 -1.6e-5 1.1e-6");
        let ext = one(10, "2.27 -0.0101 0.0106 0.00029 -1.6e-5 1.1e-6 0 0");
        let ext2 = one(12, "2.27 -0.0101 0.0106 0.00029 -1.6e-5 1.1e-6 0 0");
        let ext3 = one(13, "2.27 -0.0101 0 0.0106 0.00029 -1.6e-5 1.1e-6 0 0");
        // Sellmeier 4 = A + two Sellmeier terms; with A = 1 it is a two-term Sellmeier 1.
        let s4 = one(
            9,
            "1 1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002",
        );
        let s1two = one(
            2,
            "1.03961212 6.00069867E-003 2.31792344E-001 2.00179144E-002 0 0",
        );
        // Handbook 2 with D = 0, A = 1 is a one-term Sellmeier.
        let h2 = one(8, "1 1.03961212 6.00069867E-003 0");
        let s1one = one(2, "1.03961212 6.00069867E-003 0 0 0 0");
        // Sellmeier 2 with A = 0, B2 = 0: one term with the resonance squared.
        let sz2 = one(4, "0 1.03961212 0.0774641 0 0");
        for l in [0.4, 0.5875618, 0.7, 1.0, 1.5] {
            let n = |g: &AgfGlass| g.dispersion.index(l);
            assert!(close(n(&s3), n(&s1)) && close(n(&s5), n(&s1)), "{l}");
            assert!(
                close(n(&ext), n(&schott)) && close(n(&ext2), n(&schott)),
                "{l}"
            );
            assert!(close(n(&ext3), n(&schott)), "{l}");
            assert!(close(n(&s4), n(&s1two)) && close(n(&h2), n(&s1one)), "{l}");
            let l2 = l * l;
            let c = 0.0774641f64 * 0.0774641;
            assert!(
                close(n(&sz2), (1.0 + 1.03961212 * l2 / (l2 - c)).sqrt()),
                "{l}"
            );
            // Written out: Herzberger, Conrady, Handbook 1, and the extra terms of Extended 2.
            let h = one(3, "1.5 0.004 0.0003 -0.002 1e-5 -2e-7");
            let ll = 1.0 / (l2 - 0.028);
            let want = 1.5 + 0.004 * ll + 0.0003 * ll * ll - 0.002 * l2 + 1e-5 * l2 * l2
                - 2e-7 * l2 * l2 * l2;
            assert!(close(n(&h), want), "Herzberger {l}");
            let c5 = one(5, "1.5 0.004 0.0003");
            let want = 1.5 + 0.004 / l + 0.0003 / l.powf(3.5);
            assert!(close(n(&c5), want), "Conrady {l}");
            let h1 = one(7, "2.3 0.01 0.02 0.005");
            let want = (2.3 + 0.01 / (l2 - 0.02) - 0.005 * l2).sqrt();
            assert!(close(n(&h1), want), "Handbook 1 {l}");
            let e2 = one(12, "2.27 -0.0101 0.0106 0.00029 -1.6e-5 1.1e-6 3e-4 -2e-5");
            let want = (n(&schott).powi(2) + 3e-4 * l2 * l2 - 2e-5 * l2 * l2 * l2).sqrt();
            assert!((n(&e2) - want).abs() < 1e-14, "Extended 2 {l}");
            let e1 = one(10, "2.27 -0.0101 0.0106 0.00029 -1.6e-5 1.1e-6 3e-8 -2e-9");
            let want = (n(&schott).powi(2) + 3e-8 / l2.powi(5) - 2e-9 / l2.powi(6)).sqrt();
            assert!((n(&e1) - want).abs() < 1e-14, "Extended {l}");
        }
    }

    #[test]
    fn errors_name_the_line() {
        let e = AgfCatalog::from_str("CC x\nNM A 14 0 1.5 60\nCD 1\n", "T").unwrap_err();
        assert!(
            e.message().starts_with("line 2:") && e.message().contains("formula 14"),
            "{}",
            e.message()
        );
        let e = AgfCatalog::from_str("CC x\nCD 1 2\n", "T").unwrap_err();
        assert!(
            e.message().starts_with("line 2: CD before any NM"),
            "{}",
            e.message()
        );
        let e = AgfCatalog::from_str("NM A 2 0 1.5 60\nCD 1 x 3\n", "T").unwrap_err();
        assert!(
            e.message().starts_with("line 2: CD coefficient 2"),
            "{}",
            e.message()
        );
        let e = AgfCatalog::from_str("NM A 2 0 1.5 60\nLD 0.3\n", "T").unwrap_err();
        assert!(
            e.message().starts_with("line 2: LD needs"),
            "{}",
            e.message()
        );
        let e =
            AgfCatalog::from_str("NM A 2 0 1.5 60\nNM B 2 0 1.5 60\nCD 1 0.01\n", "T").unwrap_err();
        assert!(
            e.message().contains("line 1: glass A has no CD"),
            "{}",
            e.message()
        );
        assert!(AgfCatalog::from_str("CC nothing\n", "T").is_err());
    }

    /// Found by the fuzzer (examples/fuzz.rs): a mutated coefficient gave N-BK7 a NaN index
    /// inside its LD range, and the glass was kept (a `tolray glass` of it printed NaN).
    #[test]
    fn a_glass_whose_formula_fails_inside_its_range_is_skipped_with_a_warning() {
        let text = "NM GOOD 2 0 1.5168 64.17 0 1\nCD 1.03961212 6.00069867E-003 \
                    2.31792344E-001 2.00179144E-002 1.01046945 1.03560653E+002\nLD 0.3 2.5\n\
                    NM BAD 2 0 1.5168 64.17 0 1\nCD 1.03961212 6.00069867E-003 \
                    2.31792344E-001 1.2 1.01046945 1.03560653E+002\nLD 0.3 2.5\n";
        let (c, w) = AgfCatalog::from_str(text, "T").unwrap();
        assert_eq!(c.glasses.len(), 1, "{w:?}");
        assert_eq!(c.glasses[0].name, "GOOD");
        assert!(broken_in_range(&c.glasses[0]).is_none());
        assert!(
            w.iter()
                .any(|m| m.starts_with("line 4: glass BAD") && m.contains("skipped")),
            "{w:?}"
        );
    }
}
