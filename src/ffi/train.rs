//! The two-stage optics training through the C ABI: the library's runner
//! ([`crate::optim::train::run_to_report`]) with checkpoints, an exact resume, a stop request
//! from the caller's progress callback and the final report, as `tolray train` runs it.

use super::handles::tolray_lens;
use super::{boundary, c_str, nonnull, tolray_status, FfiError, FfiResult};
use crate::optim::train::{
    run_to_report, Checkpoints, RunControl, RunEnd, TrainConfig, TrainState,
};
use std::ffi::{c_char, c_void};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

/// Called after every finished training iteration with the caller's `user` pointer, the
/// iteration (global over both stages, from 0), the number of iterations of the run, the
/// iteration's loss and its spot size (µm: RMS in stage 1, mean distance in stage 2). A nonzero
/// return asks the run to stop after this iteration, with a checkpoint to resume from (a Ctrl-C
/// handler sets a flag that the callback returns). Called on the thread that called
/// [`tolray_train`]; it must not unwind.
pub type tolray_train_progress = Option<
    unsafe extern "C" fn(
        user: *mut c_void,
        iter: usize,
        total: usize,
        loss: f64,
        spot_um: f64,
    ) -> i32,
>;

/// The training settings for `lens`: its defaults ([`TrainConfig::for_lens`]) with the keys of
/// the JSON object `text` put over them (NULL: none). Unknown keys are refused.
fn config(lens: &crate::Lens, text: Option<&str>) -> FfiResult<TrainConfig> {
    let mut cfg = serde_json::to_value(TrainConfig::for_lens(lens))
        .map_err(|e| FfiError::argument(format!("settings: {e}")))?;
    if let Some(text) = text {
        let over: serde_json::Value = serde_json::from_str(text).map_err(|e| {
            FfiError::new(
                tolray_status::TOLRAY_ERROR_PARSE,
                format!("config_json: {e}"),
            )
        })?;
        let serde_json::Value::Object(over) = over else {
            return Err(FfiError::new(
                tolray_status::TOLRAY_ERROR_PARSE,
                "config_json: not a JSON object",
            ));
        };
        let defaults = cfg.clone();
        let base = cfg
            .as_object_mut()
            .ok_or_else(|| FfiError::argument("settings"))?;
        for (k, v) in over {
            if !base.contains_key(&k) {
                let keys: Vec<&str> = base.keys().map(String::as_str).collect();
                return Err(FfiError::argument(format!(
                    "config_json: unknown key \"{k}\" (the keys: {})",
                    keys.join(", ")
                )));
            }
            // Each value alone over the defaults, so that an error names its key.
            let mut one = defaults.clone();
            one[&k] = v.clone();
            if let Err(e) = serde_json::from_value::<TrainConfig>(one) {
                return Err(FfiError::new(
                    tolray_status::TOLRAY_ERROR_INVALID_INPUT,
                    format!("config_json: \"{k}\": {e}"),
                ));
            }
            base.insert(k, v);
        }
    }
    let cfg: TrainConfig = serde_json::from_value(cfg).map_err(|e| {
        FfiError::new(
            tolray_status::TOLRAY_ERROR_INVALID_INPUT,
            format!("config_json: {e}"),
        )
    })?;
    cfg.validate()?;
    Ok(cfg)
}

/// Runs `state` to its end or a stop request, then writes the report; `*stopped` says which.
///
/// # Safety
/// As [`tolray_train`] says of `progress`, `user` and `stopped`.
#[allow(clippy::too_many_arguments)]
unsafe fn drive(
    mut state: TrainState,
    out: &Path,
    checkpoint_every: u32,
    eval_trials: u32,
    progress: tolray_train_progress,
    user: *mut c_void,
    stopped: *mut u32,
) -> FfiResult<()> {
    if stopped.is_null() {
        return Err(FfiError::null("stopped"));
    }
    if eval_trials == 0 || eval_trials > 100_000 {
        return Err(FfiError::argument(format!(
            "eval_trials {eval_trials}: give 1 to 100000"
        )));
    }
    let stop = AtomicBool::new(false);
    let total = state.total_iters();
    // `checkpoint_every` 0 counts as 1 (tolray.h).
    let opts = RunControl {
        checkpoints: Checkpoints::every(checkpoint_every.max(1) as usize),
        stop: &|| stop.load(Ordering::SeqCst),
    };
    let end = run_to_report(&mut state, out, opts, eval_trials as usize, |l| {
        if let Some(f) = progress {
            // SAFETY: the caller gave a function of this signature, and `user` is passed back
            // untouched, as tolray_train's # Safety says.
            if unsafe { f(user, l.iter, total, l.loss, l.spot_um) } != 0 {
                stop.store(true, Ordering::SeqCst);
            }
        }
    })?;
    // SAFETY: `stopped` is writable (the caller's promise) and not NULL (checked above).
    unsafe { *stopped = u32::from(matches!(end, RunEnd::Stopped { .. })) };
    Ok(())
}

