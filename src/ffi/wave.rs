//! Wave optics through the C ABI: wavefront statistics and Zernike coefficients, the OPD map,
//! diffraction PSFs and MTFs.

use super::geometric::tolray_field;
use super::handles::{check_wavelength, tolray_system};
use super::{boundary, c_slice, nonnull, tolray_status, FfiError, FfiResult};
use crate::trace::TraceOptions;
use crate::wave::{self, mtf, psf, PupilCoords, Reference, Sampling, WaveOptions};

/// Settings of [`tolray_wavefront`], checked (`TOLRAY_ERROR_ARGUMENT`): `rings` and `spokes` at
/// least 1 with at most 4194304 rays in all, `zernike_terms` 1 to 231, `reference` and
/// `zernike_pupil` 0 or 1.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct tolray_wave_options {
    /// Radial Gauss nodes of the pupil quadrature (16 by default).
    pub rings: u32,
    /// Angular nodes of the pupil quadrature (48 by default).
    pub spokes: u32,
    /// Zernike Standard (Noll) terms to fit (37 by default).
    pub zernike_terms: u32,
    /// `TOLRAY_REFERENCE_CHIEF` or `TOLRAY_REFERENCE_CENTROID`: the reference sphere's centre.
    pub reference: u32,
    /// `TOLRAY_ZERNIKE_ENTRANCE` or `TOLRAY_ZERNIKE_EXIT`: the pupil coordinates of the fit.
    pub zernike_pupil: u32,
    /// Nonzero: aim rays at the real stop.
    pub aim: u32,
    /// Nonzero: apertures clip.
    pub apertures: u32,
}

/// The reference sphere is centred on the chief ray's image point (OpticStudio's default).
pub const TOLRAY_REFERENCE_CHIEF: u32 = 0;
/// The reference sphere is centred on the centroid of the rays' image points.
pub const TOLRAY_REFERENCE_CENTROID: u32 = 1;
/// Zernike terms fitted over the normalised entrance pupil (the launch points; optiland's).
pub const TOLRAY_ZERNIKE_ENTRANCE: u32 = 0;
/// Zernike terms fitted over the normalised exit pupil (points on the reference sphere;
/// OpticStudio's).
pub const TOLRAY_ZERNIKE_EXIT: u32 = 1;

/// Wavefront error of one field and wavelength, in waves of that wavelength.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct tolray_wavefront_stats {
    /// RMS OPD with piston removed, waves.
    pub rms_to_chief_waves: f64,
    /// RMS OPD with piston and tilt removed, waves.
    pub rms_to_centroid_waves: f64,
    /// Peak to valley, waves.
    pub pv_to_chief_waves: f64,
    /// Peak to valley with tilt removed, waves.
    pub pv_to_centroid_waves: f64,
    /// Maréchal's Strehl estimate exp(-(2 pi rms_to_centroid)^2).
    pub strehl_marechal: f64,
    /// RMS of the OPD minus the Zernike Standard fit, waves.
    pub zernike_residual_waves: f64,
    /// Radius of the reference sphere, mm.
    pub reference_radius_mm: f64,
    /// Rays launched (the quadrature's points).
    pub n_launched: u64,
    /// Rays that reached the reference sphere.
    pub n_rays: u64,
}

fn wave_options(o: &tolray_wave_options) -> FfiResult<(WaveOptions, usize, PupilCoords)> {
    let sampling = Sampling::Quadrature {
        rings: o.rings as usize,
        spokes: o.spokes as usize,
    };
    sampling.check()?;
    let terms = o.zernike_terms as usize;
    wave::zernike::check_terms(wave::zernike::Ordering::Standard, terms)?;
    let reference = match o.reference {
        TOLRAY_REFERENCE_CHIEF => Reference::Chief,
        TOLRAY_REFERENCE_CENTROID => Reference::Centroid,
        r => return Err(FfiError::argument(format!("reference {r}: give 0 or 1"))),
    };
    let coords = match o.zernike_pupil {
        TOLRAY_ZERNIKE_ENTRANCE => PupilCoords::Entrance,
        TOLRAY_ZERNIKE_EXIT => PupilCoords::Exit,
        r => {
            return Err(FfiError::argument(format!(
                "zernike_pupil {r}: give 0 or 1"
            )))
        }
    };
    Ok((
        WaveOptions {
            sampling,
            reference,
            zernike_pupil: coords,
            aim: o.aim != 0,
            trace: TraceOptions {
                apertures: o.apertures != 0,
            },
        },
        terms,
        coords,
    ))
}

