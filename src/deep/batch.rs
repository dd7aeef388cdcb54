//! An iteration's batch: its crops, tolerance patterns, rays and noise drawn, then rendered, decoded and differentiated.

use super::*;

/// One training crop of an iteration, everything drawn: its tile, tolerance pattern, rays,
/// sharp image (with the halo the blur needs) and noise. Replaying a batch with another lens or
/// decoder changes nothing else, so its loss is a deterministic function of the design (what the
/// gradient checks difference).
#[derive(Clone, Debug)]
pub struct BatchCrop {
    /// PSF tile (field of the grid).
    pub tile: usize,
    /// The crop's tolerance pattern (none in the nominal phase).
    pub pattern: Option<crate::tolerance::Perturbation>,
    /// Refocus bundles when the crop's unit is refocused (`compensate_focus` in a tolerance
    /// phase), launched from the design at the start of the iteration.
    pub refocus: Option<Arc<FocusObjective>>,
    /// Rays of its RGB PSF, launched from the design at the start of the iteration.
    pub rays: Bundles,
    /// Spot bundles at its field (likewise).
    pub spot: Bundles,
    /// Its diffraction PSFs, launched from the design likewise, when training uses them.
    pub diffraction: Option<Arc<DiffractionPsfs>>,
    /// Nominal-design PSFs (the similarity term's constant reference; tolerance phases only).
    pub ideal: Vec<Vec<f64>>,
    /// Sharp image with a halo of (ks - 1) / 2 pixels, 3 planes of (crop + ks - 1)².
    pub xpad: Vec<f32>,
    /// Standard normal samples of the noise of its capture, 3 planes of crop²
    /// ([`SensorNoise::apply`]).
    pub noise: Vec<f32>,
}

/// The crops of one iteration.
#[derive(Clone, Debug)]
pub struct Batch {
    /// Global iteration.
    pub iter: usize,
    /// The crops.
    pub crops: Vec<BatchCrop>,
    /// PSF settings (rays of this iteration).
    pub psf: PsfOptions,
    /// Trace options.
    pub trace: TraceOptions,
}

