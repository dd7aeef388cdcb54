//! `deep`: the cost of the image half on the CPU.
//! - spatially variant convolution of a 2048x2048 RGB image by an 8x8 map of 51x51 kernels;
//! - one joint training iteration on lens1 at the demo's batch (32 crops of 32²), through the
//!   rays' PSFs and through diffraction PSFs, and at the paper's (64 crops of 256²), tolerance
//!   phase, Wiener + U-Net decoder;
//! - a decoder training step alone (64 crops of 64², Wiener + U-Net width 8);
//! - the U-Net alone, forward and backward over 64 crops of 64² and of 256² (width 8, 3 levels,
//!   8 input channels), crop by crop on the thread pool as training runs it: the work
//!   `scripts/bench/unet_vs_pytorch.py` times in PyTorch in the same run;
//! - the evaluation of one fabricated unit (RGB PSF map of 8192 rays per PSF, 3 images of 384²).

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use rayon::prelude::*;
use tolray::decoder::unet::{Unet, UnetConfig};
use tolray::decoder::{Crop, DecoderKind, ImageLossWeights};
use tolray::deep::eval::{evaluate, EvalConfig, EvalImages};
use tolray::deep::{step, DeepConfig, DeepState, Phase};
use tolray::image::deadleaves::DeadLeaves;
use tolray::image::render::{render_map, PsfMap};
use tolray::psf::PsfModel;
use tolray::Lens;

fn focused_lens1() -> Lens {
    let mut l = Lens::load("lens1").unwrap();
    let p = l.paraxial(l.primary_wavelength_nm).unwrap();
    let last = l.surfaces.len() - 1;
    l.surfaces[last].d_next_mm = p.image_distance_mm.unwrap();
    l
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("deep");
    g.sample_size(10);
    let img = DeadLeaves::default().generate(2048, 2048, 1, 1).unwrap();
    let ks = 51;
    let mut psf = vec![0f32; 3 * ks * ks];
    for ch in 0..3 {
        for k in 0..ks * ks {
            let (j, i) = ((k / ks) as f32 - 25.0, (k % ks) as f32 - 25.0);
            psf[ch * ks * ks + k] = (-(i * i + j * j) / 50.0).exp();
        }
    }
    let map = PsfMap::new(8, ks, psf.repeat(64)).unwrap();
    g.bench_function("render_map/2048x2048/8x8x51", |b| {
        b.iter(|| render_map(&img, &map).unwrap())
    });

    let lens = focused_lens1();
    for (name, samples, crop, model) in [
        ("demo-32x32px", 32, 32, PsfModel::Geometric),
        ("demo-32x32px-diffraction", 32, 32, PsfModel::Diffraction),
        ("paper-64x256px", 64, 256, PsfModel::Geometric),
    ] {
        let mut cfg = DeepConfig::for_lens(&lens);
        cfg.optics.samples = samples;
        cfg.crop_px = crop;
        cfg.psf = model;
        let st = DeepState::new(cfg.clone(), lens.clone(), None, Phase::Tolerance, 1, 0).unwrap();
        // A whole iteration: drawing the crops, patterns and rays, rendering, decoding, both
        // backward passes and the Adam steps.
        g.bench_function(format!("stage2_iteration/lens1/{name}"), |b| {
            b.iter_batched(
                || st.clone(),
                |mut s| step(&mut s).unwrap(),
                BatchSize::LargeInput,
            )
        });
    }

    let cfg = DeepConfig::for_lens(&lens);
    let st = DeepState::new(cfg, lens.clone(), None, Phase::Nominal, 1, 0).unwrap();
    assert_eq!(st.design.decoder.kind, DecoderKind::WienerUnet);
    let crops: Vec<Crop> = (0..64)
        .map(|j| {
            let x = DeadLeaves::default().generate(64, 64, 2, j).unwrap().data;
            Crop {
                tile: j as usize,
                y: x.clone(),
                x,
                w: 64,
                h: 64,
            }
        })
        .collect();
    g.bench_function("decoder_step/64x64px/wiener+unet8", |b| {
        b.iter(|| {
            st.design
                .decoder
                .train_batch(&crops, &ImageLossWeights::default())
                .unwrap()
        })
    });

    // The U-Net alone: L = Σ out · g per crop; parameter gradients summed in crop order.
    let cfg = UnetConfig {
        in_channels: 8,
        width: 8,
        levels: 3,
    };
    let mut u = Unet::new(cfg, 1).unwrap();
    // A nonzero output layer and biases, so that gradients reach every layer.
    for (i, v) in u.params.iter_mut().enumerate() {
        if *v == 0.0 {
            *v = 0.01 * ((i % 7) as f32 - 3.0);
        }
    }
    for side in [64, 256] {
        let k = cfg.in_channels * side * side;
        let x: Vec<Vec<f32>> = (0..64)
            .map(|j| {
                let img = DeadLeaves::default()
                    .generate(side, side, 3, j)
                    .unwrap()
                    .data;
                img.iter()
                    .chain(&img)
                    .chain(&img[..2 * side * side])
                    .copied()
                    .collect()
            })
            .collect();
        assert!(x.iter().all(|v| v.len() == k));
        let grad: Vec<f32> = (0..3 * side * side)
            .map(|i| ((i % 13) as f32 - 6.0) / 64.0)
            .collect();
        g.bench_function(format!("unet_step/64x{side}px/width8"), |b| {
            b.iter(|| {
                let per: Vec<(Vec<f32>, Vec<f32>)> = x
                    .par_iter()
                    .map(|xj| {
                        let (_, cache) = u.forward(xj, 1, side, side).unwrap();
                        let mut dp = vec![0f32; u.params.len()];
                        let mut dx = vec![0f32; k];
                        u.backward(&cache, &grad, &mut dp, &mut dx);
                        (dp, dx)
                    })
                    .collect();
                let mut dp = vec![0f32; u.params.len()];
                for (d, _) in &per {
                    dp.iter_mut().zip(d).for_each(|(a, b)| *a += b);
                }
                dp
            })
        });
    }

    let ec = EvalConfig::default();
    let images = EvalImages::builtin(8 * ec.patch_px, 2, ec.seed).unwrap();
    g.bench_function("evaluate_one_unit/lens1/3x384px", |b| {
        b.iter(|| evaluate("d", &st.design, &images, &ec, 0..1).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