/// The default wavefront settings: a 16 x 48 quadrature, 37 terms, chief-ray reference,
/// entrance-pupil Zernikes, no aiming, apertures clip.
///
/// # Safety
/// `out` points to a writable `tolray_wave_options`.
#[no_mangle]
pub unsafe extern "C" fn tolray_wave_options_default(
    out: *mut tolray_wave_options,
) -> tolray_status {
    boundary("tolray_wave_options_default", || {
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        let v = tolray_wave_options {
            rings: 16,
            spokes: 48,
            zernike_terms: 37,
            reference: TOLRAY_REFERENCE_CHIEF,
            zernike_pupil: TOLRAY_ZERNIKE_ENTRANCE,
            aim: 0,
            apertures: 1,
        };
        // SAFETY: checked non-NULL.
        unsafe { *out = v };
        Ok(())
    })
}

/// Wavefront error of one field at one wavelength (finite, 100 nm to 10 mm): the OPD of each
/// ray against the reference sphere (centred on the chief ray's image point, or the centroid,
/// through the paraxial exit pupil's centre at the primary wavelength; OpticStudio's
/// convention), integrated over the pupil quadrature of `opts`, in `*out`; and the Zernike
/// Standard (Noll, orthonormal over the unit disk) coefficients Z1..Z`opts->zernike_terms` in
/// waves in `zernike_out` (`zernike_len` must equal `opts->zernike_terms`,
/// `TOLRAY_ERROR_BUFFER_SIZE`; NULL with `zernike_len` 0 skips them). Rays are launched as
/// "Ray bundles" at the top of tolray.h says and traced through `system`.
/// `TOLRAY_ERROR_ARGUMENT` for an afocal lens or bad options; `TOLRAY_ERROR_NUMERICAL` when the
/// chief ray misses the image (a field beyond the lens' reach) or fewer than 3 rays get
/// through.
///
/// # Safety
/// Pointers valid as named; `zernike_out` holds `zernike_len` writable doubles.
#[no_mangle]
pub unsafe extern "C" fn tolray_wavefront(
    system: *const tolray_system,
    field: *const tolray_field,
    wavelength_nm: f64,
    opts: *const tolray_wave_options,
    out: *mut tolray_wavefront_stats,
    zernike_out: *mut f64,
    zernike_len: usize,
) -> tolray_status {
    boundary("tolray_wavefront", || {
        // SAFETY: NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: as above.
        let field = unsafe { nonnull(field, "field") }?.to_field()?;
        // SAFETY: as above.
        let (o, terms, coords) = wave_options(unsafe { nonnull(opts, "opts") }?)?;
        check_wavelength(wavelength_nm, &s.lens)?;
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        if !(zernike_len == 0 && zernike_out.is_null()) {
            if zernike_out.is_null() {
                return Err(FfiError::null("zernike_out"));
            }
            if zernike_len != terms {
                return Err(FfiError::size(format!(
                    "zernike_len is {zernike_len}; opts->zernike_terms is {terms}"
                )));
            }
        }
        let w = wave::wavefront(&s.nominal, &s.sys, field, wavelength_nm, &o)?;
        let st = w.stats_in(terms, coords)?;
        let v = tolray_wavefront_stats {
            rms_to_chief_waves: st.rms_to_chief_waves,
            rms_to_centroid_waves: st.rms_to_centroid_waves,
            pv_to_chief_waves: st.pv_to_chief_waves,
            pv_to_centroid_waves: st.pv_to_centroid_waves,
            strehl_marechal: st.strehl_marechal,
            zernike_residual_waves: st.zernike_standard.residual_rms,
            reference_radius_mm: w.radius_mm,
            n_launched: w.n_launched as u64,
            n_rays: w.opd_waves.len() as u64,
        };
        let z = &st.zernike_standard.coefficients;
        // SAFETY: `out` checked non-NULL; `zernike_out` holds `zernike_len` == z.len() doubles
        // when not NULL.
        unsafe {
            *out = v;
            if !zernike_out.is_null() {
                std::ptr::copy_nonoverlapping(z.as_ptr(), zernike_out, z.len());
            }
        }
        Ok(())
    })
}

/// Largest side of an OPD map, FFT PSF grid or Huygens image (8192: a 8192^2 double array is
/// 512 MiB).
pub const TOLRAY_WAVE_MAX_SIDE: u32 = 8192;

