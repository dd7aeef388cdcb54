//! `trace`: ray-surfaces per second for lens2 at the d line, 1,000,000 rays, value-only f32 and
//! f64, one thread and all threads, with the instruction-set build chosen at run time and with
//! each other build the CPU runs; and, per surface kind that needs Newton's method on its sag
//! (`trace/kinds/...`, all threads), Thorlabs' ASL5040-UV (a Qbfs asphere), the hand-made Qcon
//! singlet of the tests, Thorlabs' LJ1598L1 cylinder lens (a toroid) and the tests' Zernike sag
//! singlet (a 17-term Fringe front, a 12-term Standard back), and the tests' gradient-index
//! doublet (Gradient 3 and Gradient 1 media, ray paths integrated), each at its primary
//! wavelength; and the spot analysis end to end (`spot/lens2`: ray generation, the f64 trace and
//! the statistics of a 1024 x 1024 pupil grid at 0.7 field, one thread and all threads), the
//! work `tolray spot` does; a PSF of 1,000,000 random pupil rays end to end (`psf/lens2`, the
//! work of `tolray psf`); and a raw trace of the kernel benchmark's rays from CSV text to CSV text
//! (`raw/lens2`, the work of `tolray trace`). Throughput is reported in elements = ray-surfaces
//! (rays x (surfaces + image plane)).

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};
use tolray::analysis::{spot_diagram_rows, SpotOptions};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{zemax, GlassCatalogs, System};
use tolray::psf::{psf_streamed, PsfOptions};
use tolray::trace::raw::{trace_csv_to, HitFormat};
use tolray::trace::simd::{self, Isa};
use tolray::trace::{trace, Field, Pupil, PupilPattern, RayBatch, RaySet, TraceOptions, Traceable};
use tolray::Lens;

const RAYS: usize = 1_000_000;

fn rays(lens: &Lens, wl: f64) -> RaySet {
    let para = lens.paraxial(wl).unwrap();
    let pupil = Pupil {
        pattern: PupilPattern::Random { n: RAYS, seed: 1 },
        scale: 1.0,
        aim: false,
    };
    RaySet::generate(lens, &para, Field::fraction(0.7), &pupil, wl).unwrap()
}

/// Thread pools of one thread and of every core, with their sizes.
fn pools() -> Vec<(usize, rayon::ThreadPool)> {
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    [1, all]
        .into_iter()
        .map(|n| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build();
            (n, pool.unwrap())
        })
        .collect()
}

/// The kernel with the build chosen at run time (`trace/lens2/f32/threads/N`) and with each other
/// instruction-set build this CPU runs (`trace/lens2/f32/avx2/threads/N`, ...).
fn bench_type<S: Traceable>(c: &mut Criterion, lens: &Lens, set: &RaySet) {
    let sys: System<S> = lens.compile().convert();
    let fresh: RayBatch<S> = set.batch();
    let surfaces = (lens.surfaces.len() + 1) as u64;
    let detected = Isa::detected();
    for isa in Isa::available() {
        simd::set_active(isa).unwrap();
        let name = match isa == detected {
            true => format!("trace/lens2/{}", S::NAME),
            false => format!("trace/lens2/{}/{}", S::NAME, isa.name()),
        };
        let mut g = c.benchmark_group(name);
        g.throughput(Throughput::Elements(RAYS as u64 * surfaces));
        g.sample_size(10);
        for (threads, pool) in pools() {
            // The fresh copy of the rays is made outside the timing (a serial 64 MB copy in f64).
            g.bench_with_input(BenchmarkId::new("threads", threads), &threads, |b, _| {
                b.iter_batched_ref(
                    || fresh.clone(),
                    |batch| {
                        pool.install(|| trace(&sys, LAMBDA_D_NM, batch, TraceOptions::default()))
                    },
                    BatchSize::LargeInput,
                );
            });
        }
        g.finish();
    }
    simd::set_active(detected).unwrap();
}

