//! `tolray glass`: a glass looked up in the catalogs.

use crate::args::load_catalogs;
use crate::report::emit;
use anyhow::bail;
use clap::Args;
use std::path::PathBuf;
use tolray::lens::material::{self, LAMBDA_C_NM, LAMBDA_D_NM, LAMBDA_F_NM};

/// Arguments of `tolray glass`.
#[derive(Args)]
pub struct GlassArgs {
    /// Glass name as the vendor writes it (e.g. N-BK7, S-LAH64, H-ZF52); case-insensitive.
    pub name: String,
    /// A Zemax AGF glass catalog, searched before the built-in glasses (repeatable).
    #[arg(long = "glass-catalog", value_name = "FILE.agf")]
    pub glass_catalog: Vec<PathBuf>,
    /// Wavelengths in nm at which to print the index (default: F, d, C lines).
    #[arg(long, value_delimiter = ',', value_name = "NM,...")]
    pub wavelengths: Vec<f64>,
}

/// Runs `tolray glass`.
pub fn run(a: GlassArgs) -> anyhow::Result<()> {
    emit(&glass_text(&a.name, &a.glass_catalog, &a.wavelengths)?);
    Ok(())
}

/// `tolray glass`: what the catalogs say of one glass.
fn glass_text(name: &str, agf: &[PathBuf], wavelengths_nm: &[f64]) -> anyhow::Result<String> {
    let catalogs = load_catalogs(agf, "refuse")?;
    let Some(m) = catalogs.find(name) else {
        let close = catalogs.suggest(name, 5);
        bail!(
            "glass \"{name}\" is in no catalog (built in: {}){}",
            catalogs.vendor_order().join(", "),
            if close.is_empty() {
                String::new()
            } else {
                format!("; closest: {}", close.join(", "))
            }
        );
    };
    let (vendor, formula, nd, vd, range) = match &m {
        material::Material::Catalog(g) => (
            g.vendor.to_string(),
            format!("{:?}", g.dispersion),
            g.nd,
            g.vd,
            g.range_um,
        ),
        material::Material::Agf(g) => (
            format!("{} (AGF file)", g.catalog),
            format!("AGF formula {}: {:?}", g.formula, g.dispersion),
            g.nd,
            g.vd,
            g.range_um,
        ),
        _ => bail!("\"{name}\" is not a catalog glass"),
    };
    let label = m.catalog_name().unwrap_or(name).to_string();
    let mut s = format!("{label}  ({vendor})\n");
    s += &format!("  formula       {formula}\n");
    s += &format!("  valid range   {:.3} – {:.3} µm\n", range.0, range.1);
    s += &format!("  catalog       n_d {nd:.6}, V_d {vd:.4}\n");
    let others: Vec<&str> = material::catalog()
        .iter()
        .filter(|g| g.name.eq_ignore_ascii_case(&label) && g.vendor != vendor)
        .map(|g| g.vendor)
        .collect();
    if !others.is_empty() {
        s += &format!(
            "  also named so in {} (a .zmx file's GCAT decides which is used)\n",
            others.join(", ")
        );
    }
    let wl: Vec<(String, f64)> = if wavelengths_nm.is_empty() {
        vec![
            ("F".into(), LAMBDA_F_NM),
            ("d".into(), LAMBDA_D_NM),
            ("C".into(), LAMBDA_C_NM),
        ]
    } else {
        wavelengths_nm.iter().map(|&w| (String::new(), w)).collect()
    };
    for (line, w) in wl {
        material::check_wavelength_nm(w)?;
        let n = m.index(w);
        let note = if (range.0..=range.1).contains(&(w * 1e-3)) {
            ""
        } else {
            "  (outside the formula's range)"
        };
        s += &format!("  n({w:.4} nm){:3}  {n:.6}{note}\n", line);
    }
    Ok(s)
}
