//! The Rust library in one program: load a lens, first-order data, a spot diagram, the
//! wavefront and MTF, and a Monte Carlo tolerance analysis with a focus compensator.
//!
//! ```sh
//! cargo run --release --example library            # the Cooke triplet, built in
//! cargo run --release --example library -- my.zmx  # any lens file
//! ```
use tolray::analysis::{spot_diagram, SpotOptions};
use tolray::tolerance::{monte_carlo, McOptions, ToleranceSpec};
use tolray::trace::{Field, Pupil, TraceOptions};
use tolray::wave::{mtf::fft_mtf, psf::FftOptions, wavefront, Sampling, WaveOptions};
use tolray::Lens;

fn main() -> tolray::Result<()> {
    // A well-corrected lens by default: the paper's lens2 is prescribed 1.6 mm out of focus (20
    // waves of defocus), which an FFT over a 64² pupil grid refuses as undersampled.
    let name = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "cooke-triplet".into());
    let lens = Lens::load(&name)?; // a built-in name, DeepLens JSON or .zmx
    let wl = lens.primary_wavelength_nm;

    // First-order data (an afocal lens has no EFL: the focal quantities are options).
    let p = lens.paraxial(wl)?;
    if let (Some(efl), Some(fno)) = (p.efl_mm, p.fnum) {
        println!("{name}: EFL {efl:.4} mm, F/{fno:.3} at {wl:.1} nm");
    }

    // Spot diagram: RMS radius about the centroid per field, µm.
    let fields = [0.0, 0.7, 1.0].map(Field::fraction).to_vec();
    let sys = lens.compile(); // the flat f64 table the tracer runs on
    let spots = spot_diagram(
        &lens,
        &sys,
        &SpotOptions {
            fields: fields.clone(),
            wavelengths_nm: vec![wl],
            pupil: Pupil::grid(64),
            trace: TraceOptions::default(),
        },
    )?;
    for (f, s) in [0.0, 0.7, 1.0].iter().zip(&spots) {
        println!("  field {f:.1}: RMS spot {:8.3} µm", s.stats.rms_um);
    }

    // Wave optics on axis: RMS wavefront error to the chief ray's reference sphere and the
    // diffraction MTF at 10, 20 and 40 cycles/mm.
    let w = wavefront(&lens, &sys, fields[0], wl, &WaveOptions::default())?;
    let stats = w.stats(37)?;
    // The FFT MTF transforms the pupil on its own grid: trace the wavefront there.
    let fft = FftOptions::default();
    let on_grid = WaveOptions {
        sampling: Sampling::Grid(fft.pupil_samples),
        ..WaveOptions::default()
    };
    let mtf = fft_mtf(
        &wavefront(&lens, &sys, fields[0], wl, &on_grid)?,
        &fft,
        &[10.0, 20.0, 40.0],
    )?;
    println!(
        "  on axis: RMS wavefront {:.4} waves, Strehl (Maréchal) {:.3}, MTF T {:.3?}",
        stats.rms_to_chief_waves, stats.strehl_marechal, mtf.tangential
    );

    // Monte Carlo: the paper's Table A1 tolerances, 200 fabricated units, each refocused.
    let mc = McOptions {
        spec: ToleranceSpec::default(),
        trials: 200,
        seed: 7,
        fields,
        wavelengths_nm: vec![wl],
        pupil: Pupil::grid(32),
        compensate_focus: true,
        apertures: true,
        criterion: Default::default(),
    };
    let report = monte_carlo(&lens, &name, &mc, None, &|| {})?;
    let s = report.summary.expect("a whole study has a summary");
    let y90 = s.mean_over_fields.yield_below.iter().find(|y| y[0] == 0.9);
    println!(
        "  Monte Carlo, 200 units: mean RMS spot {:.3} ± {:.3} µm; 90 % of units below {:.3} µm",
        s.mean_over_fields.mean,
        s.mean_over_fields.std,
        y90.map_or(f64::NAN, |y| y[1])
    );
    Ok(())
}
