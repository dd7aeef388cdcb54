//! `tolray layout`: the meridional lens drawing.

use crate::args::{fields_or, LensArgs};
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
    /// Fields (see `spot --fields`) [default: the lens file's fields, else 0,0.7,1].
    #[arg(long, value_delimiter = ',')]
    pub fields: Option<Vec<String>>,
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
    let (l, file_fields) = lens.load_with_fields()?;
    let p = l.paraxial(l.primary_wavelength_nm)?;
    let fields = fields_or(&fields, file_fields, "0,0.7,1")?;
    figures::save(
        &figures::layout_figure(&l, &l.compile(), &p, &fields, l.primary_wavelength_nm, rays)?,
        &png,
    )?;
    eprintln!("wrote {}", png.display());
    Ok(())
}
