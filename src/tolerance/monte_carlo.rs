//! Monte Carlo tolerance analysis, the focus compensator, sensitivity, yield statistics, and
//! merging of sharded runs.

use super::criterion::{Criterion, WaveJudge};
use super::spec::{OperandKind, Slot, ToleranceSpec};
use super::Perturbation;
use crate::analysis::SpotMoments;
use crate::error::{Error, Result};
use crate::lens::{Lens, System};
use crate::math::stats::{percentile_sorted, yield_value, YIELD_PERCENTS};
use crate::trace::{Bundles, Field, Pupil, TraceOptions};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Most trials one Monte Carlo study may run (about half an hour at the measured 5,000 trials/s
/// on lens2; larger studies are split with shards).
pub const MAX_TRIALS: usize = 10_000_000;

/// Settings of a Monte Carlo run. Everything that determines the numbers is here, so that shard
/// reports can be checked for compatibility before merging.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct McOptions {
    /// The tolerance spec sampled.
    pub spec: ToleranceSpec,
    /// Total number of trials of the study.
    pub trials: usize,
    /// Seed; trial k uses pattern k of this seed.
    pub seed: u64,
    /// Fields at which RMS spots are computed.
    pub fields: Vec<Field>,
    /// Wavelengths, nm (polychromatic RMS when more than one).
    pub wavelengths_nm: Vec<f64>,
    /// Pupil sampling (aimed at the nominal paraxial entrance pupil).
    pub pupil: Pupil,
    /// Refocus the sensor per trial to the best RMS focus (the compensator).
    pub compensate_focus: bool,
    /// Clip at clear apertures and the stop.
    pub apertures: bool,
    /// What each trial is judged by (the compensator optimises it); the RMS spot is always
    /// reported too, at the compensator's focus.
    #[serde(default)]
    pub criterion: Criterion,
}

/// The outcome of one trial.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrialResult {
    /// Trial index (= pattern index).
    pub index: usize,
    /// RMS spot radius per field, µm (after refocus when compensating).
    pub rms_um: Vec<f64>,
    /// Mean of `rms_um` over the fields, µm.
    pub mean_rms_um: f64,
    /// Sensor refocus of the compensator along the image-plane normal, mm.
    pub focus_shift_mm: Option<f64>,
    /// The criterion per field when it is not the RMS spot (its unit: [`Criterion::label`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub criterion: Option<Vec<f64>>,
    /// Mean of `criterion` over the fields.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_criterion: Option<f64>,
    /// The sampled pattern, so that the trial can be re-traced (`tolray spot --perturb`).
    pub pattern: Perturbation,
}

/// Statistics of one quantity over the trials.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Mean.
    pub mean: f64,
    /// Standard deviation (population).
    pub std: f64,
    /// Minimum.
    pub min: f64,
    /// Maximum.
    pub max: f64,
    /// Percentiles `[p, value]` for p = 10, 50, 70, 90 (linear interpolation between ranks).
    pub percentiles: Vec<[f64; 2]>,
    /// Yield in the paper's form: `[fraction, X]` = "this fraction of lenses have RMS spot
    /// below X µm", for 90, 70, 50 and 10 %.
    pub yield_below: Vec<[f64; 2]>,
    /// For a criterion where higher is better (Strehl, MTF): `[fraction, X]` = "this fraction
    /// of lenses reach at least X", for 90, 70, 50 and 10 %.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub yield_above: Vec<[f64; 2]>,
}

/// Statistics of `values` (in the given order).
pub fn stats(values: &[f64]) -> Stats {
    let n = values.len().max(1) as f64;
    let mean = values.iter().sum::<f64>() / n;
    let std = (values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n).sqrt();
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    Stats {
        mean,
        std,
        min: s.first().copied().unwrap_or(f64::NAN),
        max: s.last().copied().unwrap_or(f64::NAN),
        percentiles: [10.0, 50.0, 70.0, 90.0]
            .iter()
            .map(|&p| [p, percentile_sorted(&s, p)])
            .collect(),
        yield_below: YIELD_PERCENTS
            .iter()
            .map(|&p| [p / 100.0, yield_value(&s, p, false)])
            .collect(),
        yield_above: Vec::new(),
    }
}

