//! Manufacturing-yield evaluation of deep-optics designs: the same held-out random tolerance
//! patterns for every design (paired), each fabricated unit imaging the evaluation images through
//! its own RGB PSF map, the design's decoder reconstructing them, and PSNR/SSIM per unit; per
//! design the mean, standard deviation and the yield table (the PSNR that 90/70/50/10 % of units
//! exceed, the paper's Table 2), and for pairs of designs the paired difference with a bootstrap
//! 95 % interval.
//!
//! An evaluation image is `grid · patch` pixels square: tile `t` of the PSF grid covers its
//! `patch x patch` block, blurred by that tile's PSF over the block plus a halo from the
//! reflect-padded image (so the image is rendered as [`crate::image::render::render_map`] does,
//! with hard tile edges) and decoded by the decoder's filter of that tile. The sensor pitch is
//! the lens', so each tile's block is a `patch`-pixel window of the full-resolution sensor at
//! that field: a stratified sample of the sensor, one block per PSF, not the whole 2048-pixel
//! frame (which is what the paper renders and what `patch = 256` gives).

use super::{psf_options, rgb_psf_map_of, Design};
use crate::decoder::Crop;
use crate::error::{Error, Result};
use crate::image::metrics::{psnr, ssim};
use crate::image::render::{blur_patch, pad_reflect, SensorNoise};
use crate::image::Image;
use crate::lens::{Lens, System};
use crate::math::stats::{paired_bootstrap, pooled_paired_bootstrap, YieldTable};
use crate::psf::PsfModel;
use crate::tolerance::monte_carlo::{perturbed_rms, McOptions};
use crate::tolerance::ToleranceSpec;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Margin of capture around each tile's block that the decoder sees, pixels (a multiple of 8,
/// the U-Net's size step).
pub const DECODE_MARGIN_PX: usize = 8;

/// Evaluation settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    /// Number of random fabricated units (tolerance patterns).
    pub trials: usize,
    /// Seed of the patterns (use one that training did not).
    pub seed: u64,
    /// Tolerances.
    pub spec: ToleranceSpec,
    /// PSF grid per side.
    pub grid: usize,
    /// PSF kernel size, pixels.
    pub ks: usize,
    /// Rays per PSF.
    pub spp: usize,
    /// Additive Gaussian noise, linear [0, 1] units.
    pub noise_sigma: f64,
    /// Electrons of a full well for photon shot noise on top of `noise_sigma`
    /// ([`SensorNoise`]); `None`: Gaussian noise alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_well_electrons: Option<f64>,
    /// Block side per PSF tile, pixels (the evaluation images are `grid · patch` square).
    pub patch_px: usize,
    /// Refocus each unit to its best RMS focus before imaging (the assembly's focus
    /// compensator).
    pub compensate_focus: bool,
    /// Bootstrap resamples of the paired intervals.
    pub bootstrap: usize,
    /// The PSFs the units are imaged with: geometric (the paper's, as trained) or diffraction.
    #[serde(default, skip_serializing_if = "PsfModel::is_geometric")]
    pub psf: PsfModel,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            trials: 100,
            seed: 1_000_003,
            spec: ToleranceSpec::default(),
            grid: 8,
            ks: 51,
            spp: 8192,
            noise_sigma: 0.01,
            full_well_electrons: None,
            patch_px: 48,
            compensate_focus: false,
            bootstrap: 2000,
            psf: PsfModel::Geometric,
        }
    }
}

impl EvalConfig {
    /// The sensor noise of the captures: `noise_sigma` and `full_well_electrons`.
    pub fn sensor(&self) -> SensorNoise {
        SensorNoise {
            sigma: self.noise_sigma,
            full_well_electrons: self.full_well_electrons,
        }
    }
}

/// One unit's scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrialScore {
    /// Pattern index.
    pub index: usize,
    /// Mean over the evaluation images of the PSNR of the decoded image (sRGB, dB).
    pub psnr: f64,
    /// Mean over the evaluation images of the SSIM of the decoded image (sRGB).
    pub ssim: f64,
    /// Mean over fields 0, 0.7 and 1 of the polychromatic RMS spot radius, µm.
    pub rms_spot_um: f64,
    /// Mean over tiles and channels of the PSF similarity to the design's nominal PSF map.
    pub psf_similarity: f64,
}

