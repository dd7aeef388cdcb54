//! `tolray convert`: a lens between Zemax .zmx and DeepLens JSON.

use crate::args::{lens_output_path, load_catalogs};
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::lens::{json, zemax};
use tolray::tolerance::Perturbation;
use tolray::Lens;

/// Arguments of `tolray convert`.
#[derive(Args)]
pub struct ConvertArgs {
    /// Input lens: a .zmx or .json file, or a built-in name.
    pub input: String,
    /// Output file, ending in .zmx or .json.
    #[arg(value_parser = lens_output_path)]
    pub output: PathBuf,
    /// A Zemax AGF glass catalog, searched before the built-in glasses (repeatable).
    #[arg(long = "glass-catalog", value_name = "FILE.agf")]
    pub glass_catalog: Vec<PathBuf>,
    /// When a .zmx GLAS names a glass in no catalog: "refuse" (default: an error naming the
    /// line) or "file-values" (use the n_d and V_d on the GLAS line as a model glass;
    /// OpticStudio's 1.5 / 40 placeholder is still refused).
    #[arg(long = "glass-fallback", value_name = "refuse|file-values", default_value = "refuse", value_parser = ["refuse", "file-values"])]
    pub glass_fallback: String,
    /// Write the lens perturbed by this tolerance pattern (surface decenters and tilts become
    /// coordinate breaks in a .zmx file).
    #[arg(long, value_name = "PATTERN.json")]
    pub perturb: Option<PathBuf>,
}

/// Runs `tolray convert`.
pub fn run(a: ConvertArgs) -> anyhow::Result<()> {
    let ConvertArgs {
        input,
        output,
        glass_catalog,
        glass_fallback,
        perturb,
    } = a;
    let catalogs = load_catalogs(&glass_catalog, &glass_fallback)?;
    let in_path = Path::new(&input);
    let (mut lens, extras) = if zemax::is_zmx_path(in_path) && in_path.exists() {
        let z = zemax::read_file(in_path, &catalogs)?;
        for w in &z.warnings {
            eprintln!("warning: {w}");
        }
        (z.lens, Some(z.extras))
    } else {
        (Lens::load_with_catalogs(&input, &catalogs)?.0, None)
    };
    if let Some(p) = perturb {
        let (perturbed, adj) = Perturbation::read(&p)?.apply(&lens)?;
        lens = perturbed
            .with_adjustments(&adj)
            .with_context(|| format!("{}: cannot write this perturbation", p.display()))?;
    }
    if zemax::is_zmx_path(&output) {
        zemax::write_file(&lens, extras.as_ref(), &output)?;
    } else {
        json::write_file(&lens, &output)?;
    }
    eprintln!("wrote {}", output.display());
    Ok(())
}
