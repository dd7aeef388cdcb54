//! Statistics over units (lenses, images, training seeds): one percentile, the paper's yield in
//! either direction ([`yield_value`], [`YieldTable`]), and paired bootstrap intervals of a
//! difference between two designs.

use crate::error::{Error, Result};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// Percentile `p` (0 to 100, clamped) of `values` by linear interpolation between order
/// statistics (numpy's default); NaN for no values.
///
/// ```
/// use tolray::math::stats::percentile;
/// // numpy.percentile([3, 1, 4, 1, 5], [10, 97.5]) = 1.0, 4.9
/// assert_eq!(percentile(&[3.0, 1.0, 4.0, 1.0, 5.0], 10.0), 1.0);
/// assert!((percentile(&[3.0, 1.0, 4.0, 1.0, 5.0], 97.5) - 4.9).abs() < 1e-12);
/// ```
pub fn percentile(values: &[f64], p: f64) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    percentile_sorted(&v, p)
}

/// [`percentile`] of values already sorted in ascending order.
pub fn percentile_sorted(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = (p / 100.0).clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos - pos.floor());
    if i + 1 < sorted.len() {
        sorted[i] + f * (sorted[i + 1] - sorted[i])
    } else {
        sorted[i]
    }
}

/// The fractions of units, in percent, that the paper's yield tables give: 90, 70, 50 and 10.
pub const YIELD_PERCENTS: [f64; 4] = [90.0, 70.0, 50.0, 10.0];

/// The paper's yield at `percent` % of units over values sorted ascending: the value that
/// `percent` % of units stay below when lower is better (an RMS spot: the `percent`-th
/// percentile), or reach at least when higher is better (PSNR, Strehl, MTF: the
/// `(100 - percent)`-th percentile).
///
/// ```
/// use tolray::math::stats::yield_value;
/// let sorted = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0];
/// assert_eq!(yield_value(&sorted, 90.0, false), 10.0); // 90 % of units below 10
/// assert_eq!(yield_value(&sorted, 90.0, true), 2.0); // 90 % of units at least 2
/// ```
pub fn yield_value(sorted: &[f64], percent: f64, higher_is_better: bool) -> f64 {
    if higher_is_better {
        percentile_sorted(sorted, 100.0 - percent)
    } else {
        percentile_sorted(sorted, percent)
    }
}

/// The manufacturing-yield table: the value that 90/70/50/10 % of units exceed (the 10th,
/// 30th, 50th and 90th percentiles).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct YieldTable {
    /// Exceeded by 90 % of units.
    #[serde(rename = "90")]
    pub y90: f64,
    /// Exceeded by 70 %.
    #[serde(rename = "70")]
    pub y70: f64,
    /// Exceeded by 50 % (the median).
    #[serde(rename = "50")]
    pub y50: f64,
    /// Exceeded by 10 %.
    #[serde(rename = "10")]
    pub y10: f64,
}

impl YieldTable {
    /// The table of `values`, where higher is better (PSNR, SSIM).
    pub fn from(values: &[f64]) -> YieldTable {
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let y = |percent| yield_value(&v, percent, true);
        YieldTable {
            y90: y(90.0),
            y70: y(70.0),
            y50: y(50.0),
            y10: y(10.0),
        }
    }
}

/// `stat(a) - stat(b)` and its 95 % bootstrap percentile interval over `resamples` paired
/// resamples (the same resampled unit indices for `a` and `b`), seeded.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for samples of different or zero length or no resamples.
pub fn paired_bootstrap(
    a: &[f64],
    b: &[f64],
    stat: impl Fn(&[f64]) -> f64,
    resamples: usize,
    seed: u64,
) -> Result<(f64, [f64; 2])> {
    if a.len() != b.len() || a.is_empty() || resamples == 0 {
        return Err(Error::argument(format!(
            "paired bootstrap of {} and {} values with {resamples} resamples",
            a.len(),
            b.len()
        )));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = a.len();
    let (mut ra, mut rb) = (vec![0.0; n], vec![0.0; n]);
    let diffs: Vec<f64> = (0..resamples)
        .map(|_| {
            for k in 0..n {
                let i = rng.random_range(0..n);
                ra[k] = a[i];
                rb[k] = b[i];
            }
            stat(&ra) - stat(&rb)
        })
        .collect();
    Ok((
        stat(a) - stat(b),
        [percentile(&diffs, 2.5), percentile(&diffs, 97.5)],
    ))
}

/// Pooled over independent repetitions (training seeds) evaluated on the same units: the mean
/// over groups of `stat(a_g) - stat(b_g)` and its 95 % bootstrap percentile interval. Each of
/// the `resamples` draws both groups (with replacement: the spread between training seeds) and
/// unit indices (with replacement, the same indices in every group and for `a` and `b`: the
/// units are shared and paired), so the interval carries both sources of variation.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for no group, groups or samples of different or zero length,
/// or no resamples.
///
/// # Examples
/// ```
/// use tolray::math::stats::pooled_paired_bootstrap;
/// let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
/// // Two seeds whose designs differ by exactly 0.5 and 0.3 dB on every unit.
/// let g1 = (vec![20.5, 21.5, 19.5], vec![20.0, 21.0, 19.0]);
/// let g2 = (vec![20.3, 21.3, 19.3], vec![20.0, 21.0, 19.0]);
/// let (d, ci) = pooled_paired_bootstrap(&[g1, g2], mean, 1000, 7)?;
/// assert!((d - 0.4).abs() < 1e-12 && ci[0] >= 0.3 - 1e-12 && ci[1] <= 0.5 + 1e-12);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn pooled_paired_bootstrap(
    groups: &[(Vec<f64>, Vec<f64>)],
    stat: impl Fn(&[f64]) -> f64,
    resamples: usize,
    seed: u64,
) -> Result<(f64, [f64; 2])> {
    let n = groups.first().map_or(0, |g| g.0.len());
    if groups.is_empty()
        || n == 0
        || resamples == 0
        || groups.iter().any(|g| g.0.len() != n || g.1.len() != n)
    {
        return Err(Error::argument(format!(
            "pooled bootstrap of {} groups (every group needs the same, nonzero number of paired \
             values) with {resamples} resamples",
            groups.len()
        )));
    }
    let m = groups.len();
    let diff = |g: &(Vec<f64>, Vec<f64>)| stat(&g.0) - stat(&g.1);
    let estimate = groups.iter().map(diff).sum::<f64>() / m as f64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut ra, mut rb) = (vec![0.0; n], vec![0.0; n]);
    let mut units = vec![0usize; n];
    let diffs: Vec<f64> = (0..resamples)
        .map(|_| {
            for u in units.iter_mut() {
                *u = rng.random_range(0..n);
            }
            let mut sum = 0.0;
            for _ in 0..m {
                let g = &groups[rng.random_range(0..m)];
                for (k, &i) in units.iter().enumerate() {
                    ra[k] = g.0[i];
                    rb[k] = g.1[i];
                }
                sum += stat(&ra) - stat(&rb);
            }
            sum / m as f64
        })
        .collect();
    Ok((
        estimate,
        [percentile(&diffs, 2.5), percentile(&diffs, 97.5)],
    ))
}