/// The evaluation images, linear RGB, each `grid · patch` square.
#[derive(Clone, Debug)]
pub struct EvalImages {
    /// Name and image.
    pub images: Vec<(String, Image)>,
}

/// Which trial's images a report shows.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Example {
    /// `best`, `median` or `worst` (by PSNR).
    pub which: String,
    /// Pattern index.
    pub trial: usize,
    /// Its PSNR, dB.
    pub psnr: f64,
    /// Sharp, captured and reconstructed first evaluation image.
    #[serde(skip)]
    pub images: Option<[Image; 3]>,
}

/// One design's results.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DesignScores {
    /// Design name.
    pub name: String,
    /// Per-unit scores, by pattern index.
    pub trials: Vec<TrialScore>,
    /// Scores of the nominal lens (no tolerance).
    pub nominal: TrialScore,
}

/// Renders the evaluation images through `sys` (RGB PSF map of `design.lens`) and decodes them
/// with the design's decoder; returns per image (sharp, captured, reconstructed) when `keep`,
/// and the mean PSNR and SSIM. Noise of image `i` comes from stream `noise_stream + i`.
fn image_scores(
    design: &Design,
    map: &[f32],
    images: &EvalImages,
    cfg: &EvalConfig,
    noise_stream: u64,
    keep: bool,
) -> Result<(f64, f64, Vec<[Image; 3]>)> {
    let (g, p, ks) = (cfg.grid, cfg.patch_px, cfg.ks);
    let nc = 3;
    let ks2 = ks * ks;
    let mut psnr_sum = 0.0;
    let mut ssim_sum = 0.0;
    let mut kept = Vec::new();
    for (i, (name, img)) in images.images.iter().enumerate() {
        if img.width != g * p || img.height != g * p {
            return Err(Error::argument(format!(
                "evaluation image {name} is {}x{}; the settings need {s}x{s}",
                img.width,
                img.height,
                s = g * p
            )));
        }
        let half = (ks - 1) / 2;
        let padded = pad_reflect(img, half)?;
        // Each tile's block plus its halo, blurred by the tile's PSF.
        let crops: Vec<Crop> = (0..g * g)
            .into_par_iter()
            .map(|t| -> Result<Crop> {
                let (row, col) = (t / g, t % g);
                let xpad = padded.crop(col * p, row * p, p + ks - 1, p + ks - 1)?;
                let psf = &map[t * nc * ks2..(t + 1) * nc * ks2];
                let mut y = blur_patch(&xpad.data, p, p, psf, ks)?;
                cfg.sensor().add(
                    &mut y,
                    cfg.seed ^ 0x6576_616c,
                    (noise_stream + i as u64) * 4096 + t as u64,
                );
                let x = xpad.crop(half, half, p, p)?.data;
                Ok(Crop {
                    tile: t,
                    y,
                    x,
                    w: p,
                    h: p,
                })
            })
            .collect::<Result<_>>()?;
        let mut captured = Image::new(g * p, g * p)?;
        for (t, c) in crops.iter().enumerate() {
            let (row, col) = (t / g, t % g);
            for ch in 0..nc {
                for yy in 0..p {
                    let dst = ch * g * p * g * p + (row * p + yy) * g * p + col * p;
                    let src = ch * p * p + yy * p;
                    captured.data[dst..dst + p].copy_from_slice(&c.y[src..src + p]);
                }
            }
        }
        // Each tile is decoded with a margin of the capture around it (reflected at the image
        // border) and only its own block kept, so that tiles do not show seams.
        let m = DECODE_MARGIN_PX;
        let cpad = pad_reflect(&captured, m)?;
        let views: Vec<Crop> = (0..g * g)
            .map(|t| {
                let (row, col) = (t / g, t % g);
                Ok(Crop {
                    tile: t,
                    y: cpad.crop(col * p, row * p, p + 2 * m, p + 2 * m)?.data,
                    x: Vec::new(),
                    w: p + 2 * m,
                    h: p + 2 * m,
                })
            })
            .collect::<Result<_>>()?;
        let xhat = design.decoder.decode_batch(&views)?;
        let mut recon = Image::new(g * p, g * p)?;
        let q = p + 2 * m;
        for (t, r) in xhat.iter().enumerate() {
            let (row, col) = (t / g, t % g);
            for ch in 0..nc {
                for yy in 0..p {
                    let dst = ch * g * p * g * p + (row * p + yy) * g * p + col * p;
                    let src = ch * q * q + (yy + m) * q + m;
                    recon.data[dst..dst + p].copy_from_slice(&r[src..src + p]);
                }
            }
        }
        let (sharp, rec) = (img.to_srgb(), recon.to_srgb());
        psnr_sum += psnr(&sharp, &rec)?;
        ssim_sum += ssim(&sharp, &rec)?;
        if keep {
            kept.push([img.clone(), captured, recon]);
        }
    }
    let n = images.images.len() as f64;
    Ok((psnr_sum / n, ssim_sum / n, kept))
}

