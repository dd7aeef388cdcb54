//! The paper's claim, reproduced on lens1 at its stated object distance (1000 mm): stage 1
//! removes the defocus of the prescribed image plane and shrinks the RMS spot; stage 2 then
//! trades some nominal sharpness for a smaller Monte Carlo spread of the RMS spot and a higher
//! mean PSF similarity, measured on 400 held-out tolerance patterns (another seed).
//!
//! Stage 2 fine-tunes the stage-1 design at a tenth of its learning rates. At the full rates,
//! Adam's first steps threw lens1 out of focus (a ~150 um spot) before stage 2 recovered, and the
//! end point was chaotic: a change of the learning rate by one part in 10^12 moved the final
//! nominal RMS spot from 7.4 to 9.1 um. At a tenth it moves it from 7.0 to 7.4 um, and training
//! seeds 0 and 1 and that change gave a refocused spread 3.9 to 4.2 % lower, a PSF similarity
//! 0.077 to 0.089 higher and a nominal spot 2.1 to 2.6 um larger (400 held-out patterns). The
//! claims are checked for two training seeds, with thresholds about half of these, on 400
//! held-out patterns (with 100, the standard deviations of one design vary by about 10 % from
//! one held-out seed to another), and only where the effect is systematic:
//! - the spread is measured with each lens refocused to its best focus, as a lens is focused
//!   at assembly. Without refocusing, the spread of lens1 is dominated by the focus error of
//!   the 0.3 % curvature tolerances, which the paper's losses do not reduce (stage 2 raises it
//!   slightly); the report prints both.
//! - the 90 % yield of the RMS spot gets worse, as in the paper (its tolerance-aware lens1 has
//!   a larger spot, 16.2 against 7.3 um): it is not asserted.
//!
//! Deterministic (seeded, thread-count independent), so the numbers are the same on every run.

use tolray::optim::train::{held_out, step, HeldOut, TrainConfig, TrainState};
use tolray::Lens;

/// Trains lens1 with `seed` (300 + 100 iterations) and evaluates the prescription, the stage-1
/// and the final design on 400 held-out patterns.
fn train_and_evaluate(seed: u64) -> [HeldOut; 3] {
    let lens = Lens::load("lens1").unwrap();
    let mut cfg = TrainConfig::for_lens(&lens);
    cfg.pretrain_iters = 300;
    cfg.tolerance_iters = 100;
    cfg.seed = seed;
    let mut state = TrainState::new(&lens, cfg.clone());
    while state.next_iter < state.total_iters() {
        step(&mut state).unwrap();
    }
    let stage1 = state.stage1_lens.clone().unwrap();
    let fin = state.lens.clone();
    let held = 1_000_003;
    [&lens, &stage1, &fin].map(|l| held_out(l, &cfg, 400, held).unwrap())
}

fn check(seed: u64) {
    let [h0, h1, h2] = train_and_evaluate(seed);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let show = |h: &HeldOut| {
        format!(
            "nominal {:.3} um; MC mean {:.3} std {:.3}; refocused mean {:.3} std {:.3}; sim {:.4}",
            mean(&h.nominal_rms_um),
            h.rms_mean_um,
            h.rms_std_um,
            h.refocused_rms_mean_um,
            h.refocused_rms_std_um,
            h.psf_similarity_mean
        )
    };
    let what = format!(
        "seed {seed}\n  stage 1: {}\n  stage 2: {}",
        show(&h1),
        show(&h2)
    );
    // Stage 1: the ~200 um defocus blur is gone.
    assert!(
        mean(&h0.nominal_rms_um) > 150.0 && mean(&h1.nominal_rms_um) < 10.0,
        "{:?} -> {:?}",
        h0.nominal_rms_um,
        h1.nominal_rms_um
    );
    // Stage 2: nominally softer, but more stable under tolerances.
    assert!(
        mean(&h2.nominal_rms_um) > mean(&h1.nominal_rms_um) + 1.0,
        "{what}"
    );
    assert!(
        h2.refocused_rms_std_um < 0.98 * h1.refocused_rms_std_um,
        "the refocused spread falls by 2 % or more: {what}"
    );
    assert!(
        h2.psf_similarity_mean > h1.psf_similarity_mean + 0.04,
        "the PSF similarity rises by 0.04 or more: {what}"
    );
}

#[test]
#[ignore = "the paper's optics claim (about 40 s of two cores); .ci/run executes it"]
fn stage_two_stabilizes_the_stage_one_design_seed_0() {
    check(0);
}

#[test]
#[ignore = "the paper's optics claim (about 40 s of two cores); .ci/run executes it"]
fn stage_two_stabilizes_the_stage_one_design_seed_1() {
    check(1);
}
