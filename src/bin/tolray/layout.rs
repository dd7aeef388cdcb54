//! `tolray layout`: the meridional lens drawing.

use crate::args::{parse_fields, LensArgs};
use crate::usage;
use clap::Args;
use std::path::PathBuf;
use tolray::figures;

/// Arguments of `tolray layout`.
#[derive(Args)]
pub struct LayoutArgs {
    #[command(flatten)]
    pub lens: LensArgs,
    /// Output picture (PNG at 2 pixels per point, or SVG if FILE ends in .svg).
    #[arg(long, value_name = "FILE.png")]
    pub png: PathBuf,
    /// Fields (see `spot --fields`).
    #[arg(long, value_delimiter = ',', default_value = "0,0.7,1")]
    pub fields: Vec<String>,
    /// Rays per field fan.
    #[arg(long, default_value_t = 7)]
    pub rays: usize,
}

/// Runs `tolray layout`.
pub fn run(a: LayoutArgs) -> anyhow::Result<()> {
    let LayoutArgs {
        lens,
        png,
        fields,
        rays,
    } = a;
    if rays == 0 || rays > 1000 {
        usage!("--rays {rays}: give 1 to 1000 rays per field");
    }
    let l = lens.load()?;
    let p = l.paraxial(l.primary_wavelength_nm)?;
    let fields = parse_fields(&fields)?;
    figures::save(
        &figures::layout_figure(&l, &l.compile(), &p, &fields, l.primary_wavelength_nm, rays)?,
        &png,
    )?;
    eprintln!("wrote {}", png.display());
    Ok(())
}
