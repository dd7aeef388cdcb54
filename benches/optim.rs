//! `optim`: the cost of gradients and of the optimization's building blocks on lens2.
//! - trace of 4096 rays in f64 vs `Dual<f64, 8>` vs `Dual<f64, 16>` (gradient cost relative to
//!   the value trace, per pass);
//! - one stage-2 iteration (64 patterns, 51x51 PSFs, RGB, 21 design variables);
//! - a PSF map of 8x8 fields, 51x51 kernels, 8192 rays per field, no gradients.

use criterion::{criterion_group, criterion_main, Criterion};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{Adjustments, System};
use tolray::optim::train::{step, TrainConfig, TrainState};
use tolray::psf::{psf_map, PsfOptions};
use tolray::real::Dual;
use tolray::trace::simd::{self, Isa};
use tolray::trace::{trace, Field, Pupil, RayBatch, RaySet, TraceOptions, Traceable};
use tolray::Lens;

fn trace_cost<S: Traceable>(c: &mut Criterion, lens: &Lens, set: &RaySet, name: &str) {
    let lift = |_, v: S| v;
    let sys: System<S> = System::compile(lens, &Adjustments::none(lens.surfaces.len()), &lift);
    let fresh: RayBatch<S> = set.batch();
    c.bench_function(&format!("optim/lens2/trace4096/{name}"), |b| {
        let mut batch = fresh.clone();
        b.iter(|| {
            batch.clone_from(&fresh);
            trace(&sys, LAMBDA_D_NM, &mut batch, TraceOptions::default());
        })
    });
}

fn bench(c: &mut Criterion) {
    let lens = Lens::load("lens2").unwrap();
    let para = lens.paraxial(LAMBDA_D_NM).unwrap();
    let set = RaySet::generate(
        &lens,
        &para,
        Field::fraction(0.7),
        &Pupil {
            pattern: tolray::trace::PupilPattern::Random { n: 4096, seed: 1 },
            scale: 1.0,
            aim: false,
        },
        LAMBDA_D_NM,
    )
    .unwrap();
    trace_cost::<f64>(c, &lens, &set, "f64");
    trace_cost::<Dual<f64, 8>>(c, &lens, &set, "dual8");
    trace_cost::<Dual<f64, 16>>(c, &lens, &set, "dual16");
    // The builds of the widths the library differentiates with, per instruction set.
    let detected = Isa::detected();
    for isa in Isa::available().into_iter().filter(|&i| i != detected) {
        simd::set_active(isa).unwrap();
        trace_cost::<f64>(c, &lens, &set, &format!("f64/{}", isa.name()));
        trace_cost::<Dual<f64, 8>>(c, &lens, &set, &format!("dual8/{}", isa.name()));
    }
    simd::set_active(detected).unwrap();

    let mut cfg = TrainConfig::for_lens(&lens);
    cfg.pretrain_iters = 0;
    cfg.tolerance_iters = 1;
    let state = TrainState::new(&lens, cfg);
    let mut g = c.benchmark_group("optim/lens2");
    g.sample_size(10);
    g.bench_function("stage2_iteration_64_patterns", |b| {
        b.iter(|| {
            let mut s = state.clone();
            step(&mut s).unwrap()
        })
    });
    let opts = PsfOptions::for_lens(&lens);
    let sys = lens.compile();
    g.bench_function("psf_map_8x8_51px_8192rays", |b| {
        b.iter(|| psf_map(&lens, &sys, 8, LAMBDA_D_NM, &opts).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
