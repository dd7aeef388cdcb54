//! Opaque handles: lens, tolerance spec, tolerance pattern, and the traced system.

use super::{boundary, c_str, copy_text, nonnull, tolray_status, FfiError, FfiResult};
use crate::lens::{self, Adjustments, Lens, Param, System};
use crate::tolerance::{Perturbation, ToleranceSpec};
use std::ffi::c_char;

/// A lens prescription (immutable; shareable between threads).
pub struct tolray_lens {
    pub(crate) lens: Lens,
}

/// A tolerance spec: operands, ranges and distributions (immutable; shareable).
pub struct tolray_spec {
    pub(crate) spec: ToleranceSpec,
}

/// A tolerance pattern: the perturbation values of one fabricated lens (immutable; shareable).
pub struct tolray_pattern {
    pub(crate) pattern: Perturbation,
}

/// A lens as traced: a nominal lens compiled with a tolerance pattern applied (or none). Rays are
/// aimed at the nominal lens' entrance pupil, as a fabricated lens is used ("Ray bundles" at the
/// top of tolray.h). Immutable; shareable.
pub struct tolray_system {
    /// The nominal lens (ray generation, ideal PSFs).
    pub(crate) nominal: Lens,
    /// The lens with the pattern's material changes.
    pub(crate) lens: Lens,
    /// The pattern's geometric adjustments.
    pub(crate) adj: Adjustments,
    /// The compiled table.
    pub(crate) sys: System<f64>,
}

/// A design variable of a lens, for gradients and [`tolray_lens_with_param`]. Checked against the
/// lens (`TOLRAY_ERROR_ARGUMENT`): `kind` 0 to 8; `surface` below the number of surfaces; `term`
/// 0 to 7 for `TOLRAY_PARAM_ASPHERE`, below the surface's number of Zernike terms for
/// `TOLRAY_PARAM_ZERNIKE` or of phase terms for `TOLRAY_PARAM_PHASE`, 0 to 9 for
/// `TOLRAY_PARAM_GRADIENT` (ignored by the other kinds); for the glass kinds, the medium after
/// the surface must be a model glass ("n_d/V_d" in the lens JSON), for
/// `TOLRAY_PARAM_GRADIENT` a gradient-index medium.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct tolray_param {
    /// One of the `TOLRAY_PARAM_*` values.
    pub kind: u32,
    /// Surface index, from 0 (for glass variables: the surface the glass follows).
    pub surface: u32,
    /// Asphere term index for `TOLRAY_PARAM_ASPHERE`: 0 is the r^2 coefficient, up to 7 (r^16)
    /// (on an odd asphere 0 is r^1; on a toroid, y^2); for `TOLRAY_PARAM_ZERNIKE`, 0 is Z1; for
    /// `TOLRAY_PARAM_PHASE`, 0 is A_1 (on rho^2); for `TOLRAY_PARAM_GRADIENT`, 0 is n0, 1 to 6
    /// the r^2 to r^12 terms, 7 to 9 the z to z^3 terms.
    pub term: u32,
}

/// Curvature c of a surface, 1/mm (the radius is 1/c; 0 is flat).
pub const TOLRAY_PARAM_CURVATURE: u32 = 0;
/// Conic constant of a surface.
pub const TOLRAY_PARAM_CONIC: u32 = 1;
/// Polynomial sag coefficient `term` (0..7) of a surface: r^2..r^16 on an even asphere
/// (mm^(1-2(term+1))), r^1..r^8 on an odd asphere, y^2..y^16 on a toroid's profile.
pub const TOLRAY_PARAM_ASPHERE: u32 = 2;
/// Gap after a surface (thickness or air space), mm. Changing it moves every later surface and
/// the image plane; the last surface's gap is its distance to the image plane.
pub const TOLRAY_PARAM_GAP: u32 = 3;
/// n_d (the index at 587.5618 nm) of the model glass after a surface. A model glass' index is
/// n = A + B / lambda^2, fitted to n_d and V_d.
pub const TOLRAY_PARAM_GLASS_ND: u32 = 4;
/// V_d (the Abbe number) of the model glass after a surface.
pub const TOLRAY_PARAM_GLASS_VD: u32 = 5;
/// Zernike coefficient `term` (0 is Z1) of a Zernike sag surface (OpticStudio FZERNSAG,
/// SZERNSAG), mm.
pub const TOLRAY_PARAM_ZERNIKE: u32 = 6;
/// Diffractive phase coefficient `term` (0 is A_1, on rho^2) of a surface's radial phase
/// (OpticStudio's Binary 2), radians.
pub const TOLRAY_PARAM_PHASE: u32 = 7;
/// Coefficient `term` of the gradient-index medium after a surface (OpticStudio's Gradient 1
/// to 3): 0 is n0, 1 to 6 the terms on r^2 .. r^12, 7 to 9 those on z .. z^3 (mm-based units).
pub const TOLRAY_PARAM_GRADIENT: u32 = 8;

