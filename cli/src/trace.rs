//! `tolray trace`: raw rays from a file to the image plane.

use crate::args::LensArgs;
use clap::Args;
use std::path::{Path, PathBuf};
use tolray::trace::raw::{parse_json, trace_csv_to, trace_rays_to, HitFormat};
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
    let is_json = |p: &Path| {
        p.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    };
    let sys = l.compile();
    let opts = TraceOptions {
        apertures: !no_apertures,
    };
    let format = match is_json(&out) {
        true => HitFormat::Json,
        false => HitFormat::Csv,
    };
    // The hits are written as they are traced, to a temporary file renamed over --out at the end
    // (nothing is left there on an error). CSV input streams too; a JSON array is read whole.
    let mut counts = None;
    tolray::files::write_atomic_with(&out, |file| {
        // A failed write is reported with the output's path, not the input's.
        let mut w = Noting {
            inner: file,
            failed: None,
        };
        let n = if is_json(&rays) {
            let text = std::fs::read_to_string(&rays).map_err(|e| tolray::Error::io(&rays, e))?;
            let input = parse_json(&text).map_err(|e| e.context(rays.display()))?;
            trace_rays_to(&sys, &input, &mut w, format, opts)
        } else {
            let file = std::fs::File::open(&rays).map_err(|e| tolray::Error::io(&rays, e))?;
            let input = std::io::BufReader::with_capacity(1 << 20, file);
            trace_csv_to(&sys, input, &mut w, format, opts)
        };
        if let Some(e) = w.failed.take() {
            return Err(tolray::Error::io(&out, e));
        }
        counts = Some(n.map_err(|e| e.context(rays.display()))?);
        Ok(())
    })?;
    let n = counts.unwrap_or_default();
    eprintln!(
        "traced {} rays ({} reached the image) -> {}",
        n.rays,
        n.alive,
        out.display()
    );
    Ok(())
}

/// A writer that keeps a copy of its first error.
struct Noting<W> {
    inner: W,
    failed: Option<std::io::Error>,
}

impl<W: std::io::Write> std::io::Write for Noting<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.inner.write(buf).inspect_err(|e| self.note(e))
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush().inspect_err(|e| self.note(e))
    }
}

impl<W> Noting<W> {
    fn note(&mut self, e: &std::io::Error) {
        if self.failed.is_none() {
            self.failed = Some(std::io::Error::new(e.kind(), e.to_string()));
        }
    }
}
