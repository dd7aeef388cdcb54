//! `tolray info`: paraxial data and prescription.

use crate::args::LensArgs;
use crate::report::{emit, emit_line, paraxial_text};
use clap::Args;
use tolray::lens::json;

/// Arguments of `tolray info`.
#[derive(Args)]
pub struct InfoArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Wavelength for the paraxial data, nm (default: the lens' primary wavelength).
    #[arg(long, value_name = "NM")]
    pub wavelength: Option<f64>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `tolray info`.
pub fn run(a: InfoArgs) -> anyhow::Result<()> {
    let l = a.lens.load()?;
    let p = l.paraxial(a.wavelength.unwrap_or(l.primary_wavelength_nm))?;
    if a.json {
        let v = serde_json::json!({ "paraxial": p, "lens": json::to_value(&l), "warnings": l.warnings() });
        emit_line(&serde_json::to_string_pretty(&v)?.to_string());
    } else {
        emit(&paraxial_text(&l, &p).to_string());
    }
    Ok(())
}
