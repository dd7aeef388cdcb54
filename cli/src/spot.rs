//! `tolray spot`: spot diagrams and RMS spot radii.

use crate::args::{perturbed_system, LensArgs, RayArgs};
use crate::report::{emit, emit_line, spot_table};
use clap::Args;
use std::path::PathBuf;
use tolray::analysis::{afocal_spot_diagram_rows, spot_diagram_rows};
use tolray::figures;

/// Arguments of `tolray spot`.
#[derive(Args)]
pub struct SpotArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    #[command(flatten)]
    pub rays: RayArgs,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write a spot-diagram picture (PNG at 2 pixels per point, or SVG if FILE ends in .svg).
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
    /// Afocal image space (OpticStudio's mode for afocal lenses): spots are the rays' angles
    /// after the lens in the image plane's frame, sizes in µrad and centroids in mrad, instead
    /// of where they land.
    #[arg(long)]
    pub afocal: bool,
    /// Trace the lens perturbed by this tolerance pattern (JSON, as written by `tolerance --json`).
    #[arg(long, value_name = "PATTERN.json")]
    pub perturb: Option<PathBuf>,
}

/// Runs `tolray spot`.
pub fn run(a: SpotArgs) -> anyhow::Result<()> {
    let (l, file_fields) = a.lens.load_with_fields()?;
    let opts = a.rays.options(&l, file_fields)?;
    let sys = perturbed_system(&l, a.perturb.as_deref())?;
    // A field with no ray at the image is a row of its own (reported, and the command fails at
    // the end), not a reason to hide the fields that have spots.
    let rows = if a.afocal {
        afocal_spot_diagram_rows
    } else {
        spot_diagram_rows
    };
    let (results, failures) = rows(&l, &sys, &opts)?;
    if results.is_empty() {
        anyhow::bail!(
            "no field has a spot: {}",
            failures
                .iter()
                .map(|f| f.reason.as_str())
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    if a.json {
        emit_line(&serde_json::to_string_pretty(&results)?.to_string());
    } else {
        emit(&spot_table(&results).to_string());
    }
    if let Some(p) = a.png {
        figures::save(
            &figures::spot_figure(&results, &format!("Spot diagram: {}", a.lens.lens)),
            &p,
        )?;
        eprintln!("wrote {}", p.display());
    }
    if !failures.is_empty() {
        for f in &failures {
            eprintln!("no spot: {}", f.reason);
        }
        anyhow::bail!(
            "{} of {} spot rows have no result (listed above); the other rows are printed",
            failures.len(),
            failures.len() + results.len()
        );
    }
    Ok(())
}