/// The fabricated unit `k` of `cfg` (the nominal lens for `None`) as [`evaluate`] scores it:
/// its pattern applied and, with `compensate_focus`, its sensor moved to its best RMS focus; with
/// its RMS spot per field, µm.
fn unit(
    lens: &Lens,
    cfg: &EvalConfig,
    k: Option<usize>,
) -> Result<(Lens, crate::lens::Adjustments, Vec<f64>)> {
    let mc = McOptions {
        compensate_focus: cfg.compensate_focus,
        ..super::refocus_options(lens)
    };
    Ok(match k {
        Some(k) => {
            let pattern = cfg.spec.sample(lens, cfg.seed, k as u64)?;
            let (rms, delta) = perturbed_rms(lens, &mc, &pattern)?;
            let (plens, adj) = super::unit_lens(lens, &pattern, delta)?;
            (plens, adj, rms)
        }
        None => {
            let empty = crate::tolerance::Perturbation::default();
            let (rms, _) = perturbed_rms(lens, &mc, &empty)?;
            let (plens, adj) = empty.apply(lens)?;
            (plens, adj, rms)
        }
    })
}

/// Scores `design` on the patterns `range` of `cfg` (all trials when `None`), in parallel over
/// patterns, plus the nominal lens. Deterministic whatever the thread count.
///
/// # Errors
/// Bad settings or images; a unit that loses every ray of a field or whose PSF receives no ray
/// (named with its pattern index).
pub fn evaluate(
    name: &str,
    design: &Design,
    images: &EvalImages,
    cfg: &EvalConfig,
    range: std::ops::Range<usize>,
) -> Result<DesignScores> {
    if images.images.is_empty() {
        return Err(Error::argument("evaluation needs at least one image"));
    }
    let lens = &design.lens;
    cfg.spec.validate(lens)?;
    cfg.sensor().validate()?;
    let wavelengths = lens.rgb_wavelengths_nm.to_vec();
    let opts = psf_options(lens, cfg.ks, cfg.spp, cfg.seed);
    let nominal_map = rgb_psf_map_of(
        cfg.psf,
        lens,
        &lens.compile(),
        cfg.grid,
        &wavelengths,
        &opts,
    )?;
    let ks2 = cfg.ks * cfg.ks;
    let score = |k: Option<usize>| -> Result<TrialScore> {
        let (plens, adj, rms) = unit(lens, cfg, k)?;
        let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
        let map = rgb_psf_map_of(cfg.psf, lens, &sys, cfg.grid, &wavelengths, &opts)?;
        let sim = nominal_map
            .chunks(ks2)
            .zip(map.chunks(ks2))
            .map(|(a, b)| {
                let a: Vec<f64> = a.iter().map(|&v| v as f64).collect();
                let b: Vec<f64> = b.iter().map(|&v| v as f64).collect();
                crate::psf::psf_similarity(&a, &b, cfg.ks)
            })
            .sum::<f64>()
            / (nominal_map.len() / ks2) as f64;
        let stream = k.map_or(0, |k| k as u64 + 1) * 64;
        let (psnr, ssim, _) = image_scores(design, &map, images, cfg, stream, false)?;
        let index = k.unwrap_or(usize::MAX);
        let s = TrialScore {
            index,
            psnr,
            ssim,
            rms_spot_um: rms.iter().sum::<f64>() / rms.len() as f64,
            psf_similarity: sim,
        };
        if [s.psnr, s.ssim, s.rms_spot_um, s.psf_similarity]
            .iter()
            .any(|v| !v.is_finite())
        {
            return Err(Error::numerical(format!(
                "design {name}, pattern {index}: a score is not finite ({s:?})"
            )));
        }
        Ok(s)
    };
    let nominal = score(None).map_err(|e| e.context(format!("design {name}, nominal lens")))?;
    let trials = range
        .into_par_iter()
        .map(|k| score(Some(k)).map_err(|e| e.context(format!("design {name}, pattern {k}"))))
        .collect::<Result<Vec<_>>>()?;
    Ok(DesignScores {
        name: name.to_string(),
        trials,
        nominal,
    })
}

