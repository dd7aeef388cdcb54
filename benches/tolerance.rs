//! `tolerance`: Monte Carlo trials per second on lens2 (3 fields, 32x32 pupil grid, d line,
//! the paper's Table A1 tolerances), with and without the focus compensator, all threads; and
//! with the wave criteria (RMS wavefront, Strehl, MTF at 30 cycles/mm) refocused.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::tolerance::{self, monte_carlo, McOptions, MtfDirection, ToleranceSpec};
use tolray::trace::{Field, Pupil};
use tolray::Lens;

fn bench(c: &mut Criterion) {
    let lens = Lens::load("lens2").unwrap();
    let trials = 200;
    let mut g = c.benchmark_group("tolerance/lens2");
    g.sample_size(10);
    let wave = [
        (
            "trials/rms-wavefront/refocus",
            tolerance::Criterion::RmsWavefront,
        ),
        ("trials/strehl/refocus", tolerance::Criterion::Strehl),
        (
            "trials/mtf30/refocus",
            tolerance::Criterion::Mtf {
                freq_lpmm: 30.0,
                direction: MtfDirection::Mean,
            },
        ),
    ];
    let runs = [
        ("trials", false, tolerance::Criterion::RmsSpot),
        ("trials/refocus", true, tolerance::Criterion::RmsSpot),
    ]
    .into_iter()
    .chain(wave.map(|(n, c)| (n, true, c)));
    for (name, compensate, criterion) in runs {
        let trials = if criterion == tolerance::Criterion::RmsSpot {
            trials
        } else {
            20
        };
        g.throughput(Throughput::Elements(trials as u64));
        let opts = McOptions {
            spec: ToleranceSpec::default(),
            trials,
            seed: 7,
            fields: [0.0, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: vec![LAMBDA_D_NM],
            pupil: Pupil::grid(32),
            compensate_focus: compensate,
            apertures: true,
            criterion,
        };
        g.bench_function(name, |b| {
            b.iter(|| monte_carlo(&lens, "lens2", &opts, None, &|| {}).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