fn side(n: u32, what: &str, min: u32) -> FfiResult<usize> {
    if n < min || n > TOLRAY_WAVE_MAX_SIDE {
        return Err(FfiError::argument(format!(
            "{what} {n}: give {min} to {TOLRAY_WAVE_MAX_SIDE}"
        )));
    }
    Ok(n as usize)
}

/// The OPD map of one field at one wavelength on an `n` x `n` cell-centred grid over the
/// normalised entrance pupil (`n` 2 to 2048), in waves with the chief ray's reference sphere,
/// row-major with row 0 at +y (pupil y = 1) and column 0 at -x: `opd_out[r n + c]`.
/// `valid_out[r n + c]` is 1 where a ray got through and 0 elsewhere (outside the pupil,
/// vignetted), where `opd_out` holds 0. Both arrays hold `out_len` = n^2 elements
/// (`TOLRAY_ERROR_BUFFER_SIZE` otherwise). Errors as [`tolray_wavefront`].
///
/// # Safety
/// Pointers valid as named; `opd_out` and `valid_out` hold `out_len` writable elements.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn tolray_opd_map(
    system: *const tolray_system,
    field: *const tolray_field,
    wavelength_nm: f64,
    n: u32,
    aim: u32,
    apertures: u32,
    opd_out: *mut f64,
    valid_out: *mut u8,
    out_len: usize,
) -> tolray_status {
    boundary("tolray_opd_map", || {
        // SAFETY: NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: as above.
        let field = unsafe { nonnull(field, "field") }?.to_field()?;
        check_wavelength(wavelength_nm, &s.lens)?;
        if !(2..=2048).contains(&n) {
            return Err(FfiError::argument(format!(
                "OPD map side {n}: give 2 to 2048"
            )));
        }
        let n = n as usize;
        if opd_out.is_null() {
            return Err(FfiError::null("opd_out"));
        }
        if valid_out.is_null() {
            return Err(FfiError::null("valid_out"));
        }
        if out_len != n * n {
            return Err(FfiError::size(format!(
                "out_len is {out_len}; a {n} x {n} map needs {}",
                n * n
            )));
        }
        let o = WaveOptions {
            sampling: Sampling::Grid(n),
            aim: aim != 0,
            trace: TraceOptions {
                apertures: apertures != 0,
            },
            ..WaveOptions::default()
        };
        let w = wave::wavefront(&s.nominal, &s.sys, field, wavelength_nm, &o)?;
        let mut opd = vec![0.0; n * n];
        let mut valid = vec![0u8; n * n];
        let cell = |x: f64| (((x + 1.0) * 0.5 * n as f64).floor() as usize).min(n - 1);
        for (p, &v) in w.pupil.iter().zip(&w.opd_waves) {
            let k = (n - 1 - cell(p[1])) * n + cell(p[0]);
            opd[k] = v;
            valid[k] = 1;
        }
        // SAFETY: both checked non-NULL, each holding `out_len` == n² elements.
        unsafe {
            std::ptr::copy_nonoverlapping(opd.as_ptr(), opd_out, opd.len());
            std::ptr::copy_nonoverlapping(valid.as_ptr(), valid_out, valid.len());
        }
        Ok(())
    })
}

/// FFT diffraction PSF: the pupil function on a `pupil_samples` grid zero-padded to `grid`.
pub const TOLRAY_DIFFRACTION_FFT: u32 = 0;
/// Huygens diffraction PSF: the direct sum of wavelets from the reference sphere.
pub const TOLRAY_DIFFRACTION_HUYGENS: u32 = 1;

/// Settings of [`tolray_diffraction_psf`] and [`tolray_mtf`], checked
/// (`TOLRAY_ERROR_ARGUMENT`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct tolray_diffraction_options {
    /// `TOLRAY_DIFFRACTION_FFT` or `TOLRAY_DIFFRACTION_HUYGENS` (the PSF); for the MTF,
    /// `TOLRAY_MTF_FFT` or `TOLRAY_MTF_DIRECT`.
    pub method: u32,
    /// Pupil samples across the diameter, 4 or more, at most 4194304 rays in the disk (64 by
    /// default); a grid whose OPD steps by
    /// more than half a wave between neighbouring samples is refused
    /// (`TOLRAY_ERROR_NUMERICAL`, the message says how many samples would do).
    pub pupil_samples: u32,
    /// FFT: the transformed array's side, at least 2 `pupil_samples`, at most 8192 (256);
    /// Huygens: image points per side, 1 to 2048.
    pub grid: u32,
    /// Huygens: the image pixel pitch, micrometres, finite and positive (ignored by the FFT,
    /// whose pitch is lambda N_w / (grid / pupil_samples)).
    pub pitch_um: f64,
    /// Nonzero: aim rays at the real stop.
    pub aim: u32,
    /// Nonzero: apertures clip.
    pub apertures: u32,
}

