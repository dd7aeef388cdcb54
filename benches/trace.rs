//! `trace`: ray-surfaces per second for lens2 at the d line, 1,000,000 rays, value-only f32 and
//! f64, one thread and all threads. Throughput is reported in elements = ray-surfaces
//! (rays x (surfaces + image plane)).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::System;
use tolray::trace::{trace, Field, Pupil, PupilPattern, RayBatch, RaySet, TraceOptions, Traceable};
use tolray::Lens;

const RAYS: usize = 1_000_000;

fn rays(lens: &Lens) -> RaySet {
    let para = lens.paraxial(LAMBDA_D_NM).unwrap();
    let pupil = Pupil {
        pattern: PupilPattern::Random { n: RAYS, seed: 1 },
        scale: 1.0,
        aim: false,
    };
    RaySet::generate(lens, &para, Field::fraction(0.7), &pupil, LAMBDA_D_NM).unwrap()
}

fn bench_type<S: Traceable>(c: &mut Criterion, lens: &Lens, set: &RaySet) {
    let sys: System<S> = lens.compile().convert();
    let fresh: RayBatch<S> = set.batch();
    let surfaces = (lens.surfaces.len() + 1) as u64;
    let mut g = c.benchmark_group(format!("trace/lens2/{}", S::NAME));
    g.throughput(Throughput::Elements(RAYS as u64 * surfaces));
    g.sample_size(10);
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    for threads in [1, all] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        g.bench_with_input(BenchmarkId::new("threads", threads), &threads, |b, _| {
            let mut batch = fresh.clone();
            b.iter(|| {
                batch.clone_from(&fresh);
                pool.install(|| trace(&sys, LAMBDA_D_NM, &mut batch, TraceOptions::default()));
            });
        });
    }
    g.finish();
}

fn bench(c: &mut Criterion) {
    let lens = Lens::load("lens2").unwrap();
    let set = rays(&lens);
    bench_type::<f32>(c, &lens, &set);
    bench_type::<f64>(c, &lens, &set);
}

criterion_group!(benches, bench);
criterion_main!(benches);
