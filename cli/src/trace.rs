//! `tolray trace`: raw rays from a file to the image plane.

use crate::args::LensArgs;
use crate::report::write_text;
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::trace::raw::{parse_csv, parse_json, to_csv, trace_raw};
use tolray::trace::TraceOptions;

/// Arguments of `tolray trace`.
#[derive(Args)]
pub struct TraceArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Input rays: CSV with columns ox,oy,oz,dx,dy,dz,wavelength_nm (mm, global frame; directions need not be normalized), or a .json array of such objects.
    #[arg(long, value_name = "FILE")]
    pub rays: PathBuf,
    /// Output: one row per input ray, x,y,z,dx,dy,dz,opl_mm,status (CSV, or JSON if the name ends in .json).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Ignore clear apertures and the stop.
    #[arg(long)]
    pub no_apertures: bool,
}

/// Runs `tolray trace`.
pub fn run(a: TraceArgs) -> anyhow::Result<()> {
    let TraceArgs {
        lens,
        rays,
        out,
        no_apertures,
    } = a;
    let l = lens.load()?;
    let text = std::fs::read_to_string(&rays)
        .with_context(|| format!("{}: cannot read", rays.display()))?;
    let is_json = |p: &Path| {
        p.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    };
    let input = if is_json(&rays) {
        parse_json(&text)
    } else {
        parse_csv(&text)
    }
    .map_err(|e| e.context(rays.display()))?;
    let hits = trace_raw(
        &l.compile(),
        &input,
        TraceOptions {
            apertures: !no_apertures,
        },
    )
    .map_err(|e| e.context(rays.display()))?;
    let body = if is_json(&out) {
        serde_json::to_string_pretty(&hits)? + "\n"
    } else {
        to_csv(&hits)
    };
    write_text(&out, &body)?;
    let alive = hits.iter().filter(|h| h.status == "alive").count();
    eprintln!(
        "traced {} rays ({alive} reached the image) -> {}",
        hits.len(),
        out.display()
    );
    Ok(())
}