impl tolray_param {
    pub(crate) fn to_param(self) -> FfiResult<Param> {
        let s = self.surface as usize;
        Ok(match self.kind {
            TOLRAY_PARAM_CURVATURE => Param::Curvature(s),
            TOLRAY_PARAM_CONIC => Param::Conic(s),
            TOLRAY_PARAM_ASPHERE => Param::Asphere(s, self.term as usize),
            TOLRAY_PARAM_GAP => Param::Gap(s),
            TOLRAY_PARAM_GLASS_ND => Param::GlassNd(s),
            TOLRAY_PARAM_GLASS_VD => Param::GlassVd(s),
            TOLRAY_PARAM_ZERNIKE => Param::Zernike(s, self.term as usize),
            TOLRAY_PARAM_PHASE => Param::Phase(s, self.term as usize),
            TOLRAY_PARAM_GRADIENT => Param::Gradient(s, self.term as usize),
            k => {
                return Err(FfiError::argument(format!(
                    "unknown parameter kind {k} (expected 0 to 8, TOLRAY_PARAM_*)"
                )))
            }
        })
    }
}

/// First-order properties of a lens at one wavelength; lengths in mm, axial positions are
/// global z (first vertex at 0, light toward +z). An afocal lens (`afocal` = 1) has no focal
/// length: its `efl_mm`, `bfd_mm`, `fnum` and `half_fov_deg` are 0 and `angular_magnification`
/// is set; `image_distance_mm` and `working_fnum` are 0 when the image is at infinity
/// (`image_at_infinity` = 1).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct tolray_paraxial {
    /// Wavelength of the analysis, nm.
    pub wavelength_nm: f64,
    /// Effective focal length 1/Φ, mm: OpticStudio's "Effective Focal Length (in air)" (0
    /// when `afocal`).
    pub efl_mm: f64,
    /// Effective focal length in image space n'/Φ, mm: OpticStudio's "Effective Focal Length
    /// (in image space)", n' signed as OpticStudio signs it (negative after an odd number of
    /// mirrors; 1.333 `efl_mm` for an image in water), 0 when `afocal` (ABI version 3).
    pub efl_image_space_mm: f64,
    /// Back focal distance (last vertex to the infinity focus), mm (0 when `afocal`).
    pub bfd_mm: f64,
    /// Last vertex to the paraxial image of the stated object, mm (0 when
    /// `image_at_infinity`).
    pub image_distance_mm: f64,
    /// Axial position of the entrance pupil, mm.
    pub entrance_pupil_z_mm: f64,
    /// Entrance pupil diameter, mm.
    pub entrance_pupil_diameter_mm: f64,
    /// Axial position of the exit pupil, mm.
    pub exit_pupil_z_mm: f64,
    /// Exit pupil diameter, mm.
    pub exit_pupil_diameter_mm: f64,
    /// F-number for an object at infinity, EFL / EPD (0 when `afocal`).
    pub fnum: f64,
    /// Working F-number for the stated object, 1 / (2 |u'|) of the paraxial marginal ray (0
    /// when `image_at_infinity`).
    pub working_fnum: f64,
    /// Lateral magnification for the stated object (0 at infinity).
    pub magnification: f64,
    /// Half field of view from the sensor's half-diagonal, atan(r_sensor / EFL), degrees (0
    /// when `afocal`).
    pub half_fov_deg: f64,
    /// Optical power 1 / EFL, 1/mm (0 for an afocal lens).
    pub power_per_mm: f64,
    /// Angular magnification u' / u of an afocal lens (0 for a lens with a focal length).
    pub angular_magnification: f64,
    /// Total track: first vertex to the image plane, mm.
    pub total_track_mm: f64,
    /// Index of the aperture-stop surface: the marked one, else the surface that limits the axial
    /// beam.
    pub stop_surface: u32,
    /// Number of surfaces of the lens (the image plane not counted).
    pub num_surfaces: u32,
    /// 1 for an afocal lens (no focal length), else 0.
    pub afocal: u32,
    /// 1 when the paraxial image of the stated object is at infinity, else 0.
    pub image_at_infinity: u32,
}

