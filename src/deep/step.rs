//! One training step, the design's refocus after it, and the held-out validation PSNR.

use super::*;

/// Runs one iteration of the current phase and returns its log. Crops, patterns, noise and
/// pupil samples derive from (seed, global iteration, crop index): the same state gives the
/// same numbers whatever the thread count.
///
/// # Errors
/// Ray-generation errors; a crop whose PSF receives no ray; a non-finite loss.
pub fn step(state: &mut DeepState) -> Result<DeepLog> {
    let it = state.iter_offset + state.phase_iter;
    let phase = state.phase;
    let batch = draw_batch(&state.config, &state.design.lens, phase, it)?;
    let vars = phase.trains_lens().then_some(state.vars.as_slice());
    let e = eval_batch(
        &state.config,
        &batch,
        &state.design.lens,
        &state.design.decoder,
        vars,
    )?;
    if !e.loss.is_finite() {
        return Err(Error::numerical(format!(
            "iteration {it}: the loss is not finite"
        )));
    }
    let scale = cosine_schedule(state.phase_iter as u64, state.phase_iters as u64, 0.05);
    if phase.trains_lens() {
        let mut lens = state.design.lens.clone();
        let mut x: Vec<f64> = state
            .vars
            .iter()
            .map(|&p| param_value(&lens, p))
            .collect::<Result<_>>()?;
        state.adam_lens.step(&mut x, &e.dlens, scale);
        for (&p, &v) in state.vars.iter().zip(&x) {
            set_param(&mut lens, p, v)?;
        }
        if state.config.compensate_focus && phase.samples_tolerances() {
            refocus_design(&mut lens, state.config.optics.apertures)?;
        }
        crate::optim::train::project(&mut lens, &state.config.optics.constraints);
        state.design.lens = lens;
    }
    if phase.trains_decoder() {
        let mut params = state.design.decoder.params().to_vec();
        state.adam_decoder.step(&mut params, &e.ddecoder, scale);
        state.design.decoder.set_params(&params)?;
    }
    state.phase_iter += 1;
    Ok(DeepLog {
        iter: it,
        phase,
        image_loss: e.image_loss,
        psnr_db: e.psnr_db,
        spot_um: e.spot_um,
        psf_similarity: e.psf_similarity,
        val_psnr_db: None,
    })
}

/// Moves the sensor of `lens` to its own best RMS focus ([`FocusObjective`] on the lens without
/// a pattern). Training on refocused units leaves the design's sensor position free (each
/// unit's refocus cancels a move of the sensor exactly, so the loss of a drawn batch is flat in
/// it), so after each step of such a phase the design is put back at its best focus: the
/// design a user receives is a focused lens, and the reference of the PSF-similarity term (the
/// design's nominal PSFs, drawn with each batch) is that of the focused design, as the refocused
/// units it is compared with. Without it the reference stayed at the stage-1 sensor and the
/// similarity of refocused units to it was 0.16 instead of 0.87 (lens1).
///
/// # Errors
/// Ray-generation errors; a refocus that is not finite.
pub fn refocus_design(lens: &mut Lens, apertures: bool) -> Result<()> {
    let f = FocusObjective::new(lens, apertures)?;
    let d = crate::optim::value(&f, lens, &Adjustments::none(lens.surfaces.len()));
    if !d.is_finite() {
        return Err(Error::numerical("the design's best focus is not finite"));
    }
    let last = lens.surfaces.len() - 1;
    lens.surfaces[last].d_next_mm += d;
    Ok(())
}

/// Seed offset of the validation batch: its crops, patterns and noise are never trained on.
pub(super) const VALIDATION_SEED: u64 = 0x7661_6c69_6461_7465;

/// PSNR (sRGB, dB) of the current design on a fixed validation batch: `samples` crops from the
/// training source, each through its own random fabricated unit (a pattern of the spec, refocused
/// when the config says so), drawn from a seed that training never uses. The same batch for
/// every branch and iteration of a run, so the curves compare.
///
/// # Errors
/// As [`eval_batch`].
pub fn validation_psnr(state: &DeepState) -> Result<f64> {
    let mut cfg = state.config.clone();
    cfg.optics.seed ^= VALIDATION_SEED;
    let batch = draw_batch(&cfg, &state.design.lens, Phase::Tolerance, 0)?;
    Ok(eval_batch(
        &cfg,
        &batch,
        &state.design.lens,
        &state.design.decoder,
        None,
    )?
    .psnr_db)
}