/// Trains `lens` with the paper's two stages, as `tolray train` does, writing into the folder
/// `out_dir` (created if missing): `lens-initial.json`, `log.jsonl` (one JSON line per
/// iteration), `checkpoint.json` and `lens-iterN.json` every `checkpoint_every` iterations (0
/// counts as 1), and at the end `training.png`, `report.txt`, `report.json` and
/// `lens-final.json` (the designs evaluated on `eval_trials` held-out tolerance patterns, 1 to
/// 100000). `config_json` is NULL for the lens' defaults or a JSON object whose keys replace
/// them (e.g. `{"pretrain_iters": 100, "tolerance_iters": 100, "samples": 64, "seed": 0}`; the
/// keys are those of `report.json`'s `"config"`; an unknown key is `TOLRAY_ERROR_ARGUMENT`).
/// `progress` (may be NULL) is called after every iteration; when it returns nonzero the run
/// stops after that iteration with a checkpoint, `*stopped` is 1, and [`tolray_train_resume`]
/// continues it to exactly the files of an uninterrupted run. Otherwise `*stopped` is 0.
/// Iterations are deterministic for the settings' seed, whatever the thread count.
///
/// # Safety
/// `lens` is a live handle; `config_json` is NULL or a NUL-terminated string; `out_dir` is a
/// NUL-terminated string; `progress` is NULL or a function with this signature that does not
/// unwind; `user` is passed to it untouched; `stopped` points to a writable `uint32_t`.
#[no_mangle]
pub unsafe extern "C" fn tolray_train(
    lens: *const tolray_lens,
    config_json: *const c_char,
    out_dir: *const c_char,
    checkpoint_every: u32,
    eval_trials: u32,
    progress: tolray_train_progress,
    user: *mut c_void,
    stopped: *mut u32,
) -> tolray_status {
    boundary("tolray_train", || {
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let lens = unsafe { nonnull(lens, "lens") }?;
        let text = if config_json.is_null() {
            None
        } else {
            // SAFETY: a non-NULL `config_json` is a C string, as # Safety says.
            Some(unsafe { c_str(config_json, "config_json") }?)
        };
        // SAFETY: `out_dir` is NULL or a C string, as # Safety says; NULL is refused.
        let out = Path::new(unsafe { c_str(out_dir, "out_dir") }?);
        let cfg = config(&lens.lens, text)?;
        let state = TrainState::new(&lens.lens, cfg);
        // SAFETY: `progress`, `user` and `stopped` are as # Safety says.
        unsafe {
            drive(
                state,
                out,
                checkpoint_every,
                eval_trials,
                progress,
                user,
                stopped,
            )
        }
    })
}

/// Continues the run whose checkpoint is in `out_dir` (a run of [`tolray_train`] that was
/// stopped, or `tolray train`'s) exactly where it stopped, with the same outputs, callback and
/// `*stopped` as [`tolray_train`]. `TOLRAY_ERROR_IO` when `out_dir/checkpoint.json` cannot be
/// read, `TOLRAY_ERROR_PARSE` when it is not a training checkpoint.
///
/// # Safety
/// `out_dir` is a NUL-terminated string; `progress` is NULL or a function with the signature of
/// [`tolray_train_progress`] that does not unwind; `user` is passed to it untouched; `stopped`
/// points to a writable `uint32_t`.
#[no_mangle]
pub unsafe extern "C" fn tolray_train_resume(
    out_dir: *const c_char,
    checkpoint_every: u32,
    eval_trials: u32,
    progress: tolray_train_progress,
    user: *mut c_void,
    stopped: *mut u32,
) -> tolray_status {
    boundary("tolray_train_resume", || {
        // SAFETY: `out_dir` is NULL or a C string, as # Safety says; NULL is refused.
        let out = Path::new(unsafe { c_str(out_dir, "out_dir") }?);
        let state: TrainState = crate::files::read_json(&out.join("checkpoint.json"))?;
        state.config.validate()?;
        // SAFETY: `progress`, `user` and `stopped` are as # Safety says.
        unsafe {
            drive(
                state,
                out,
                checkpoint_every,
                eval_trials,
                progress,
                user,
                stopped,
            )
        }
    })
}