/// The sharp, captured and reconstructed evaluation images of one pattern (`None`: the nominal
/// lens), as in [`evaluate`].
///
/// # Errors
/// As [`evaluate`].
pub fn example_images(
    design: &Design,
    images: &EvalImages,
    cfg: &EvalConfig,
    pattern: Option<usize>,
) -> Result<Vec<[Image; 3]>> {
    let lens = &design.lens;
    let wavelengths = lens.rgb_wavelengths_nm.to_vec();
    let opts = psf_options(lens, cfg.ks, cfg.spp, cfg.seed);
    let (plens, adj, _) = unit(lens, cfg, pattern)?;
    let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
    let map = rgb_psf_map_of(cfg.psf, lens, &sys, cfg.grid, &wavelengths, &opts)?;
    let stream = pattern.map_or(0, |k| k as u64 + 1) * 64;
    Ok(image_scores(design, &map, images, cfg, stream, true)?.2)
}

/// Mean, standard deviation and yield table of a set of values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Mean.
    pub mean: f64,
    /// Standard deviation (population).
    pub std: f64,
    /// The value that 90/70/50/10 % of units exceed.
    #[serde(rename = "yield")]
    pub yield_table: YieldTable,
}

impl Summary {
    /// Summarizes `v`.
    pub fn of(v: &[f64]) -> Summary {
        let n = v.len().max(1) as f64;
        let mean = v.iter().sum::<f64>() / n;
        let std = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n).sqrt();
        Summary {
            mean,
            std,
            yield_table: YieldTable::from(v),
        }
    }
}

/// A design's row of the report.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DesignRow {
    /// Design name.
    pub name: String,
    /// Number of units.
    pub trials: usize,
    /// PSNR, dB.
    pub psnr: Summary,
    /// SSIM.
    pub ssim: Summary,
    /// RMS spot, µm.
    pub rms_spot_um: Summary,
    /// PSF similarity to the design's nominal PSFs.
    pub psf_similarity: Summary,
    /// PSNR of the nominal lens, dB.
    pub nominal_psnr: f64,
}

/// Paired comparison of design `a` against design `b` (differences are a minus b).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PairRow {
    /// Design a.
    pub a: String,
    /// Design b.
    pub b: String,
    /// Mean PSNR difference, dB.
    pub psnr_mean_diff: f64,
    /// Its bootstrap 95 % interval.
    pub psnr_mean_diff_ci95: [f64; 2],
    /// Difference of the PSNR at 90 % yield, dB.
    pub psnr_yield90_diff: f64,
    /// Its bootstrap 95 % interval.
    pub psnr_yield90_diff_ci95: [f64; 2],
}

/// The evaluation report: settings, design rows, pairs and every unit's scores (so that shards
/// merge into exactly the single-run report).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    /// Settings.
    pub config: EvalConfig,
    /// Names of the evaluation images.
    pub images: Vec<String>,
    /// One row per design.
    pub designs: Vec<DesignRow>,
    /// Paired comparisons.
    pub pairs: Vec<PairRow>,
    /// Per-design unit scores.
    pub scores: Vec<DesignScores>,
}