/// [`stats`], with [`Stats::yield_above`] when higher values are better.
pub fn stats_for(values: &[f64], higher_is_better: bool) -> Stats {
    let mut st = stats(values);
    if higher_is_better {
        let mut s = values.to_vec();
        s.sort_by(f64::total_cmp);
        st.yield_above = YIELD_PERCENTS
            .iter()
            .map(|&p| [p / 100.0, yield_value(&s, p, true)])
            .collect();
    }
    st
}

/// Summary over all trials: per field and for the field mean.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Per field, in the order of the fields.
    pub per_field: Vec<Stats>,
    /// Of the mean RMS over fields.
    pub mean_over_fields: Stats,
    /// Of the compensator's refocus, mm.
    pub focus_shift_mm: Option<Stats>,
    /// Of the criterion, when it is not the RMS spot.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub criterion: Option<CriterionSummary>,
}

/// Statistics of a criterion other than the RMS spot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CriterionSummary {
    /// What was judged, e.g. `MTF at 30 cycles/mm (mean of T and S)`.
    pub label: String,
    /// Per field, in the order of the fields.
    pub per_field: Vec<Stats>,
    /// Of the field mean.
    pub mean_over_fields: Stats,
}

/// A Monte Carlo report (complete, or one shard of a study).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct McReport {
    /// tolray version that wrote it.
    pub tolray_version: String,
    /// The lens analysed (name or path as given).
    pub lens: String,
    /// Settings.
    pub options: McOptions,
    /// `[k, n]` if this is shard k (from 0) of n.
    pub shard: Option<[usize; 2]>,
    /// Nominal RMS per field, µm (refocused too when compensating).
    pub nominal_rms_um: Vec<f64>,
    /// Nominal refocus, mm (when compensating).
    pub nominal_focus_shift_mm: Option<f64>,
    /// Nominal criterion per field, when it is not the RMS spot.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_criterion: Option<Vec<f64>>,
    /// Trials in index order.
    pub trials: Vec<TrialResult>,
    /// Statistics; present when the report holds every trial of the study.
    pub summary: Option<Summary>,
}

/// Rays of every field and wavelength, generated once from the nominal lens (aimed at its
/// paraxial entrance pupil).
fn bundles(lens: &Lens, opts: &McOptions) -> Result<Bundles> {
    if opts.fields.is_empty() || opts.wavelengths_nm.is_empty() {
        return Err(Error::argument(
            "a tolerance analysis needs at least one field and one wavelength",
        ));
    }
    Bundles::new(lens, &opts.fields, &opts.wavelengths_nm, &opts.pupil)
}

/// What one system is judged: RMS spot per field (µm), the compensator's shift, the criterion
/// per field (when not the RMS spot).
type Judged = (Vec<f64>, Option<f64>, Option<Vec<f64>>);