/// Boxes `value` and writes the new handle to `*out`.
///
/// # Safety
/// `out` is NULL (refused) or points to writable storage for a pointer.
unsafe fn give<T>(out: *mut *mut T, value: T) -> FfiResult<()> {
    if out.is_null() {
        return Err(FfiError::null("out"));
    }
    // SAFETY: `out` is non-NULL and points to a writable pointer (caller's promise).
    unsafe { *out = Box::into_raw(Box::new(value)) };
    Ok(())
}

unsafe fn free<T>(p: *mut T) {
    if !p.is_null() {
        // SAFETY: `p` came from `give` (Box::into_raw) and is freed once (caller's promise).
        drop(unsafe { Box::from_raw(p) });
    }
}

fn parse_json<T: serde::de::DeserializeOwned>(text: &str, what: &str) -> FfiResult<T> {
    serde_json::from_str(text).map_err(|e| {
        FfiError::new(
            tolray_status::TOLRAY_ERROR_PARSE,
            format!("{what} JSON: line {}, column {}: {e}", e.line(), e.column()),
        )
    })
}

/// Loads a lens from a built-in name (`lens1`, `lens2`, `cooke-triplet`, in any case; tried
/// first) or a file path: a Zemax OpticStudio .zmx file by its extension (in any case), otherwise
/// lens JSON (the format at the top of tolray.h). `*out` receives a new handle to free with
/// [`tolray_lens_free`]. A path that does not exist gives `TOLRAY_ERROR_IO`; a JSON file's
/// errors are those of [`tolray_lens_from_json`].
///
/// # Safety
/// `name_or_path` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_load(
    name_or_path: *const c_char,
    out: *mut *mut tolray_lens,
) -> tolray_status {
    boundary("tolray_lens_load", || {
        // SAFETY: `name_or_path` is NULL or a C string, as # Safety says; NULL is refused.
        let name = unsafe { c_str(name_or_path, "name_or_path") }?;
        let lens = Lens::load(name)?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_lens { lens }) }
    })
}

/// Parses a lens from DeepLens JSON text (the format at the top of tolray.h); `*out` receives a
/// new handle. `TOLRAY_ERROR_PARSE` for malformed JSON or a value of the wrong JSON type,
/// `TOLRAY_ERROR_INVALID_INPUT` for a missing key, an unknown surface type or glass, an object
/// distance of 0, non-square pixels or a lens beyond the limits listed there.
///
/// # Safety
/// `json` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_from_json(
    json: *const c_char,
    out: *mut *mut tolray_lens,
) -> tolray_status {
    boundary("tolray_lens_from_json", || {
        // SAFETY: `json` is NULL or a C string, as # Safety says; NULL is refused.
        let text = unsafe { c_str(json, "json") }?;
        let lens = lens::json::from_str(text)?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_lens { lens }) }
    })
}

/// Writes the lens as DeepLens JSON (the format at the top of tolray.h; it reads back to the
/// same lens) into `buf` (`cap` bytes, NUL-terminated) and its length without the NUL into
/// `*len_out`. Call with `buf` NULL and `cap` 0 to learn the length; a `cap`
/// smaller than length + 1 gives `TOLRAY_ERROR_BUFFER_SIZE` and writes nothing.
///
/// # Safety
/// `lens` is a live handle; `buf` has `cap` writable bytes or is NULL with `cap` 0; `len_out`
/// points to a writable `size_t`.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_to_json(
    lens: *const tolray_lens,
    buf: *mut c_char,
    cap: usize,
    len_out: *mut usize,
) -> tolray_status {
    boundary("tolray_lens_to_json", || {
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let lens = unsafe { nonnull(lens, "lens") }?;
        // SAFETY: `buf` and `cap`, `len_out` are as # Safety says (copy_text checks NULL).
        unsafe { copy_text(&lens::json::to_string(&lens.lens), buf, cap, len_out) }
    })
}

/// Frees a lens handle; NULL is ignored.
///
/// # Safety
/// `lens` is NULL or a handle not yet freed.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_free(lens: *mut tolray_lens) {
    // SAFETY: `lens` is NULL or a handle of this library not yet freed, as # Safety says.
    unsafe { free(lens) }
}