impl Report {
    /// The design table in the paper's Table 2 layout, as its column headers and one row of
    /// formatted cells per design: the one table the text report and the HTML report print.
    ///
    /// # Examples
    /// ```
    /// # fn show(report: &tolray::deep::eval::Report) {
    /// let (header, rows) = report.design_table();
    /// assert_eq!(header[2], "PSNR (dB)");
    /// for row in &rows {
    ///     println!("{}", row.join(" | "));
    /// }
    /// # }
    /// ```
    pub fn design_table(&self) -> ([&'static str; 10], Vec<[String; 10]>) {
        let header = [
            "design",
            "RMS spot (µm)",
            "PSNR (dB)",
            "SSIM",
            "PSF similarity",
            "PSNR @90 %",
            "@70 %",
            "@50 %",
            "@10 %",
            "nominal PSNR",
        ];
        let rows = self
            .designs
            .iter()
            .map(|d| {
                let y = &d.psnr.yield_table;
                [
                    d.name.clone(),
                    format!("{:.2}", d.rms_spot_um.mean),
                    format!("{:.2} ± {:.2}", d.psnr.mean, d.psnr.std),
                    format!("{:.4}", d.ssim.mean),
                    format!("{:.3}", d.psf_similarity.mean),
                    format!("{:.2}", y.y90),
                    format!("{:.2}", y.y70),
                    format!("{:.2}", y.y50),
                    format!("{:.2}", y.y10),
                    format!("{:.2}", d.nominal_psnr),
                ]
            })
            .collect();
        (header, rows)
    }
}

/// Mean of `v` (0 for none): the paired comparisons' first statistic.
fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The value 90 % of `v` exceed: the paired comparisons' yield statistic.
fn y90(v: &[f64]) -> f64 {
    YieldTable::from(v).y90
}

/// Builds the report from per-design scores; `pairs` names (a, b) design pairs.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for a pair naming an unknown design, or designs scored on
/// different patterns.
pub fn report(
    config: &EvalConfig,
    images: &[String],
    scores: Vec<DesignScores>,
    pairs: &[(String, String)],
) -> Result<Report> {
    let designs = scores
        .iter()
        .map(|s| {
            let col = |f: fn(&TrialScore) -> f64| s.trials.iter().map(f).collect::<Vec<_>>();
            DesignRow {
                name: s.name.clone(),
                trials: s.trials.len(),
                psnr: Summary::of(&col(|t| t.psnr)),
                ssim: Summary::of(&col(|t| t.ssim)),
                rms_spot_um: Summary::of(&col(|t| t.rms_spot_um)),
                psf_similarity: Summary::of(&col(|t| t.psf_similarity)),
                nominal_psnr: s.nominal.psnr,
            }
        })
        .collect();
    let find = |n: &str| {
        scores.iter().find(|s| s.name == n).ok_or_else(|| {
            Error::argument(format!(
                "pair names design \"{n}\", which was not evaluated"
            ))
        })
    };
    let mut rows = Vec::new();
    for (a, b) in pairs {
        let (sa, sb) = (find(a)?, find(b)?);
        let ia: Vec<usize> = sa.trials.iter().map(|t| t.index).collect();
        let ib: Vec<usize> = sb.trials.iter().map(|t| t.index).collect();
        if ia != ib {
            return Err(Error::argument(format!(
                "designs {a} and {b} were scored on different patterns; a paired comparison needs the same"
            )));
        }
        let pa: Vec<f64> = sa.trials.iter().map(|t| t.psnr).collect();
        let pb: Vec<f64> = sb.trials.iter().map(|t| t.psnr).collect();
        let (dm, cim) = paired_bootstrap(&pa, &pb, mean, config.bootstrap, config.seed)?;
        let (dy, ciy) = paired_bootstrap(&pa, &pb, y90, config.bootstrap, config.seed ^ 1)?;
        rows.push(PairRow {
            a: a.clone(),
            b: b.clone(),
            psnr_mean_diff: dm,
            psnr_mean_diff_ci95: cim,
            psnr_yield90_diff: dy,
            psnr_yield90_diff_ci95: ciy,
        });
    }
    Ok(Report {
        config: config.clone(),
        images: images.to_vec(),
        designs,
        pairs: rows,
        scores,
    })
}

/// The built-in evaluation photographs (`data/images/`, public domain or CC0; see
/// `data/images/SOURCES.md`), 384 x 384 sRGB PNG.
const BUILTIN_PHOTOS: [(&str, &[u8]); 4] = [
    (
        "astronaut",
        include_bytes!("../../data/images/astronaut.png"),
    ),
    ("coffee", include_bytes!("../../data/images/coffee.png")),
    ("rocket", include_bytes!("../../data/images/rocket.png")),
    ("camera", include_bytes!("../../data/images/camera.png")),
];

/// The centre `side x side` crop of `img`.
fn centre_crop(name: &str, img: &Image, side: usize) -> Result<Image> {
    if img.width < side || img.height < side {
        return Err(Error::argument(format!(
            "evaluation image {name} is {}x{}; at least {side}x{side} is needed (PSF grid x patch)",
            img.width, img.height
        )));
    }
    img.crop((img.width - side) / 2, (img.height - side) / 2, side, side)
}

impl EvalImages {
    /// The built-in set: a dead-leaves image (seed `seed`) and the first `photos` built-in
    /// photographs (at most 4), centre crops of `side` pixels (at most 384 for the photographs).
    ///
    /// # Errors
    /// A side larger than the photographs.
    pub fn builtin(side: usize, photos: usize, seed: u64) -> Result<EvalImages> {
        let mut images = vec![(
            "dead-leaves".to_string(),
            crate::image::deadleaves::DeadLeaves::default().generate(side, side, seed, u64::MAX)?,
        )];
        for (name, bytes) in BUILTIN_PHOTOS.iter().take(photos) {
            let img = Image::decode(bytes).map_err(|e| e.context(name))?;
            images.push((name.to_string(), centre_crop(name, &img, side)?));
        }
        Ok(EvalImages { images })
    }