/// The kernel on surface kinds traced by Newton's method (Q-type aspheres, toroids, Zernike sag
/// surfaces) and through gradient-index media, all threads.
fn bench_kinds(c: &mut Criterion) {
    let mut g = c.benchmark_group("trace/kinds");
    g.sample_size(10);
    for (name, file) in [
        ("qbfs-asl5040", "real/rayoptics/ASL5040-UV-Zemax(ZMX).zmx"),
        ("qcon-singlet", "qcon.zmx"),
        ("toroid-lj1598l1", "real/optiland/thorlabs_lj1598l1.zmx"),
        ("zernike-singlet", "zernike.zmx"),
        // Two gradient-index media, integrated in steps of 0.05 mm (about 140 a ray).
        ("grin-doublet", "grin.zmx"),
    ] {
        let path = format!("{}/tests/data/zemax/{file}", env!("CARGO_MANIFEST_DIR"));
        let lens = zemax::read_file(std::path::Path::new(&path), &GlassCatalogs::builtin())
            .unwrap()
            .lens;
        let wl = lens.primary_wavelength_nm;
        let set = rays(&lens, wl);
        g.throughput(Throughput::Elements(
            RAYS as u64 * (lens.surfaces.len() as u64 + 1),
        ));
        let sys64: System<f64> = lens.compile();
        let sys32: System<f32> = sys64.convert();
        let (fresh64, fresh32) = (set.batch::<f64>(), set.batch::<f32>());
        g.bench_function(format!("{name}/f32"), |b| {
            let run = |batch: &mut RayBatch<f32>| trace(&sys32, wl, batch, TraceOptions::default());
            b.iter_batched_ref(|| fresh32.clone(), run, BatchSize::LargeInput);
        });
        g.bench_function(format!("{name}/f64"), |b| {
            let run = |batch: &mut RayBatch<f64>| trace(&sys64, wl, batch, TraceOptions::default());
            b.iter_batched_ref(|| fresh64.clone(), run, BatchSize::LargeInput);
        });
    }
    g.finish();
}

/// The spot analysis end to end: rays generated, traced and reduced a chunk at a time.
fn bench_spot(c: &mut Criterion, lens: &Lens) {
    let opts = SpotOptions {
        fields: vec![Field::fraction(0.7)],
        wavelengths_nm: vec![LAMBDA_D_NM],
        pupil: Pupil::grid(1024),
        trace: TraceOptions::default(),
    };
    let sys = lens.compile();
    let (rows, _) = spot_diagram_rows(lens, &sys, &opts).unwrap();
    let launched = rows[0].stats.n_launched as u64;
    let mut g = c.benchmark_group("spot/lens2/grid1024");
    g.throughput(Throughput::Elements(
        launched * (lens.surfaces.len() as u64 + 1),
    ));
    g.sample_size(10);
    for (threads, pool) in pools() {
        g.bench_with_input(BenchmarkId::new("threads", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| spot_diagram_rows(lens, &sys, &opts).unwrap()));
        });
    }
    g.finish();
}

/// A PSF end to end (`tolray psf`): 1,000,000 random pupil rays at 0.7 field generated, traced
/// in f64 and splatted a chunk at a time.
fn bench_psf(c: &mut Criterion, lens: &Lens) {
    let mut opts = PsfOptions::for_lens(lens);
    opts.pupil.pattern = PupilPattern::Random { n: RAYS, seed: 1 };
    let sys = lens.compile();
    let field = Field::fraction(0.7);
    let mut g = c.benchmark_group("psf/lens2/random1M");
    g.throughput(Throughput::Elements(
        RAYS as u64 * (lens.surfaces.len() as u64 + 1),
    ));
    g.sample_size(10);
    for (threads, pool) in pools() {
        g.bench_with_input(BenchmarkId::new("threads", threads), &threads, |b, _| {
            b.iter(|| {
                pool.install(|| psf_streamed(lens, &sys, field, LAMBDA_D_NM, &opts).unwrap())
            });
        });
    }
    g.finish();
}

/// A raw trace end to end (`tolray trace`): the CSV text of the kernel benchmark's 1,000,000
/// rays parsed, traced in f64 and written as CSV (to a sink) a chunk at a time.
fn bench_raw(c: &mut Criterion, lens: &Lens, set: &RaySet) {
    use std::fmt::Write;
    let mut csv = String::from("ox,oy,oz,dx,dy,dz,wavelength_nm\n");
    for (o, d) in set.origins.iter().zip(&set.directions) {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{LAMBDA_D_NM}",
            o.x, o.y, o.z, d.x, d.y, d.z
        );
    }
    let sys = lens.compile();
    let mut g = c.benchmark_group("raw/lens2/csv1M");
    g.throughput(Throughput::Elements(
        set.origins.len() as u64 * (lens.surfaces.len() as u64 + 1),
    ));
    g.sample_size(10);
    for (threads, pool) in pools() {
        g.bench_with_input(BenchmarkId::new("threads", threads), &threads, |b, _| {
            b.iter(|| {
                pool.install(|| {
                    let (input, out) = (csv.as_bytes(), std::io::sink());
                    trace_csv_to(&sys, input, out, HitFormat::Csv, TraceOptions::default()).unwrap()
                })
            });
        });
    }
    g.finish();
}

fn bench(c: &mut Criterion) {
    let lens = Lens::load("lens2").unwrap();
    let set = rays(&lens, LAMBDA_D_NM);
    bench_type::<f32>(c, &lens, &set);
    bench_type::<f64>(c, &lens, &set);
    bench_kinds(c);
    bench_spot(c, &lens);
    bench_psf(c, &lens);
    bench_raw(c, &lens, &set);
}

criterion_group!(benches, bench);
criterion_main!(benches);