/// Judges a compiled system: RMS per field (µm), refocused when `opts.compensate_focus` (one
/// sensor shift for all fields: [`SpotMoments::best_focus`] for the RMS spot, the criterion's
/// optimum for a wave criterion), and the criterion per field at that focus.
fn system_eval(
    bundles: &Bundles,
    sys: &System<f64>,
    opts: &McOptions,
    judge: Option<&WaveJudge>,
) -> Result<Judged> {
    let mut rays: Vec<Vec<[f64; 4]>> = vec![Vec::new(); opts.fields.len()];
    let trace = TraceOptions {
        apertures: opts.apertures,
    };
    for k in 0..bundles.len() {
        rays[bundles.sets[k].field_index].extend(bundles.sensor_rays(sys, k, trace));
    }
    let moments = rays
        .iter()
        .enumerate()
        .map(|(f, r)| {
            SpotMoments::of_rays(r).ok_or_else(|| {
                Error::numerical(format!(
                    "no ray of field {} reached the image",
                    opts.fields[f].label()
                ))
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let mut delta = opts
        .compensate_focus
        .then(|| SpotMoments::best_focus(&moments));
    let criterion = match judge {
        None => None,
        Some(j) => Some(match delta {
            Some(d0) => {
                let (d, v) = j.best_focus(sys, d0)?;
                delta = Some(d);
                v
            }
            None => j.values(sys)?,
        }),
    };
    let d = delta.unwrap_or(0.0);
    let rms = moments.iter().map(|m| m.rms_at(d) * 1e3).collect();
    Ok((rms, delta, criterion))
}

/// The wave judge of `opts.criterion` (None for the RMS spot).
fn judge<'a>(lens: &'a Lens, opts: &'a McOptions) -> Result<Option<WaveJudge<'a>>> {
    if opts.criterion == Criterion::RmsSpot {
        return Ok(None);
    }
    WaveJudge::new(
        lens,
        opts.criterion,
        &opts.fields,
        &opts.wavelengths_nm,
        TraceOptions {
            apertures: opts.apertures,
        },
    )
    .map(Some)
}

fn trial_eval(
    lens: &Lens,
    bundles: &Bundles,
    opts: &McOptions,
    judge: Option<&WaveJudge>,
    pattern: &Perturbation,
) -> Result<Judged> {
    let (plens, adj) = pattern.apply(lens)?;
    let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
    system_eval(bundles, &sys, opts, judge)
}

/// RMS spot per field (µm) of `lens` perturbed by `pattern`, refocused when the options say so.
///
/// # Errors
/// Invalid pattern, ray generation, or a field with no surviving ray.
pub fn perturbed_rms(
    lens: &Lens,
    opts: &McOptions,
    pattern: &Perturbation,
) -> Result<(Vec<f64>, Option<f64>)> {
    let j = judge(lens, opts)?;
    trial_eval(lens, &bundles(lens, opts)?, opts, j.as_ref(), pattern).map(|r| (r.0, r.1))
}

/// The criterion per field of `lens` perturbed by `pattern` (after the compensator when the
/// options say so), with the RMS spot per field (µm) and the refocus (mm): what one Monte Carlo
/// trial records. For the RMS spot criterion the first two are the same numbers.
///
/// # Errors
/// As [`perturbed_rms`].
pub fn perturbed_criterion(
    lens: &Lens,
    opts: &McOptions,
    pattern: &Perturbation,
) -> Result<(Vec<f64>, Vec<f64>, Option<f64>)> {
    let j = judge(lens, opts)?;
    let (rms, d, c) = trial_eval(lens, &bundles(lens, opts)?, opts, j.as_ref(), pattern)?;
    Ok((c.unwrap_or_else(|| rms.clone()), rms, d))
}

/// Runs the Monte Carlo trials `range` (all of them when `shard` is `None`) in parallel; results
/// are independent of the thread count. `progress` is called once per finished trial.
///
/// # Errors
/// Spec validation errors, and the first trial whose lens loses every ray of a field (its index
/// and pattern are named).
pub fn monte_carlo(
    lens: &Lens,
    lens_name: &str,
    opts: &McOptions,
    shard: Option<(usize, usize)>,
    progress: &(dyn Fn() + Sync),
) -> Result<McReport> {
    if opts.trials == 0 || opts.trials > MAX_TRIALS {
        return Err(Error::argument(format!(
            "{} trials: give 1 to {MAX_TRIALS} (statistics of no trial are not a result)",
            opts.trials
        )));
    }
    let slots = opts.spec.slots(lens)?;
    let bundles = bundles(lens, opts)?;
    let judge = judge(lens, opts)?;
    let judge = judge.as_ref();
    let (nominal, nominal_shift, nominal_criterion) =
        system_eval(&bundles, &lens.compile(), opts, judge)?;
    let range = match shard {
        None => 0..opts.trials,
        Some((k, n)) => {
            if n == 0 || k >= n {
                return Err(Error::argument(format!("shard {k}/{n}: K must be in 0..N")));
            }
            (k * opts.trials / n)..((k + 1) * opts.trials / n)
        }
    };
    let trials: Vec<TrialResult> = range
        .into_par_iter()
        .map(|k| {
            let pattern = opts.spec.sample_slots(&slots, opts.seed, k as u64);
            let r = trial_eval(lens, &bundles, opts, judge, &pattern).map_err(|e| {
                e.context(format!(
                    "trial {k} (pattern: {})",
                    serde_json::to_string(&pattern).unwrap_or_default()
                ))
            });
            progress();
            r.map(|(rms, shift, crit)| TrialResult {
                index: k,
                mean_rms_um: rms.iter().sum::<f64>() / rms.len() as f64,
                rms_um: rms,
                focus_shift_mm: shift,
                mean_criterion: crit
                    .as_ref()
                    .map(|c| c.iter().sum::<f64>() / c.len() as f64),
                criterion: crit,
                pattern,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let mut report = McReport {
        tolray_version: env!("CARGO_PKG_VERSION").to_string(),
        lens: lens_name.to_string(),
        options: opts.clone(),
        shard: shard.map(|(k, n)| [k, n]),
        nominal_rms_um: nominal,
        nominal_focus_shift_mm: nominal_shift,
        nominal_criterion,
        trials,
        summary: None,
    };
    if shard.is_none() {
        report.summary = Some(summarize(&report));
    }
    Ok(report)
}

fn summarize(r: &McReport) -> Summary {
    let nf = r.options.fields.len();
    let per_field = (0..nf)
        .map(|f| stats(&r.trials.iter().map(|t| t.rms_um[f]).collect::<Vec<_>>()))
        .collect();
    let shifts: Vec<f64> = r.trials.iter().filter_map(|t| t.focus_shift_mm).collect();
    let c = r.options.criterion;
    let criterion = r.nominal_criterion.as_ref().map(|_| {
        let at = |f: usize| -> Vec<f64> {
            r.trials
                .iter()
                .map(|t| t.criterion.as_ref().map_or(f64::NAN, |v| v[f]))
                .collect()
        };
        CriterionSummary {
            label: c.label(),
            per_field: (0..nf)
                .map(|f| stats_for(&at(f), c.higher_is_better()))
                .collect(),
            mean_over_fields: stats_for(
                &r.trials
                    .iter()
                    .map(|t| t.mean_criterion.unwrap_or(f64::NAN))
                    .collect::<Vec<_>>(),
                c.higher_is_better(),
            ),
        }
    });
    Summary {
        per_field,
        mean_over_fields: stats(&r.trials.iter().map(|t| t.mean_rms_um).collect::<Vec<_>>()),
        focus_shift_mm: (!shifts.is_empty()).then(|| stats(&shifts)),
        criterion,
    }
}

/// Combines shard reports of one study into the report a single run gives.
///
/// # Errors
/// [`crate::ErrorKind::Invalid`] if the shards come from different studies, overlap, or leave
/// trials missing.
pub fn merge_reports(parts: &[McReport]) -> Result<McReport> {
    let first = parts
        .first()
        .ok_or_else(|| Error::argument("nothing to merge"))?;
    let mut out = first.clone();
    out.trials.clear();
    for (i, p) in parts.iter().enumerate() {
        if p.options != first.options
            || p.lens != first.lens
            || p.nominal_rms_um != first.nominal_rms_um
        {
            return Err(Error::invalid(format!(
                "report {i} comes from a different study (lens, settings or nominal differ)"
            )));
        }
        out.trials.extend(p.trials.iter().cloned());
    }
    out.trials.sort_by_key(|t| t.index);
    for (k, t) in out.trials.iter().enumerate() {
        if t.index != k {
            let what = if t.index < k {
                "appears twice"
            } else {
                "is missing"
            };
            return Err(Error::invalid(format!(
                "trial {} {what}",
                if t.index < k { t.index } else { k }
            )));
        }
    }
    if out.trials.len() != first.options.trials {
        return Err(Error::invalid(format!(
            "trials {}..{} are missing",
            out.trials.len(),
            first.options.trials
        )));
    }
    out.shard = None;
    out.summary = Some(summarize(&out));
    Ok(out)
}

/// One row of a sensitivity table: one operand on one target and axis, at −max and +max.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SensitivityRow {
    /// Operand.
    pub operand: OperandKind,
    /// Element or surface index.
    pub target: usize,
    /// Axis (0 = x, 1 = y, 2 = z) for decenters and tilts.
    pub axis: usize,
    /// The range max applied.
    pub max: f64,
    /// RMS per field at −max, µm.
    pub rms_minus_um: Vec<f64>,
    /// RMS per field at +max, µm.
    pub rms_plus_um: Vec<f64>,
    /// Largest |ΔRMS| over fields and signs, µm.
    pub worst_delta_um: f64,
    /// The criterion per field at −max, when it is not the RMS spot.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub criterion_minus: Option<Vec<f64>>,
    /// The criterion per field at +max.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub criterion_plus: Option<Vec<f64>>,
    /// Largest |Δ criterion| over fields and signs (the rows are sorted by it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub worst_delta_criterion: Option<f64>,
}

/// The nominal lens of a sensitivity table: RMS spot per field (µm) and the criterion per field
/// (when not the RMS spot).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SensitivityNominal {
    /// RMS spot per field, µm.
    pub rms_um: Vec<f64>,
    /// The criterion per field.
    pub criterion: Option<Vec<f64>>,
}

/// Sensitivity analysis: each operand alone at −max and +max, sorted worst first.
///
/// # Errors
/// As [`monte_carlo`].
pub fn sensitivity(
    lens: &Lens,
    opts: &McOptions,
) -> Result<(SensitivityNominal, Vec<SensitivityRow>)> {
    let slots: Vec<Slot> = opts.spec.slots(lens)?;
    let bundles = bundles(lens, opts)?;
    let judge = judge(lens, opts)?;
    let judge = judge.as_ref();
    let (nominal, _, nominal_c) = system_eval(&bundles, &lens.compile(), opts, judge)?;
    let worst_of = |minus: &[f64], plus: &[f64], nom: &[f64]| {
        minus
            .iter()
            .chain(plus)
            .zip(nom.iter().chain(nom))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    let mut rows = slots
        .par_iter()
        .map(|&(k, t, axis)| {
            let op = &opts.spec.operands[k];
            let at = |v: f64| {
                let mut p = Perturbation {
                    pivot: opts.spec.pivot,
                    ..Default::default()
                };
                op.kind.set(&mut p, t, axis, v);
                trial_eval(lens, &bundles, opts, judge, &p)
            };
            let ((minus, _, cm), (plus, _, cp)) = (at(-op.max)?, at(op.max)?);
            let worst = worst_of(&minus, &plus, &nominal);
            let worst_c = match (&cm, &cp, &nominal_c) {
                (Some(a), Some(b), Some(n)) => Some(worst_of(a, b, n)),
                _ => None,
            };
            Ok(SensitivityRow {
                operand: op.kind,
                target: t,
                axis,
                max: op.max,
                rms_minus_um: minus,
                rms_plus_um: plus,
                worst_delta_um: worst,
                criterion_minus: cm,
                criterion_plus: cp,
                worst_delta_criterion: worst_c,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    rows.sort_by(|a, b| {
        let key = |r: &SensitivityRow| r.worst_delta_criterion.unwrap_or(r.worst_delta_um);
        key(b).total_cmp(&key(a))
    });
    Ok((
        SensitivityNominal {
            rms_um: nominal,
            criterion: nominal_c,
        },
        rows,
    ))
}