/// The diffraction PSF of one field at one wavelength, relative to the peak of the unaberrated
/// PSF of the same pupil (so the peak is the Strehl ratio), row-major with row 0 at +y, centred
/// on the chief ray's image point: `grid` x `grid` values in `out` (`out_len` must be
/// `grid`^2, `TOLRAY_ERROR_BUFFER_SIZE`). `*strehl_out` gets the Strehl ratio (the peak found
/// between pixels) and `pitch_um_out[0..2]` the pixel pitch along x and y in micrometres
/// (the FFT's pixels are rectangular off axis). Errors as [`tolray_wavefront`], and
/// `TOLRAY_ERROR_NUMERICAL` for an undersampled pupil.
///
/// # Safety
/// Pointers valid as named; `out` holds `out_len` writable doubles, `pitch_um_out` two.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn tolray_diffraction_psf(
    system: *const tolray_system,
    field: *const tolray_field,
    wavelength_nm: f64,
    opts: *const tolray_diffraction_options,
    out: *mut f64,
    out_len: usize,
    strehl_out: *mut f64,
    pitch_um_out: *mut f64,
) -> tolray_status {
    boundary("tolray_diffraction_psf", || {
        // SAFETY: NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: as above.
        let field = unsafe { nonnull(field, "field") }?.to_field()?;
        // SAFETY: as above.
        let o = *unsafe { nonnull(opts, "opts") }?;
        check_wavelength(wavelength_nm, &s.lens)?;
        for (p, what) in [
            (out.is_null(), "out"),
            (strehl_out.is_null(), "strehl_out"),
            (pitch_um_out.is_null(), "pitch_um_out"),
        ] {
            if p {
                return Err(FfiError::null(what));
            }
        }
        let trace = TraceOptions {
            apertures: o.apertures != 0,
        };
        let samples = side(o.pupil_samples, "pupil_samples", 4)?;
        let p = match o.method {
            TOLRAY_DIFFRACTION_FFT => {
                let grid = side(o.grid, "grid", 8)?;
                let f = psf::FftOptions {
                    pupil_samples: samples,
                    grid,
                };
                f.check()?;
                check_len(out_len, grid)?;
                let wo = WaveOptions {
                    sampling: Sampling::Grid(samples),
                    aim: o.aim != 0,
                    trace,
                    ..WaveOptions::default()
                };
                let w = wave::wavefront(&s.nominal, &s.sys, field, wavelength_nm, &wo)?;
                psf::fft_psf(&w, &f)?
            }
            TOLRAY_DIFFRACTION_HUYGENS => {
                let m = side(o.grid, "grid", 1)?;
                check_len(out_len, m)?;
                let wo = WaveOptions {
                    sampling: Sampling::Grid(samples),
                    aim: o.aim != 0,
                    trace,
                    ..WaveOptions::default()
                };
                let w = wave::wavefront(&s.nominal, &s.sys, field, wavelength_nm, &wo)?;
                psf::huygens_psf(
                    &w,
                    &psf::HuygensOptions {
                        image_samples: o.grid as usize,
                        pitch_um: o.pitch_um,
                    },
                )?
            }
            m => {
                return Err(FfiError::argument(format!(
                    "method {m}: give 0 (FFT) or 1 (Huygens)"
                )))
            }
        };
        if p.values.len() != out_len {
            return Err(FfiError::size(format!(
                "out_len is {out_len}; the PSF has {} values",
                p.values.len()
            )));
        }
        // SAFETY: all checked non-NULL; `out` holds `out_len` == values.len() doubles,
        // `pitch_um_out` two.
        unsafe {
            std::ptr::copy_nonoverlapping(p.values.as_ptr(), out, out_len);
            *strehl_out = p.strehl;
            *pitch_um_out = p.pitch_um[0];
            *pitch_um_out.add(1) = p.pitch_um[1];
        }
        Ok(())
    })
}