    /// Every PNG or JPEG file in `dir` (sorted by name), centre crops of `side` pixels.
    ///
    /// # Errors
    /// I/O and decoding errors naming the file; a folder without images; an image smaller than
    /// `side`.
    pub fn from_dir(dir: &std::path::Path, side: usize) -> Result<EvalImages> {
        let files = crate::image::source::image_files(dir)?;
        let images = files
            .iter()
            .map(|p| {
                let name = p
                    .file_name()
                    .map_or(String::new(), |n| n.to_string_lossy().into_owned());
                let img = Image::load(p)?;
                Ok((
                    name.clone(),
                    centre_crop(&name, &img, side).map_err(|e| e.context(p.display()))?,
                ))
            })
            .collect::<Result<_>>()?;
        Ok(EvalImages { images })
    }
}

/// A comparison pooled over studies that differ only in their training seed (see [`pool`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PooledPair {
    /// Design a.
    pub a: String,
    /// Design b.
    pub b: String,
    /// Per study, the mean PSNR difference a − b, dB.
    pub per_seed_mean_diff: Vec<f64>,
    /// Per study, the difference of the PSNR at 90 % yield, dB.
    pub per_seed_yield90_diff: Vec<f64>,
    /// Mean over the studies of the mean PSNR difference, dB.
    pub psnr_mean_diff: f64,
    /// Its two-level bootstrap 95 % interval (studies and units resampled).
    pub psnr_mean_diff_ci95: [f64; 2],
    /// Mean over the studies of the 90 %-yield PSNR difference, dB.
    pub psnr_yield90_diff: f64,
    /// Its two-level bootstrap 95 % interval.
    pub psnr_yield90_diff_ci95: [f64; 2],
}

/// Several studies' evaluations pooled (see [`pool`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PooledReport {
    /// Number of studies (training seeds).
    pub studies: usize,
    /// Units per study (the same patterns in every study).
    pub trials: usize,
    /// Bootstrap resamples.
    pub bootstrap: usize,
    /// One row per pair of the first report.
    pub pairs: Vec<PooledPair>,
}

