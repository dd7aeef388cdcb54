//! `wave`: the wave-optics analyses on the Cooke triplet at the d line, 0.7 field, all threads: the
//! wavefront with its Zernike fits (16 x 48 quadrature, 37 terms), the FFT PSF (128² pupil in a
//! 256² array), the Huygens PSF (64² pupil x 64² image points) and the diffraction MTF of one
//! field (64² pupil, 256² array, three frequencies). `scripts/bench/wave_vs_optiland.py` times
//! optiland 0.6.3 on the same work.

use criterion::{criterion_group, criterion_main, Criterion};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::trace::Field;
use tolray::wave::mtf::fft_mtf;
use tolray::wave::psf::{fft_psf, huygens_psf, FftOptions, HuygensOptions};
use tolray::wave::{wavefront, Sampling, WaveOptions};
use tolray::Lens;

fn bench(c: &mut Criterion) {
    let lens = Lens::load("cooke-triplet").unwrap();
    let sys = lens.compile();
    let field = Field::fraction(0.7);
    let mut g = c.benchmark_group("wave/cooke-triplet");
    g.sample_size(10);
    g.bench_function("wavefront+zernike", |b| {
        b.iter(|| {
            let w = wavefront(&lens, &sys, field, LAMBDA_D_NM, &WaveOptions::default()).unwrap();
            w.stats(37).unwrap()
        })
    });
    let grid = |n: usize| WaveOptions {
        sampling: Sampling::Grid(n),
        ..WaveOptions::default()
    };
    g.bench_function("fft_psf/128", |b| {
        b.iter(|| {
            let w = wavefront(&lens, &sys, field, LAMBDA_D_NM, &grid(128)).unwrap();
            fft_psf(
                &w,
                &FftOptions {
                    pupil_samples: 128,
                    grid: 256,
                },
            )
            .unwrap()
        })
    });
    g.bench_function("huygens_psf/64x64", |b| {
        b.iter(|| {
            let w = wavefront(&lens, &sys, field, LAMBDA_D_NM, &grid(64)).unwrap();
            huygens_psf(
                &w,
                &HuygensOptions {
                    image_samples: 64,
                    pitch_um: 0.5,
                },
            )
            .unwrap()
        })
    });
    g.bench_function("mtf/fft", |b| {
        b.iter(|| {
            let w = wavefront(&lens, &sys, field, LAMBDA_D_NM, &grid(64)).unwrap();
            fft_mtf(&w, &FftOptions::default(), &[10.0, 20.0, 40.0]).unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