fn check_len(out_len: usize, side: usize) -> FfiResult<()> {
    if out_len != side * side {
        return Err(FfiError::size(format!(
            "out_len is {out_len}; a {side} x {side} PSF needs {}",
            side * side
        )));
    }
    Ok(())
}

/// Diffraction MTF as the FFT of the FFT PSF (`pupil_samples`, `grid`).
pub const TOLRAY_MTF_FFT: u32 = 0;
/// Diffraction MTF as the pupil's autocorrelation evaluated directly from exactly traced,
/// sheared pupils (`pupil_samples` grid; `grid` ignored): no FFT grid, nothing aliases.
pub const TOLRAY_MTF_DIRECT: u32 = 1;

/// The diffraction MTF of one field at one wavelength at `n_freqs` frequencies (cycles/mm,
/// finite, 0 or more, below the cutoff: `TOLRAY_ERROR_ARGUMENT` names it), tangential (along
/// the field's direction in the image plane; y on axis) in `tangential_out` and sagittal in
/// `sagittal_out`, 1 at zero frequency; the diffraction limit of the same pupil (tangential) in
/// `limit_out` (may be NULL). Each output holds `n_freqs` doubles. `opts->method` is
/// `TOLRAY_MTF_FFT` or `TOLRAY_MTF_DIRECT`. Errors as [`tolray_diffraction_psf`].
///
/// # Safety
/// Pointers valid as named; `freqs_lpmm` holds `n_freqs` doubles, each output `n_freqs`
/// writable doubles.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn tolray_mtf(
    system: *const tolray_system,
    field: *const tolray_field,
    wavelength_nm: f64,
    opts: *const tolray_diffraction_options,
    freqs_lpmm: *const f64,
    n_freqs: usize,
    tangential_out: *mut f64,
    sagittal_out: *mut f64,
    limit_out: *mut f64,
) -> tolray_status {
    boundary("tolray_mtf", || {
        // SAFETY: NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let s = unsafe { nonnull(system, "system") }?;
        // SAFETY: as above.
        let field = unsafe { nonnull(field, "field") }?.to_field()?;
        // SAFETY: as above.
        let o = *unsafe { nonnull(opts, "opts") }?;
        check_wavelength(wavelength_nm, &s.lens)?;
        if n_freqs == 0 {
            return Err(FfiError::size("n_freqs is 0: give at least one frequency"));
        }
        // SAFETY: caller's promise of `n_freqs` readable doubles.
        let freqs = unsafe { c_slice(freqs_lpmm, n_freqs, "freqs_lpmm") }?.to_vec();
        if tangential_out.is_null() {
            return Err(FfiError::null("tangential_out"));
        }
        if sagittal_out.is_null() {
            return Err(FfiError::null("sagittal_out"));
        }
        let samples = side(o.pupil_samples, "pupil_samples", 4)?;
        let wo = WaveOptions {
            sampling: Sampling::Grid(samples),
            aim: o.aim != 0,
            trace: TraceOptions {
                apertures: o.apertures != 0,
            },
            ..WaveOptions::default()
        };
        let m = match o.method {
            TOLRAY_MTF_FFT => {
                let f = psf::FftOptions {
                    pupil_samples: samples,
                    grid: side(o.grid, "grid", 8)?,
                };
                f.check()?;
                let w = wave::wavefront(&s.nominal, &s.sys, field, wavelength_nm, &wo)?;
                mtf::fft_mtf(&w, &f, &freqs)?
            }
            TOLRAY_MTF_DIRECT => {
                mtf::direct_mtf(&s.nominal, &s.sys, field, wavelength_nm, &wo, &freqs)?
            }
            m => {
                return Err(FfiError::argument(format!(
                    "method {m}: give 0 (FFT) or 1 (direct)"
                )))
            }
        };
        // SAFETY: outputs checked non-NULL (limit_out may be NULL: skipped), each holding
        // `n_freqs` == m.*.len() doubles.
        unsafe {
            std::ptr::copy_nonoverlapping(m.tangential.as_ptr(), tangential_out, n_freqs);
            std::ptr::copy_nonoverlapping(m.sagittal.as_ptr(), sagittal_out, n_freqs);
            if !limit_out.is_null() {
                std::ptr::copy_nonoverlapping(m.diffraction_limit.as_ptr(), limit_out, n_freqs);
            }
        }
        Ok(())
    })
}
