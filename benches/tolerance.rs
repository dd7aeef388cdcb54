//! `tolerance`: Monte Carlo trials per second on lens2 (3 fields, 32x32 pupil grid, d line,
//! the paper's Table A1 tolerances), with and without the focus compensator, all threads.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::tolerance::{monte_carlo, McOptions, ToleranceSpec};
use tolray::trace::{Field, Pupil};
use tolray::Lens;

fn bench(c: &mut Criterion) {
    let lens = Lens::load("lens2").unwrap();
    let trials = 200;
    let mut g = c.benchmark_group("tolerance/lens2");
    g.throughput(Throughput::Elements(trials as u64));
    g.sample_size(10);
    for compensate in [false, true] {
        let opts = McOptions {
            spec: ToleranceSpec::default(),
            trials,
            seed: 7,
            fields: [0.0, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: vec![LAMBDA_D_NM],
            pupil: Pupil::grid(32),
            compensate_focus: compensate,
            apertures: true,
        };
        let name = if compensate {
            "trials/refocus"
        } else {
            "trials"
        };
        g.bench_function(name, |b| {
            b.iter(|| monte_carlo(&lens, "lens2", &opts, None, &|| {}).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
