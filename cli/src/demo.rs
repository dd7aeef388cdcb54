//! `tolray demo`: the main job on built-in defaults.

use crate::deep;
use crate::report::{
    emit, emit_line, paraxial_text, spot_table, tolerance_text, with_progress, write_text,
};
use anyhow::Context;
use clap::{Args, Parser};
use std::path::{Path, PathBuf};
use tolray::analysis::{spot_diagram, SpotOptions};
use tolray::figures;
use tolray::tolerance::{monte_carlo, sensitivity, McOptions, ToleranceSpec};
use tolray::trace::{Field, Pupil, TraceOptions};
use tolray::Lens;

/// Arguments of `tolray demo`.
#[derive(Args)]
pub struct DemoArgs {
    /// Output directory for the pictures and JSON reports.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Run the optics tour instead of the deep-optics study.
    #[arg(long)]
    pub optics: bool,
    /// Any further `deep` flags, after `--` (e.g. `-- --trials 20`).
    #[arg(last = true)]
    pub extra: Vec<String>,
}

/// Runs `tolray demo`.
pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    if a.optics {
        return optics_tour(&a.out);
    }
    #[derive(Parser)]
    struct DeepDemo {
        #[command(flatten)]
        a: deep::DeepArgs,
    }
    let out_s = a.out.to_string_lossy().into_owned();
    let mut argv = vec!["demo", "lens1", "--out", out_s.as_str()];
    argv.extend(a.extra.iter().map(String::as_str));
    let d = DeepDemo::try_parse_from(argv)?;
    deep::deep(&d.a)
}

/// The optics tour (`demo --optics`): info, spots, pictures and tolerances of every built-in
/// lens.
fn optics_tour(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("{}: cannot create directory", out.display()))?;
    for name in tolray::lens::builtin_names() {
        let l = Lens::load(name)?;
        let p = l.paraxial(l.primary_wavelength_nm)?;
        emit_line(&format!("==================== {name} ===================="));
        emit(&paraxial_text(&l, &p).to_string());
        let opts = SpotOptions {
            fields: [0.0, 0.5, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: l.rgb_wavelengths_nm.to_vec(),
            pupil: Pupil::grid(64),
            trace: TraceOptions::default(),
        };
        let spots = spot_diagram(&l, &l.compile(), &opts)?;
        emit_line("\nSpots (64x64 grid over the entrance pupil, apertures on, RGB)");
        emit(&spot_table(&spots).to_string());
        let spot_png = out.join(format!("{name}-spots.png"));
        figures::save(
            &figures::spot_figure(&spots, &format!("Spot diagram: {name}")),
            &spot_png,
        )?;
        let layout_png = out.join(format!("{name}-layout.png"));
        let fields = [0.0, 0.7, 1.0].map(Field::fraction);
        figures::save(
            &figures::layout_figure(&l, &l.compile(), &p, &fields, l.primary_wavelength_nm, 7)?,
            &layout_png,
        )?;
        write_text(
            &out.join(format!("{name}-spots.json")),
            &(serde_json::to_string_pretty(&spots)? + "\n"),
        )?;
        // Tolerances: the paper's Table A1, 200 Monte Carlo trials with a refocus compensator.
        let mc = McOptions {
            spec: ToleranceSpec::default(),
            trials: 200,
            seed: 7,
            fields: [0.0, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: vec![l.primary_wavelength_nm],
            pupil: Pupil::grid(32),
            compensate_focus: true,
            apertures: true,
            criterion: Default::default(),
        };
        emit_line("");
        let report = with_progress(mc.trials as u64, "trials", |tick| {
            monte_carlo(&l, name, &mc, None, tick)
        })?;
        emit(&tolerance_text(&report));
        let hist_png = out.join(format!("{name}-tolerance.png"));
        figures::save(&figures::tolerance_figure(&report), &hist_png)?;
        write_text(
            &out.join(format!("{name}-tolerance.json")),
            &(serde_json::to_string_pretty(&report)? + "\n"),
        )?;
        let (_, rows) = sensitivity(&l, &mc)?;
        emit_line("most sensitive operands (worst change of RMS spot, µm):");
        for r in rows.iter().take(5) {
            let axis = if r.operand.axes() == 1 {
                String::new()
            } else {
                format!(" {}", ["x", "y", "z"][r.axis])
            };
            let target = if r.operand.per_element() {
                "element"
            } else {
                "surface"
            };
            emit_line(&format!(
                "  {:?}{axis} of {target} {} at +-{} {}: {:.3}",
                r.operand,
                r.target,
                r.max,
                r.operand.unit(),
                r.worst_delta_um
            ));
        }
        emit_line(&format!(
            "wrote {}, {}, {}\n",
            spot_png.display(),
            layout_png.display(),
            hist_png.display()
        ));
    }
    Ok(())
}