/// Draws the batch of global iteration `it` for `lens`: crop `j` at tile `j mod grid²`, its
/// pattern, training crop and noise from (seed, it · samples + j).
///
/// # Errors
/// Ray-generation errors; invalid patterns.
pub fn draw_batch(cfg: &DeepConfig, lens: &Lens, phase: Phase, it: usize) -> Result<Batch> {
    let o = &cfg.optics;
    let fields = grid_fields(lens, o.psf_grid);
    let trace = TraceOptions {
        apertures: o.apertures,
    };
    let psf = psf_options(
        lens,
        o.psf_ks,
        o.psf_spp,
        o.seed ^ (it as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    );
    let nominal = lens.compile();
    // One set of refocus bundles for the batch, shared by its refocused crops.
    let focus = if phase.samples_tolerances() && cfg.compensate_focus {
        Some(Arc::new(FocusObjective::new(lens, cfg.optics.apertures)?))
    } else {
        None
    };
    let (c, ks) = (cfg.crop_px, o.psf_ks);
    let side = c + ks - 1;
    let n = o.samples;
    let crops = (0..n)
        .into_par_iter()
        .map(|j| -> Result<BatchCrop> {
            let stream = (it * n + j) as u64;
            let tile = j % fields.len();
            let pattern = if phase.samples_tolerances() {
                Some(o.spec.sample(lens, o.seed, stream)?)
            } else {
                None
            };
            let refocus = if pattern.is_some() {
                focus.clone()
            } else {
                None
            };
            let pairs: Vec<(Field, f64)> = o
                .wavelengths_nm
                .iter()
                .map(|&w| (fields[tile], w))
                .collect();
            let rays = Bundles::pairs(lens, &pairs, &psf.pupil)?;
            let diffraction = match cfg.psf {
                PsfModel::Geometric => None,
                PsfModel::Diffraction => Some(Arc::new(DiffractionPsfs::new(
                    lens,
                    fields[tile],
                    &o.wavelengths_nm,
                    ks,
                    psf.pitch_mm,
                    trace,
                )?)),
            };
            let ideal = if phase.samples_tolerances() {
                crop_psfs(
                    &rays,
                    diffraction.as_deref(),
                    &nominal,
                    &|_, v| v,
                    &psf,
                    trace,
                )
            } else {
                Vec::new()
            };
            let spot = Bundles::new(
                lens,
                &[fields[tile]],
                &o.wavelengths_nm,
                &Pupil::grid((o.spot_grid / 2).max(2)),
            )?;
            let xpad = cfg.train_images.crop(side, o.seed, stream)?.data;
            let noise = standard_normals(3 * c * c, o.seed ^ 0x6e_6f69_7365, stream);
            Ok(BatchCrop {
                tile,
                pattern,
                refocus,
                rays,
                spot,
                diffraction,
                ideal,
                xpad,
                noise,
            })
        })
        .collect::<Result<_>>()?;
    Ok(Batch {
        iter: it,
        crops,
        psf,
        trace,
    })
}

/// What a batch evaluation gives.
#[derive(Clone, Debug)]
pub struct BatchEval {
    /// Total loss: mean image loss + the spot and similarity terms (batch means).
    pub loss: f64,
    /// Mean image loss.
    pub image_loss: f64,
    /// Batch PSNR, dB.
    pub psnr_db: f64,
    /// Mean spot distance, µm.
    pub spot_um: f64,
    /// Mean PSF similarity (tolerance phases).
    pub psf_similarity: Option<f64>,
    /// dL/dθ over the lens variables (empty unless asked).
    pub dlens: Vec<f64>,
    /// dL/dφ over the decoder parameters.
    pub ddecoder: Vec<f64>,
}

/// Evaluates the batch with `lens` and `decoder`: renders every crop through its own PSF (the
/// crop's pattern applied to `lens`, traced with the batch's rays), decodes, scores; with
/// `vars`, also the exact gradient with respect to those lens variables (dual numbers through
/// [`PatternObjective`]).
///
/// # Errors
/// A crop whose PSF receives no ray; decoder errors.
pub fn eval_batch(
    cfg: &DeepConfig,
    batch: &Batch,
    lens: &Lens,
    decoder: &Decoder,
    vars: Option<&[Param]>,
) -> Result<BatchEval> {
    let o = &cfg.optics;
    let (c, ks) = (cfg.crop_px, o.psf_ks);
    let n = batch.crops.len();
    let (psf, trace) = (batch.psf, batch.trace);
    // 1. Each crop's PSFs (values) and capture.
    let sensor = cfg.sensor();
    // Per crop: its capture, mean spot (mm), PSF similarity and the noise's dy/db.
    let rendered: Vec<(Crop, f64, f64, Option<Vec<f32>>)> = batch
        .crops
        .par_iter()
        .enumerate()
        .map(|(j, bc)| -> Result<_> {
            let (plens, adj) = crop_lens(lens, bc)?;
            let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
            let psfs: Vec<Vec<f64>> = crop_psfs(
                &bc.rays,
                bc.diffraction.as_deref(),
                &sys,
                &|_, v| v,
                &psf,
                trace,
            );
            for (k, p) in psfs.iter().enumerate() {
                crate::psf::check_landed(
                    p,
                    &format!(
                        "iteration {}, crop {j}, {} nm",
                        batch.iter, bc.rays.sets[k].wavelength_nm
                    ),
                )?;
            }
            let psf32: Vec<f32> = psfs.iter().flatten().map(|&v| v as f32).collect();
            let mut y = blur_patch(&bc.xpad, c, c, &psf32, ks)?;
            // dy/db of the noise, for the lens gradient (shot noise only: else 1).
            let slope = sensor.slope(&y, &bc.noise);
            sensor.apply(&mut y, &bc.noise);
            let x = crop_centre(&bc.xpad, c + ks - 1, (ks - 1) / 2, c);
            let spot_mm = spot_sum(&bc.spot, &sys, &|_, v| v, SpotMeasure::Mean, trace)
                / bc.spot.len().max(1) as f64;
            let sim = if bc.ideal.is_empty() {
                1.0
            } else {
                bc.ideal
                    .iter()
                    .zip(&psfs)
                    .map(|(i, p)| psf_similarity(i, p, ks))
                    .sum::<f64>()
                    / bc.ideal.len() as f64
            };
            let crop = Crop {
                tile: bc.tile,
                y,
                x,
                w: c,
                h: c,
            };
            Ok((crop, spot_mm, sim, slope))
        })
        .collect::<Result<_>>()?;
    let crops: Vec<Crop> = rendered.iter().map(|r| r.0.clone()).collect();
    // 2. The decoder, forward and backward.
    let out = decoder.train_batch(&crops, &cfg.loss)?;
    let inv = 1.0 / n as f64;
    let spot_mm: f64 = rendered.iter().map(|r| r.1).sum::<f64>() * inv;
    let sim: f64 = rendered.iter().map(|r| r.2).sum::<f64>() * inv;
    let tol = batch.crops.iter().any(|b| !b.ideal.is_empty());
    let loss = out.loss
        + cfg.lambda_spot * spot_mm
        + if tol {
            cfg.lambda_psf * (1.0 - sim)
        } else {
            0.0
        };
    // 3. The lens gradient: dL/dPSF of each crop, then Jᵀ dL/dPSF by dual numbers.
    let dlens = match vars {
        None => Vec::new(),
        Some(vars) => {
            let ks2 = ks * ks;
            let per: Vec<Vec<f64>> = batch
                .crops
                .par_iter()
                .zip(out.dy.par_iter())
                .zip(rendered.par_iter())
                .map(|((bc, dy), r)| -> Result<Vec<f64>> {
                    // Through the noise: dL/db = dL/dy · dy/db (shot noise scales with b).
                    let dy_clean: Vec<f32>;
                    let dy = match &r.3 {
                        None => dy,
                        Some(slope) => {
                            dy_clean = dy.iter().zip(slope).map(|(a, b)| a * b).collect();
                            &dy_clean
                        }
                    };
                    let g = blur_patch_psf_adjoint(&bc.xpad, c, c, ks, dy)?;
                    let obj = PatternObjective {
                        spot: bc.spot.clone(),
                        psf_rays: bc.rays.clone(),
                        diffraction: bc.diffraction.clone(),
                        psf,
                        similarity: !bc.ideal.is_empty(),
                        image_grad: g
                            .chunks(ks2)
                            .map(|ch| ch.iter().map(|&v| v as f64).collect())
                            .collect(),
                        weight: inv,
                        lambda_spot: cfg.lambda_spot,
                        lambda_psf: cfg.lambda_psf,
                        trace,
                    };
                    let (plens, adj) = crop_lens(lens, bc)?;
                    let (Some(pattern), Some(focus)) = (&bc.pattern, &bc.refocus) else {
                        return Ok(gradient::<_, GRAD_WIDTH>(&obj, &plens, &adj, vars)?.1);
                    };
                    // The refocus δ moves the unit's sensor along z (patterns do not tilt the
                    // image plane), as the unit's last gap does: ∂L/∂δ is the derivative in that
                    // gap with the design (launch, reference PSFs) held.
                    let last = Param::Gap(plens.surfaces.len() - 1);
                    let g = gradient_with_unit::<_, GRAD_WIDTH>(&obj, &plens, &adj, vars, last)?.1;
                    let dl_ddelta = g[vars.len()];
                    let (ul, ua) = unit_lens(lens, pattern, None)?;
                    let dd = gradient::<_, GRAD_WIDTH>(focus.as_ref(), &ul, &ua, vars)?.1;
                    Ok((0..vars.len()).map(|k| g[k] + dl_ddelta * dd[k]).collect())
                })
                .collect::<Result<_>>()?;
            let mut g = vec![0.0; vars.len()];
            for gj in &per {
                for (a, b) in g.iter_mut().zip(gj) {
                    *a += b;
                }
            }
            g
        }
    };
    Ok(BatchEval {
        loss,
        image_loss: out.loss,
        psnr_db: out.psnr_db,
        spot_um: spot_mm * 1e3,
        psf_similarity: tol.then_some(sim),
        dlens,
        ddecoder: out.dparams,
    })
}

/// The centre `c x c` block (offset `off`) of a 3-plane square image of side `side`.
pub(super) fn crop_centre(xpad: &[f32], side: usize, off: usize, c: usize) -> Vec<f32> {
    let mut x = Vec::with_capacity(3 * c * c);
    for ch in 0..3 {
        for r in 0..c {
            let s = ch * side * side + (r + off) * side + off;
            x.extend_from_slice(&xpad[s..s + c]);
        }
    }
    x
}