/// Pools the evaluation reports of studies that differ only in their training seed (the same
/// evaluation settings, hence the same fabricated units): for each pair of the first report,
/// the mean over studies of the per-study PSNR differences (mean and 90 % yield), with a
/// two-level paired bootstrap interval ([`pooled_paired_bootstrap`]: studies and shared units
/// resampled), so that a direction seen in every seed can be tested as a whole.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for no report, reports evaluated with different settings
/// (trials, evaluation seed, tolerance spec, images) or on different units, or a pair naming a
/// design some report lacks.
pub fn pool(reports: &[Report]) -> Result<PooledReport> {
    let first = reports
        .first()
        .ok_or_else(|| Error::argument("pooling needs at least one report"))?;
    for (k, r) in reports.iter().enumerate() {
        if r.config != first.config || r.images != first.images {
            return Err(Error::argument(format!(
                "report {k}: its evaluation settings or images differ from report 0's; pooled \
                 studies must be evaluated on the same units"
            )));
        }
    }
    let psnr = |r: &Report, name: &str| -> Result<(Vec<usize>, Vec<f64>)> {
        let s =
            r.scores.iter().find(|s| s.name == name).ok_or_else(|| {
                Error::argument(format!("a report has no design \"{name}\" to pool"))
            })?;
        Ok((
            s.trials.iter().map(|t| t.index).collect(),
            s.trials.iter().map(|t| t.psnr).collect(),
        ))
    };
    let mut pairs = Vec::new();
    for p in &first.pairs {
        let mut groups = Vec::new();
        let mut units: Option<Vec<usize>> = None;
        for r in reports {
            let (ia, a) = psnr(r, &p.a)?;
            let (ib, b) = psnr(r, &p.b)?;
            if ia != ib || units.as_ref().is_some_and(|u| *u != ia) {
                return Err(Error::argument(format!(
                    "designs {} and {} are not scored on the same units in every report",
                    p.a, p.b
                )));
            }
            units = Some(ia);
            groups.push((a, b));
        }
        let (dm, cim) =
            pooled_paired_bootstrap(&groups, mean, first.config.bootstrap, first.config.seed)?;
        let (dy, ciy) =
            pooled_paired_bootstrap(&groups, y90, first.config.bootstrap, first.config.seed ^ 1)?;
        pairs.push(PooledPair {
            a: p.a.clone(),
            b: p.b.clone(),
            per_seed_mean_diff: groups.iter().map(|g| mean(&g.0) - mean(&g.1)).collect(),
            per_seed_yield90_diff: groups.iter().map(|g| y90(&g.0) - y90(&g.1)).collect(),
            psnr_mean_diff: dm,
            psnr_mean_diff_ci95: cim,
            psnr_yield90_diff: dy,
            psnr_yield90_diff_ci95: ciy,
        });
    }
    Ok(PooledReport {
        studies: reports.len(),
        trials: first.config.trials,
        bootstrap: first.config.bootstrap,
        pairs,
    })
}