/// Paraxial (first-order) data of the lens at `wavelength_nm` (finite, 100 nm to 10 mm).
/// `TOLRAY_ERROR_INVALID_INPUT` when a medium's index at that wavelength is not between 0.9 and 5;
/// `TOLRAY_ERROR_NUMERICAL` for a lens whose entrance pupil is at infinity or whose first-order
/// numbers are not finite. An afocal lens is an answer (`afocal` = 1), not an error.
///
/// # Safety
/// `lens` is a live handle; `out` points to a writable `tolray_paraxial`.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_paraxial(
    lens: *const tolray_lens,
    wavelength_nm: f64,
    out: *mut tolray_paraxial,
) -> tolray_status {
    boundary("tolray_lens_paraxial", || {
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let lens = unsafe { nonnull(lens, "lens") }?;
        check_wavelength(wavelength_nm, &lens.lens)?;
        if out.is_null() {
            return Err(FfiError::null("out"));
        }
        let p = lens.lens.paraxial(wavelength_nm)?;
        let value = tolray_paraxial {
            wavelength_nm: p.wavelength_nm,
            efl_mm: p.efl_mm.unwrap_or(0.0),
            efl_image_space_mm: p.efl_image_space_mm.unwrap_or(0.0),
            bfd_mm: p.bfd_mm.unwrap_or(0.0),
            image_distance_mm: p.image_distance_mm.unwrap_or(0.0),
            entrance_pupil_z_mm: p.entrance_pupil_z_mm,
            entrance_pupil_diameter_mm: p.entrance_pupil_diameter_mm,
            exit_pupil_z_mm: p.exit_pupil_z_mm,
            exit_pupil_diameter_mm: p.exit_pupil_diameter_mm,
            fnum: p.fnum.unwrap_or(0.0),
            working_fnum: p.working_fnum.unwrap_or(0.0),
            magnification: p.magnification,
            half_fov_deg: p.half_fov_deg.unwrap_or(0.0),
            power_per_mm: p.power_per_mm,
            angular_magnification: p.angular_magnification.unwrap_or(0.0),
            total_track_mm: p.total_track_mm,
            stop_surface: p.stop_surface as u32,
            num_surfaces: lens.lens.surfaces.len() as u32,
            afocal: u32::from(p.is_afocal()),
            image_at_infinity: u32::from(p.image_distance_mm.is_none()),
        };
        // SAFETY: checked non-NULL; the caller promises it is writable.
        unsafe { *out = value };
        Ok(())
    })
}

/// The current value of a design variable of the lens (`param` checked as [`tolray_param`]
/// says).
///
/// # Safety
/// `lens` and `param` are valid pointers; `value_out` points to a writable `double`.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_param_get(
    lens: *const tolray_lens,
    param: *const tolray_param,
    value_out: *mut f64,
) -> tolray_status {
    boundary("tolray_lens_param_get", || {
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let lens = unsafe { nonnull(lens, "lens") }?;
        // SAFETY: `param` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let p = unsafe { nonnull(param, "param") }?.to_param()?;
        if value_out.is_null() {
            return Err(FfiError::null("value_out"));
        }
        let v = crate::optim::param_value(&lens.lens, p)?;
        // SAFETY: checked non-NULL.
        unsafe { *value_out = v };
        Ok(())
    })
}

/// A new lens equal to `lens` with one design variable set to `value` (lenses are immutable;
/// this is how an optimizer steps). `param` is checked as [`tolray_param`] says and `value` must
/// be finite (`TOLRAY_ERROR_ARGUMENT`). The new lens is validated as a lens read from JSON
/// (`TOLRAY_ERROR_INVALID_INPUT`): |c| at most 1000 1/mm and 0 on an aperture surface, which
/// also takes no asphere terms; |k| at most 1e6; gaps 0 to 1e6 mm; the clear semi-aperture r
/// inside the conic's rim, (1 + k) c^2 r^2 at most 1; a model glass' n_d at least 1 and V_d above
/// 0; every medium's index between 0.9 and 5 at the primary wavelength.
///
/// # Safety
/// `lens` and `param` are valid pointers; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_lens_with_param(
    lens: *const tolray_lens,
    param: *const tolray_param,
    value: f64,
    out: *mut *mut tolray_lens,
) -> tolray_status {
    boundary("tolray_lens_with_param", || {
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let lens = unsafe { nonnull(lens, "lens") }?;
        // SAFETY: `param` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let p = unsafe { nonnull(param, "param") }?.to_param()?;
        if !value.is_finite() {
            return Err(FfiError::argument(format!(
                "{p:?}: value {value} is not finite"
            )));
        }
        let mut new = lens.lens.clone();
        crate::optim::set_param(&mut new, p, value)?;
        new.validate()?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_lens { lens: new }) }
    })
}