/// Combines the reports of evaluation shards (the same designs, settings and images, disjoint
/// trial slices) into exactly the report of a single run, bootstrap intervals included.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] when the parts differ in settings, designs or images, overlap,
/// or leave trials out.
pub fn merge(parts: &[Report]) -> Result<Report> {
    let first = parts
        .first()
        .ok_or_else(|| Error::argument("merge needs at least one report"))?;
    let names: Vec<&str> = first.scores.iter().map(|s| s.name.as_str()).collect();
    let mut scores: Vec<DesignScores> = first
        .scores
        .iter()
        .map(|s| DesignScores {
            name: s.name.clone(),
            trials: Vec::new(),
            nominal: s.nominal.clone(),
        })
        .collect();
    for (k, p) in parts.iter().enumerate() {
        let pn: Vec<&str> = p.scores.iter().map(|s| s.name.as_str()).collect();
        if p.config != first.config || p.images != first.images || pn != names {
            return Err(Error::argument(format!(
                "part {k}: settings, images or designs differ from part 0"
            )));
        }
        for (dst, src) in scores.iter_mut().zip(&p.scores) {
            dst.trials.extend(src.trials.iter().cloned());
        }
    }
    for s in &mut scores {
        s.trials.sort_by_key(|t| t.index);
        let idx: Vec<usize> = s.trials.iter().map(|t| t.index).collect();
        if idx != (0..first.config.trials).collect::<Vec<_>>() {
            return Err(Error::argument(format!(
                "design {}: the parts hold {} trials, not each of 0..{} once",
                s.name,
                idx.len(),
                first.config.trials
            )));
        }
    }
    let pairs: Vec<(String, String)> = first
        .pairs
        .iter()
        .map(|p| (p.a.clone(), p.b.clone()))
        .collect();
    report(&first.config, &first.images, scores, &pairs)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(index: usize, psnr: f64) -> TrialScore {
        TrialScore {
            index,
            psnr,
            ssim: 0.5,
            rms_spot_um: 10.0,
            psf_similarity: 0.8,
        }
    }

    /// A report of designs "ta" and "conv" on `n` units, ta = conv + `shift(unit)`.
    fn study(n: usize, shift: impl Fn(usize) -> f64) -> Report {
        let cfg = EvalConfig {
            trials: n,
            bootstrap: 500,
            ..EvalConfig::default()
        };
        let conv: Vec<TrialScore> = (0..n).map(|i| score(i, 20.0 + (i % 7) as f64)).collect();
        let ta: Vec<TrialScore> = conv
            .iter()
            .map(|t| score(t.index, t.psnr + shift(t.index)))
            .collect();
        let d = |name: &str, trials: Vec<TrialScore>| DesignScores {
            name: name.into(),
            trials,
            nominal: score(0, 30.0),
        };
        report(
            &cfg,
            &["dead-leaves".into()],
            vec![d("ta", ta), d("conv", conv)],
            &[("ta".into(), "conv".into())],
        )
        .unwrap()
    }

    #[test]
    fn pooling_averages_the_seeds_and_resamples_seeds_and_units() {
        // Constant shifts per seed: every resample lies between the smallest and largest shift.
        let r = pool(&[study(40, |_| 0.5), study(40, |_| 0.1), study(40, |_| 0.3)]).unwrap();
        let p = &r.pairs[0];
        assert_eq!((r.studies, r.trials), (3, 40));
        assert!((p.psnr_mean_diff - 0.3).abs() < 1e-12);
        assert_eq!(p.per_seed_mean_diff.len(), 3);
        assert!((p.per_seed_mean_diff[0] - 0.5).abs() < 1e-12);
        assert!(p.psnr_mean_diff_ci95[0] >= 0.1 - 1e-12 && p.psnr_mean_diff_ci95[1] <= 0.5 + 1e-12);
        assert!(
            p.psnr_mean_diff_ci95[1] - p.psnr_mean_diff_ci95[0] > 0.05,
            "seeds resampled"
        );
        // One seed, unit-varying shifts: the pooled estimate is the single study's, and the
        // interval is as wide as the unit spread makes it.
        let noisy = study(60, |i| if i % 2 == 0 { 1.0 } else { -0.6 });
        let one = pool(std::slice::from_ref(&noisy)).unwrap();
        assert!((one.pairs[0].psnr_mean_diff - noisy.pairs[0].psnr_mean_diff).abs() < 1e-12);
        let ci = one.pairs[0].psnr_mean_diff_ci95;
        assert!(ci[0] < 0.2 && ci[1] > 0.2 && ci[1] - ci[0] > 0.2, "{ci:?}");
        // Same seed, same numbers.
        let again = pool(std::slice::from_ref(&noisy)).unwrap();
        assert_eq!(again.pairs[0].psnr_mean_diff_ci95, ci);
    }

    #[test]
    fn pooling_refuses_studies_on_different_units_or_settings() {
        let mut other = study(40, |_| 0.2);
        other.config.seed += 1;
        let e = pool(&[study(40, |_| 0.2), other]).unwrap_err();
        assert!(e.message().contains("report 1"), "{}", e.message());
        let mut shuffled = study(40, |_| 0.2);
        shuffled.scores[0].trials[0].index = 99;
        let e = pool(&[study(40, |_| 0.2), shuffled]).unwrap_err();
        assert!(e.message().contains("same units"), "{}", e.message());
        assert!(pool(&[]).is_err());
    }
}