/// The default tolerance spec: the paper's Table A1 (element decenter ±0.04 mm, tilt ±0.05°,
/// axial shift ±0.04 mm, surface curvature ±0.3 %; normal with sigma = max / 3, clamped).
///
/// # Safety
/// `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_spec_default(out: *mut *mut tolray_spec) -> tolray_status {
    boundary("tolray_spec_default", || {
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe {
            give(
                out,
                tolray_spec {
                    spec: ToleranceSpec::default(),
                },
            )
        }
    })
}

/// Reads a tolerance spec file (JSON, the format of `tolray tolerance --spec`, described at the
/// top of tolray.h). A file that cannot be read gives `TOLRAY_ERROR_IO`; other errors are those
/// of [`tolray_spec_from_json`].
///
/// # Safety
/// `path` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_spec_load(
    path: *const c_char,
    out: *mut *mut tolray_spec,
) -> tolray_status {
    boundary("tolray_spec_load", || {
        // SAFETY: `path` is NULL or a C string, as # Safety says; NULL is refused.
        let path = unsafe { c_str(path, "path") }?;
        let spec = ToleranceSpec::read(std::path::Path::new(path))?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_spec { spec }) }
    })
}

/// Parses a tolerance spec from JSON text (the format at the top of tolray.h).
/// `TOLRAY_ERROR_PARSE` for malformed JSON, an unknown key, operand type or distribution, or a
/// `max` that is negative or not finite. Indices are checked later, by [`tolray_pattern_sample`].
///
/// # Safety
/// `json` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_spec_from_json(
    json: *const c_char,
    out: *mut *mut tolray_spec,
) -> tolray_status {
    boundary("tolray_spec_from_json", || {
        // SAFETY: `json` is NULL or a C string, as # Safety says; NULL is refused.
        let text = unsafe { c_str(json, "json") }?;
        let spec = parse_json(text, "tolerance spec")?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_spec { spec }) }
    })
}

/// Frees a spec handle; NULL is ignored.
///
/// # Safety
/// `spec` is NULL or a handle not yet freed.
#[no_mangle]
pub unsafe extern "C" fn tolray_spec_free(spec: *mut tolray_spec) {
    // SAFETY: `spec` is NULL or a handle of this library not yet freed, as # Safety says.
    unsafe { free(spec) }
}

/// Samples tolerance pattern `index` of `seed` for `lens`: the same pattern on every machine and
/// thread count (ChaCha8 seeded with `seed`, stream `index`), identical to the CLI's trial `index`.
/// Values are drawn operand by operand in spec order, then target by target in index order,
/// then axis x, y, z. `TOLRAY_ERROR_INVALID_INPUT` when an operand names an element or surface
/// the lens does not have, or an element operand lists surfaces (or a surface operand elements).
///
/// # Safety
/// `spec` and `lens` are live handles; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_pattern_sample(
    spec: *const tolray_spec,
    lens: *const tolray_lens,
    seed: u64,
    index: u64,
    out: *mut *mut tolray_pattern,
) -> tolray_status {
    boundary("tolray_pattern_sample", || {
        // SAFETY: `spec` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let spec = unsafe { nonnull(spec, "spec") }?;
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let lens = unsafe { nonnull(lens, "lens") }?;
        let pattern = spec.spec.sample(&lens.lens, seed, index)?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_pattern { pattern }) }
    })
}

/// Reads a tolerance pattern file (JSON, the format of `--perturb`, described at the top of
/// tolray.h). A file that cannot be read gives `TOLRAY_ERROR_IO`; other errors are those of
/// [`tolray_pattern_from_json`].
///
/// # Safety
/// `path` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_pattern_load(
    path: *const c_char,
    out: *mut *mut tolray_pattern,
) -> tolray_status {
    boundary("tolray_pattern_load", || {
        // SAFETY: `path` is NULL or a C string, as # Safety says; NULL is refused.
        let path = unsafe { c_str(path, "path") }?;
        let pattern = Perturbation::read(std::path::Path::new(path))?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_pattern { pattern }) }
    })
}

/// Parses a tolerance pattern from JSON text (the format at the top of tolray.h).
/// `TOLRAY_ERROR_PARSE` for malformed JSON, an unknown key or a value of the wrong type. The
/// pattern is checked against a lens by [`tolray_system_new`].
///
/// # Safety
/// `json` is a NUL-terminated string; `out` points to writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_pattern_from_json(
    json: *const c_char,
    out: *mut *mut tolray_pattern,
) -> tolray_status {
    boundary("tolray_pattern_from_json", || {
        // SAFETY: `json` is NULL or a C string, as # Safety says; NULL is refused.
        let text = unsafe { c_str(json, "json") }?;
        let pattern = parse_json(text, "tolerance pattern")?;
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe { give(out, tolray_pattern { pattern }) }
    })
}

/// Writes the pattern as JSON; the buffer protocol of [`tolray_lens_to_json`].
///
/// # Safety
/// As [`tolray_lens_to_json`].
#[no_mangle]
pub unsafe extern "C" fn tolray_pattern_to_json(
    pattern: *const tolray_pattern,
    buf: *mut c_char,
    cap: usize,
    len_out: *mut usize,
) -> tolray_status {
    boundary("tolray_pattern_to_json", || {
        // SAFETY: `pattern` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let p = unsafe { nonnull(pattern, "pattern") }?;
        // SAFETY: `buf` and `cap`, `len_out` are as # Safety says (copy_text checks NULL).
        unsafe { copy_text(&p.pattern.to_json(), buf, cap, len_out) }
    })
}

/// Frees a pattern handle; NULL is ignored.
///
/// # Safety
/// `pattern` is NULL or a handle not yet freed.
#[no_mangle]
pub unsafe extern "C" fn tolray_pattern_free(pattern: *mut tolray_pattern) {
    // SAFETY: `pattern` is NULL or a handle of this library not yet freed, as # Safety says.
    unsafe { free(pattern) }
}

/// Compiles `lens` for tracing with the tolerance pattern `pattern` applied, or nominal when
/// `pattern` is NULL. The lens handle is not changed and may be freed afterwards.
/// `TOLRAY_ERROR_INVALID_INPUT` when the pattern does not fit the lens: an element or surface
/// index out of range, a value that is not finite, an index error that takes n_d below 1 or an
/// Abbe-number error that makes V_d 0 or less.
///
/// # Safety
/// `lens` is a live handle; `pattern` is NULL or a live handle; `out` points to writable
/// storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn tolray_system_new(
    lens: *const tolray_lens,
    pattern: *const tolray_pattern,
    out: *mut *mut tolray_system,
) -> tolray_status {
    boundary("tolray_system_new", || {
        // SAFETY: `lens` is NULL or readable, as # Safety says; `nonnull` refuses NULL.
        let nominal = unsafe { nonnull(lens, "lens") }?.lens.clone();
        // SAFETY: NULL is allowed (nominal); otherwise a live handle (caller's promise).
        let pattern = unsafe { pattern.as_ref() };
        let (lens, adj) = match pattern {
            Some(p) => p.pattern.apply(&nominal)?,
            None => (nominal.clone(), Adjustments::none(nominal.surfaces.len())),
        };
        let sys = System::compile(&lens, &adj, &|_, v| v);
        // SAFETY: `out` is NULL or writable, as # Safety says; `give` refuses NULL.
        unsafe {
            give(
                out,
                tolray_system {
                    nominal,
                    lens,
                    adj,
                    sys,
                },
            )
        }
    })
}

/// Frees a system handle; NULL is ignored.
///
/// # Safety
/// `system` is NULL or a handle not yet freed.
#[no_mangle]
pub unsafe extern "C" fn tolray_system_free(system: *mut tolray_system) {
    // SAFETY: `system` is NULL or a handle of this library not yet freed, as # Safety says.
    unsafe { free(system) }
}

/// Checks a wavelength in nm (see [`crate::lens::material::check_wavelength_nm`]) and, beyond
/// 20 µm, that every medium of `lens` is defined there ([`Lens::check_indices`]).
pub(crate) fn check_wavelength(wl: f64, lens: &Lens) -> FfiResult<()> {
    crate::lens::material::check_wavelength_nm(wl)?;
    if wl > crate::lens::material::DEFINED_MEDIA_BEYOND_NM {
        lens.check_indices(wl)?;
    }
    Ok(())
}
