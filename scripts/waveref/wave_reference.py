#!/usr/bin/env python3
"""Reference wave-optics numbers (OPD, Zernike, FFT PSF Strehl, MTF) from optiland 0.6.3.

Versions: optiland 0.6.3, numpy 2.4.6, scipy 1.17.1, matplotlib 3.11.2, Python 3.11 (the environment of
scripts/requirements.txt). Generated once, 2026-11-28, for the tolray project; the Rust tests read the
output and never run this.

Usage (from the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/waveref/wave_reference.py
writes tests/data/wave/optiland_wave.json (about 30 seconds on 2 cores).

Lenses are read as scripts/zmxref/gen_reference.py reads them (its `load_optic`: optiland's Zemax
reader with that script's glass patches: exact glass names in GCAT order, ___BLANK model glasses
under tolray's dispersion law, FLOA semi-diameter fix), so the glasses are the ones tolray uses.
Three adaptations, recorded per lens in the JSON (`adaptations`):
  * optiland 0.6.3 reads only the first number of an old-style `WAVL a b c` line (and so loses
    PWAV 2): lens2.zmx is read from a copy in /tmp with `WAVL`/`WWGT` rewritten as the equivalent
    `WAVM k value weight` lines (same values, nothing else changed);
  * a file whose only field is the axis (the Thorlabs achromat and asphere) gets one added field
    (optiland `fields.add`) at a nominal half-field, so that optiland's normalised field is
    defined; the off-axis case is then at 0.7 of that nominal value;
  * vignetting factors (VCX/VCY, which optiland applies in its ray aimer) are set to 0 on every
    field: pupil coordinates here are always the full paraxial entrance pupil.
Physical apertures (FLAP/CLAP/... as optiland's reader builds them) are KEPT: a point whose ray is
clipped has optiland intensity 0 and is flagged `vignetted`; its OPD is still the one of the ray
traced on past the aperture (optiland clips by zeroing intensity, the geometry goes on).

CONVENTIONS (all read from optiland 0.6.3's source in site-packages/optiland):
  Frame: optiland's global frame, mm. z = optical axis; the first surface after the object is at
  z = `paraxial.first_surface_z_global_mm` (0 here). Field y > 0: for angles, a ray slope +tan(theta) in y (image
  at +y for a positive lens); for object heights, object at +y (image at -y).
  Fields: normalised Hy = value / optiland max field (the largest radial field of the optic).
  Pupil: normalised ENTRANCE-pupil coordinates (Px, Py): optiland's paraxial ray aimer
  (rays/ray_aiming/paraxial.py, the default "paraxial" mode) aims every ray at the point
  (Px EPD/2, Py EPD/2, z_EP) of the paraxial entrance pupil plane. Infinite object: all rays of a
  field are parallel, direction (tan tx, tan ty, 1)/norm, launched on a plane z = z_EP - d
  (fields/field_types/angle.py get_ray_origins). Finite object: rays start at the object point
  (for an angle field at a finite object, the object point is y = -tan(theta) * (z_EP - z_obj)).
  OPD (wavefront/strategy.py ChiefRayStrategy.compute_wavefront_data, reference_geometry.py):
    - the chief ray (Px = Py = 0) is traced to the image surface; its intersection C (global)
      is the reference-sphere centre;
    - radius R = |C - XP| with XP = optic.paraxial.exit_pupil_point_gcs() = the PARAXIAL exit
      pupil's axial point (image vertex + XPL along the axis, XPL at the primary wavelength); so
      the sphere passes through the paraxial exit-pupil centre, not through a real pupil point;
    - each ray's OPL is optiland's accumulated rays.opd from its launch point to the image surface
      (n * geometric length per medium), minus n_image * t, where t > 0 is the distance back
      along the ray from its image-surface point to the sphere (the larger root when the smaller
      is negative); n_image is evaluated at the PRIMARY wavelength (air here: 1);
    - infinite object with an angle field: + n_object * u.(r_launch - r_launch_chief) is added
      (strategy.py _restore_launch_phase), i.e. OPL counted from the plane wavefront through the
      chief ray's launch point; finite object: OPL counted from the object point;
    - OPD_waves = (OPL_chief - OPL_ray) / lambda (chief minus ray: positive where the ray's
      optical path to the reference sphere is shorter than the chief ray's), lambda in mm =
      wavelength_um * 1e-3. The chief ray's OPD is 0 by construction; NO piston removal, NO tilt
      removal (remove_tilt=False). With this sign an image plane BEYOND the focus gives a
      POSITIVE Zernike Z4 (checked in `sanity.defocus`: +0.05 mm at f/5 gives Z4 = +0.1308 waves,
      closed form |W020|/(2 sqrt 3) = 0.1312).
  Summary statistics over the quadrature points (computed here, numpy), weights w renormalised
  over the points used:
    mean = sum w W; rms_to_chief = sqrt(sum w (W - mean)^2) (piston removed, as OpticStudio's
    "RMS to chief"); rms_to_centroid = RMS of the residual after weighted least squares removal
    of {1, Px, Py}; pv_to_chief = max W - min W; zernike_standard: 37 Noll terms (orthonormal),
    zernike_fringe: 37 Fringe terms (unnormalised), both by weighted least squares on the points.
    `summary` uses the unvignetted points only; `summary_all_points` (only when a point is
    vignetted) uses every point with its OPD as traced past the aperture.
  Zernike definitions (own code, `zernike_noll` / `zernike_fringe` below):
    R_n^m(rho) = sum_k (-1)^k (n-k)! / (k! ((n+m)/2-k)! ((n-m)/2-k)!) rho^(n-2k), m = |m|;
    Noll j: n rows in order; within a row |m| ascending; m = 0 takes one j, |m| > 0 takes two,
      the EVEN j of the pair is cos(m theta), the ODD j sin(m theta);
      Z_j = sqrt(n+1) R_n^0 (m = 0), sqrt(2(n+1)) R_n^m cos|sin (m > 0); theta = atan2(Py, Px).
    Fringe j = 1..36: groups d = (n+|m|)/2 = 0,1,2,...; within a group |m| descending from d to
      0, n = 2d - |m|; |m| > 0 gives cos then sin; Z37 = R_12^0 (University of Arizona / Zemax);
      no normalisation (Z4 = 2 rho^2 - 1, Z9 = 6 rho^4 - 6 rho^2 + 1).
    Checked against optiland's ZernikeNoll / ZernikeFringe / ZernikeStandard at random points
    (`header.zernike_check`).
  optiland's own numbers (`optiland`): see the header strings written below (`optiland_notes`).

Quadrature: rho_i = sqrt(x_i), x_i the 12 Gauss-Legendre nodes mapped to [0, 1] (weights w_i/2,
sum 1); theta_j = 2 pi (j + 0.5) / 36, j = 0..35; point weight w_i / 36; order i outer, j inner.
Exact for the area measure (1/pi) dA on the unit disk for polynomials of degree <= 23 in rho^2
times trigonometric order <= 35.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import platform
import re
import sys
import tempfile
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "scripts", "zmxref"))
import gen_reference as g  # noqa: E402
from scan_zmx import scan  # noqa: E402

import optiland  # noqa: E402
import optiland.backend as be  # noqa: E402
from optiland.distribution import BaseDistribution  # noqa: E402
from optiland.mtf import FFTMTF, SampledMTF  # noqa: E402
from optiland.psf import FFTPSF  # noqa: E402
from optiland.utils import get_working_FNO  # noqa: E402
from optiland.wavefront import OPD, Wavefront, ZernikeOPD  # noqa: E402
from optiland.zernike import ZernikeFringe, ZernikeNoll, ZernikeStandard  # noqa: E402

be.set_backend("numpy")
try:
    be.set_precision("float64")
except Exception:
    pass

OUT = os.path.join(ROOT, "tests", "data", "wave", "optiland_wave.json")
DATE = "2026-11-28"

# ------------------------------------------------------------------------------------------------
# Cases. field: "file_07" = the file's own field nearest 0.7 x its largest field when within 5 %
# of it, else 0.7 x largest; "nominal" = the file has only the axis: a field at `nominal` degrees
# is added and the case is 0.7 x nominal.
LENSES = [
    {"id": "lens1", "path": "tests/data/zemax/lens1.zmx",
     "what": "tolray built-in Lens1 typed as .zmx (DeepLens camera lens, finite object 1000 mm)"},
    {"id": "lens2", "path": "tests/data/zemax/lens2.zmx", "extra_wavelength_um": 0.4861327,
     "what": "tolray built-in Lens2 typed as .zmx (old WAVL/XFLD/YFLD syntax, FNUM aperture, "
             "object at 2000 mm)"},
    {"id": "cooke-triplet", "path": "tests/data/zemax/cooke-triplet.zmx",
     "what": "tolray built-in Cooke triplet typed as .zmx (stop on a curved surface)"},
    {"id": "double-gauss-US583336", "path": "tests/data/zemax/real/rayoptics/US00583336-2-scaled.zmx",
     "what": "double Gauss from US patent 583336 example 2 (ray-optics test file), f/4.5, "
             "24 deg half-field, FLAP apertures, file vignetting factors set to 0"},
    {"id": "achromat-AC254-100-A",
     "path": "tests/data/zemax/real/dcclab_raytracing/AC254-100-A-Zemax(ZMX).zmx",
     "nominal_field_deg": 2.0,
     "what": "Thorlabs AC254-100-A cemented achromat (DCC-Lab copy), infinite object; the file "
             "has only the axis: a 2 deg field is added, the off-axis case is 1.4 deg"},
    {"id": "asphere-AL1815-C", "path": "tests/data/zemax/real/optiland/lens_thorlabs_iso_8859_1.zmx",
     "nominal_field_deg": 1.0,
     "what": "Thorlabs AL1815-C even asphere (S-LAH64, NA 0.534) at 780 nm, infinite object; the "
             "file has only the axis: a 1 deg field is added, the off-axis case is 0.7 deg"},
]

MTF_FREQS = [10.0, 20.0, 40.0, 80.0]
CUTOFF_FRACS = [0.25, 0.5, 0.75]
ZERNIKE_RINGS = 30          # ZernikeOPD hexapolar rings (1 + 3*30*31 = 2791 points)
OPD_RINGS = 15              # OPD(...) default hexapolar rings (721 points)
PSF_RAYS, PSF_GRID = 128, 256
SMTF_RAYS = 128             # SampledMTF uniform grid per axis (its default)


def fl(x):
    return float(np.asarray(be.to_numpy(x), dtype=float).ravel()[0])


def arr(x):
    return np.asarray(be.to_numpy(x), dtype=float)


def lst(a):
    return [None if not math.isfinite(float(v)) else float(v) for v in np.asarray(a, float).ravel()]


# ------------------------------------------------------------------------------------------------
# Quadrature
def quadrature():
    xg, wg = np.polynomial.legendre.leggauss(12)
    x = (xg + 1.0) / 2.0
    w = wg / 2.0
    th = 2.0 * np.pi * (np.arange(36) + 0.5) / 36.0
    rho = np.sqrt(x)
    R, T = np.meshgrid(rho, th, indexing="ij")
    W = np.repeat(w / 36.0, 36)
    return (R * np.cos(T)).ravel(), (R * np.sin(T)).ravel(), W


class PointsDistribution(BaseDistribution):
    """optiland distribution holding given normalised entrance-pupil points."""

    def __init__(self, x, y):
        super().__init__()
        self.x = be.array(np.asarray(x, float))
        self.y = be.array(np.asarray(y, float))

    def generate_points(self, num_points=None):
        pass


# ------------------------------------------------------------------------------------------------
# Own Zernike code
def radial(n, m, r):
    m = abs(m)
    out = np.zeros_like(r, dtype=float)
    for k in range((n - m) // 2 + 1):
        c = (-1) ** k * math.factorial(n - k) / (
            math.factorial(k) * math.factorial((n + m) // 2 - k) * math.factorial((n - m) // 2 - k))
        out = out + c * r ** (n - 2 * k)
    return out


def noll_indices(nterms):
    """[(n, m)] for Noll j = 1..nterms; m > 0 cos, m < 0 sin."""
    out, j, n = [], 1, 0
    while len(out) < nterms:
        for ma in range(n % 2, n + 1, 2):
            if ma == 0:
                out.append((n, 0))
                j += 1
            else:
                pair = [j, j + 1]
                for jj in pair:
                    out.append((n, ma if jj % 2 == 0 else -ma))
                j += 2
        n += 1
    return out[:nterms]


def fringe_indices(nterms=37):
    out, d = [], 0
    while len(out) < 36:
        for ma in range(d, -1, -1):
            n = 2 * d - ma
            if ma == 0:
                out.append((n, 0))
            else:
                out.append((n, ma))
                out.append((n, -ma))
        d += 1
    out = out[:36] + [(12, 0)]
    return out[:nterms]


def zterm(n, m, r, t, normalised):
    R = radial(n, m, r)
    az = np.cos(m * t) if m > 0 else (np.sin(-m * t) if m < 0 else 1.0)
    if normalised:
        c = math.sqrt(n + 1) if m == 0 else math.sqrt(2 * (n + 1))
    else:
        c = 1.0
    return c * R * az


def zernike_noll(px, py, nterms=37):
    r, t = np.hypot(px, py), np.arctan2(py, px)
    return np.stack([zterm(n, m, r, t, True) for n, m in noll_indices(nterms)], axis=1)


def zernike_fringe(px, py, nterms=37):
    r, t = np.hypot(px, py), np.arctan2(py, px)
    return np.stack([zterm(n, m, r, t, False) for n, m in fringe_indices(nterms)], axis=1)


def wls(A, y, w):
    s = np.sqrt(w)
    c, *_ = np.linalg.lstsq(A * s[:, None], y * s, rcond=None)
    return c


def summary(px, py, w, W):
    w = w / w.sum()
    mean = float(np.sum(w * W))
    rms_chief = float(np.sqrt(np.sum(w * (W - mean) ** 2)))
    A = np.stack([np.ones_like(px), px, py], axis=1)
    c = wls(A, W, w)
    res = W - A @ c
    rms_cent = float(np.sqrt(np.sum(w * res ** 2)))
    zs = wls(zernike_noll(px, py), W, w)
    zf = wls(zernike_fringe(px, py), W, w)
    return {"n_points": int(W.size), "weight_sum_before_renormalising": None,
            "mean_waves": mean, "rms_to_chief_waves": rms_chief,
            "rms_to_centroid_waves": rms_cent, "pv_to_chief_waves": float(W.max() - W.min()),
            "tilt_fit_waves": [float(v) for v in c],
            "marechal_strehl_from_rms_to_centroid": float(math.exp(-(2 * math.pi * rms_cent) ** 2)),
            "zernike_standard_noll_waves": [float(v) for v in zs],
            "zernike_fringe_waves": [float(v) for v in zf]}


def zernike_check():
    """Evaluate own and optiland's bases at random points; return max differences + mapping."""
    rng = np.random.default_rng(1)
    r = np.sqrt(rng.uniform(0, 1, 50))
    t = rng.uniform(-np.pi, np.pi, 50)
    px, py = r * np.cos(t), r * np.sin(t)
    out = {}
    on = ZernikeNoll(be.ones([37]))
    A_opt = np.stack([arr(v) for v in on.terms(be.array(r), be.array(t))], axis=1)
    out["noll_vs_optiland_ZernikeNoll_max_abs_diff"] = float(np.max(np.abs(A_opt - zernike_noll(px, py))))
    ofr = ZernikeFringe(be.ones([37]))
    F_opt = np.stack([arr(v) for v in ofr.terms(be.array(r), be.array(t))], axis=1)
    F_own = zernike_fringe(px, py)
    d = np.max(np.abs(F_opt - F_own), axis=0)
    out["fringe_vs_optiland_ZernikeFringe_max_abs_diff_terms_1_36"] = float(d[:36].max())
    out["fringe_vs_optiland_ZernikeFringe_max_abs_diff_term_37"] = float(d[36])
    out["optiland_fringe_term_37_nm"] = [int(v) for v in ofr.indices[36]]
    # optiland "standard" = OSA/ANSI (0-based j = (n(n+2)+m)/2): map to Noll.
    st = ZernikeStandard(be.ones([45]))
    S_opt = np.stack([arr(v) for v in st.terms(be.array(r), be.array(t))], axis=1)
    N_own = zernike_noll(px, py)
    mapping = []
    for j in range(37):
        dd = np.max(np.abs(S_opt - N_own[:, [j]]), axis=0)
        k = int(np.argmin(dd))
        mapping.append({"noll_j": j + 1, "optiland_standard_index0": k, "n_m": list(noll_indices(37)[j]),
                        "max_abs_diff": float(dd[k])})
    out["noll_to_optiland_standard"] = mapping
    return out


# ------------------------------------------------------------------------------------------------
def rewrite_wavl(path):
    """Copy with `WAVL a b c` / `WWGT ...` as WAVM lines (optiland reads only WAVL's first value)."""
    lines = open(path, encoding="utf-8", errors="replace").read().splitlines()
    wl, ww = None, None
    for ln in lines:
        t = ln.split()
        if t and t[0] == "WAVL":
            wl = [float(v) for v in t[1:]]
        if t and t[0] == "WWGT":
            ww = [float(v) for v in t[1:]]
    if wl is None:
        return path, None
    ww = ww or [1.0] * len(wl)
    out = []
    for ln in lines:
        t = ln.split()
        if t and t[0] == "WAVL":
            out += [f"WAVM {k + 1} {v!r} {ww[k]!r}" for k, v in enumerate(wl)]
        elif t and t[0] == "WWGT":
            continue
        else:
            out.append(ln)
    d = tempfile.mkdtemp(prefix="waveref-")
    p = os.path.join(d, os.path.basename(path))
    with open(p, "w") as fh:
        fh.write("\n".join(out) + "\n")
    return p, f"WAVL {wl} / WWGT {ww} rewritten as WAVM 1..{len(wl)} lines (copy in /tmp)"


def load(lens):
    path = os.path.join(ROOT, lens["path"])
    adapt = []
    feat = scan(path)
    rpath, note = rewrite_wavl(path)
    if note:
        adapt.append(note)
    op, patches, model, _ = g.load_optic(rpath, scan(rpath))
    for f in op.fields.fields:
        if getattr(f, "vx", 0.0) or getattr(f, "vy", 0.0):
            adapt.append(f"field y={f.y!r}: vignetting factors vx={f.vx!r}, vy={f.vy!r} set to 0")
        f.vx = 0.0
        f.vy = 0.0
    return op, patches, adapt, feat


def choose_field(op, lens, adapt):
    ys = [float(abs(f.y)) for f in op.fields.fields] + [float(abs(f.x)) for f in op.fields.fields]
    vmax = max(ys)
    if vmax == 0.0:
        nom = lens["nominal_field_deg"]
        op.fields.add(y=nom)
        adapt.append(f"the file has only the axis: field y={nom!r} added (fields.add) as nominal "
                     f"largest field; off-axis case at 0.7 x {nom!r}")
        return round(0.7 * nom, 12), "0.7 x nominal (file has only the axis)"
    target = 0.7 * vmax
    cand = [float(f.y) for f in op.fields.fields if f.y != 0]
    best = min(cand, key=lambda v: abs(v - target))
    if abs(best - target) <= 0.05 * target:
        return best, f"file field nearest 0.7 x largest ({vmax!r}); 0.7 x largest = {target!r}"
    return target, f"0.7 x largest file field {vmax!r}"


def paraxial_numbers(op, wl):
    p = op.paraxial
    ya, ua = p.marginal_ray()
    n_img = fl(op.image_surface.material_post.n(wl))
    xp = [fl(v) for v in p.exit_pupil_point_gcs()]
    out = {
        "efl_mm": fl(p.f2()),
        "fno_paraxial": fl(p.FNO()),
        "fno_definition": "optiland Paraxial.FNO(): aperture.direct_fno() if the aperture is an "
                          "F/# (FNUM) else f2/EPD (image-space F/# for an object at infinity)",
        "paraxial_working_fno": 1.0 / (2.0 * n_img * abs(float(np.ravel(arr(ua))[-1]))),
        "paraxial_working_fno_definition": "1 / (2 n' |u'|), u' = paraxial marginal-ray slope at "
                                           "the image (optiland marginal_ray, primary wavelength)",
        "epd_mm": fl(p.EPD()),
        "ep_z_rel_first_surface_mm": fl(p.EPL()),
        "ep_z_global_mm": fl(p.entrance_pupil_axial_position()),
        "xp_z_rel_image_mm": fl(p.XPL()),
        "xpd_mm": fl(p.XPD()),
        "xp_point_global_mm": xp,
        "image_surface_z_global_mm": fl(op.image_surface.geometry.cs.z),
        "first_surface_z_global_mm": fl(op.surfaces[1].geometry.cs.z),
        "object_infinite": bool(op.object_surface.is_infinite),
        "n_image": n_img,
        "wavelength_um": wl,
    }
    if not op.object_surface.is_infinite:
        out["object_z_global_mm"] = fl(op.object_surface.geometry.cs.z)
        out["magnification"] = fl(p.magnification())
    return out


def interp_or_none(freqs, vals, f):
    freqs = arr(freqs)
    vals = arr(vals)
    if f > freqs[-1]:
        return None
    return float(np.interp(f, freqs, vals))


def run_case(op, field_value, field_kind, Hy, wl, qx, qy, qw):
    t0 = time.time()
    field = (0.0, float(Hy))
    case = {"field": {"kind": field_kind, "x": 0.0, "y": field_value},
            "optiland_normalised_field": [0.0, float(Hy)], "wavelength_um": wl,
            "wavelength_nm": round(wl * 1000.0, 9)}
    # 1. OPD on the quadrature
    wf = Wavefront(op, fields=[field], wavelengths=[wl], distribution=PointsDistribution(qx, qy),
                   strategy="chief_ray", remove_tilt=False)
    d = wf.get_data(field, wl)
    opd = arr(d.opd)
    inten = arr(d.intensity)
    xi = arr(op.surfaces.x[-1])
    failed = ~np.isfinite(xi)
    vig = (inten <= 0) | failed
    chief = op.trace_generic(0.0, float(Hy), 0.0, 0.0, wl)
    case.update({
        "px": [float(v) for v in qx], "py": [float(v) for v in qy], "weight": [float(v) for v in qw],
        "opd_waves": [float(v) for v in opd], "vignetted": [bool(v) for v in vig],
        "n_vignetted": int(vig.sum()), "n_failed_rays": int(failed.sum()),
        "chief_image_point_mm": [float(v) for v in d.reference_center],
        "chief_direction_at_image": [fl(chief.L), fl(chief.M), fl(chief.N)],
        "chief_opl_mm_optiland": fl(chief.opd),
        "reference_sphere_radius_mm": float(d.radius),
        "reference_sphere": "centre = chief_image_point_mm; radius = |centre - xp_point_global_mm| "
                            "(paraxial exit pupil point)",
    })
    ok = ~vig
    case["summary"] = summary(qx[ok], qy[ok], qw[ok], opd[ok])
    case["summary"]["weight_sum_before_renormalising"] = float(qw[ok].sum())
    if vig.any():
        s = summary(qx, qy, qw, opd)
        s["weight_sum_before_renormalising"] = float(qw.sum())
        case["summary_all_points"] = s
    else:
        case["summary_all_points"] = None

    # 3. optiland's own numbers
    o = {}
    od = OPD(op, field, wl, num_rays=OPD_RINGS, distribution="hexapolar", strategy="chief_ray")
    dd = od.get_data(field, wl)
    m = arr(dd.intensity) > 0
    W = arr(dd.opd)[m]
    o["opd_hexapolar_rings"] = OPD_RINGS
    o["opd_n_points_used"] = int(m.sum())
    o["opd_rms_optiland"] = fl(od.rms())
    o["opd_rms_optiland_definition"] = "OPD.rms() = sqrt(mean(W^2)) over intensity>0 points, equal " \
                                       "weights, no piston/tilt removal (chief-ray referenced)"
    o["opd_std_equal_weights"] = float(np.sqrt(np.mean((W - W.mean()) ** 2)))
    odt = OPD(op, field, wl, num_rays=OPD_RINGS, distribution="hexapolar", strategy="chief_ray",
              remove_tilt=True)
    Wt = arr(odt.get_data(field, wl).opd)[m]
    o["opd_rms_optiland_remove_tilt"] = fl(odt.rms())
    o["opd_rms_optiland_remove_tilt_definition"] = (
        "OPD(remove_tilt=True).rms(): Wavefront.fit_and_remove_tilt fits {1,x,y} (weights = "
        "intensity, x,y = EXIT-pupil (reference-sphere) coordinates in mm) but subtracts only the "
        "x,y terms (remove_piston=False), so the piston stays in; then sqrt(mean(W^2))")
    o["opd_rms_remove_tilt_then_mean_equal_weights"] = float(np.sqrt(np.mean((Wt - Wt.mean()) ** 2)))
    for kind in ("noll", "fringe"):
        z = ZernikeOPD(op, field, wl, num_rings=ZERNIKE_RINGS, zernike_type=kind, num_terms=37,
                       strategy="chief_ray")
        o[f"zernike_{kind}_waves"] = [float(v) for v in arr(z.coeffs)]
    o["zernike_sampling"] = (f"ZernikeOPD hexapolar num_rings={ZERNIKE_RINGS} "
                             f"({1 + 3 * ZERNIKE_RINGS * (ZERNIKE_RINGS + 1)} points), intensity>0 "
                             "points, unweighted least squares on normalised entrance-pupil (Px,Py)")
    psf = FFTPSF(op, field, wl, num_rays=PSF_RAYS, grid_size=PSF_GRID, strategy="chief_ray")
    P = arr(psf.psf)
    fno_w = fl(get_working_FNO(op, field, wl))
    Q = PSF_GRID / (PSF_RAYS - 1)
    pk = np.unravel_index(int(np.argmax(P)), P.shape)
    o["fftpsf"] = {"num_rays": PSF_RAYS, "grid_size": PSF_GRID, "strehl": psf.strehl_ratio(),
                   "peak_index_row_col": [int(pk[0]), int(pk[1])], "centre_index": PSF_GRID // 2,
                   "pixel_um": wl * fno_w / Q,
                   "pixel_rule": "dx = lambda_um * working_FNO(field) / Q, Q = grid_size/(num_rays-1)",
                   "psf_sum_over_100": float(P.sum() / 100.0)}
    dpsf = psf.get_data(psf.fields[0], psf.wavelengths[0])
    gx, gy = arr(psf.distribution.x), arr(psf.distribution.y)
    ix = np.rint((gx + 1.0) / 2.0 * (PSF_RAYS - 1)).astype(int)
    iy = np.rint((gy + 1.0) / 2.0 * (PSF_RAYS - 1)).astype(int)
    G = np.full((PSF_RAYS, PSF_RAYS), np.nan)
    G[iy, ix] = np.where(arr(dpsf.intensity) > 0, arr(dpsf.opd), np.nan)
    step = float(max(np.nanmax(np.abs(np.diff(G, axis=0))), np.nanmax(np.abs(np.diff(G, axis=1)))))
    o["fftpsf"]["max_opd_step_between_pupil_samples_waves"] = step
    o["fftpsf"]["sampling_adequate"] = bool(step < 0.5)
    o["fftpsf"]["sampling_note"] = ("an OPD step >= 0.5 wave between neighbouring pupil samples "
                                    "aliases the FFT PSF/MTF/Strehl: use them only where True")
    o["working_fno"] = fno_w
    o["working_fno_definition"] = ("utils.get_working_FNO: real rays Px,Py = (0,+-1),(+-1,0) and the "
                                   "chief; NA_k = n' sin(angle to chief); N_w = 1/(2 sqrt(mean NA_k^2)) "
                                   "over unvignetted marginal rays")
    cutoff = 1.0 / (wl * 1e-3 * fno_w)
    o["cutoff_lp_mm"] = cutoff
    o["cutoff_definition"] = "1 / (lambda_mm * working_fno(field))"
    freqs = MTF_FREQS + [f * cutoff for f in CUTOFF_FRACS]
    o["mtf_frequencies_lp_mm"] = freqs
    o["mtf_frequency_labels"] = [f"{f:g} lp/mm" for f in MTF_FREQS] + [f"{f:g} x cutoff" for f in CUTOFF_FRACS]
    sm = SampledMTF(op, field, wl, num_rays=SMTF_RAYS, distribution="uniform", zernike_terms=37,
                    zernike_type="fringe")
    tan = sm.calculate_mtf([(0.0, f) for f in freqs])
    sag = sm.calculate_mtf([(f, 0.0) for f in freqs])
    o["sampled_mtf"] = {"tangential_fy": [fl(v) for v in tan], "sagittal_fx": [fl(v) for v in sag],
                        "num_rays": SMTF_RAYS, "distribution": "uniform",
                        "xpd_mm": fl(sm.xpd), "xpl_mm": fl(sm.xpl),
                        "effective_cutoff_lp_mm": fl(sm.xpd) / (wl * 1e-3 * fl(sm.xpl))}
    fm = FFTMTF(op, fields=[field], wavelength=wl, num_rays=PSF_RAYS, grid_size=PSF_GRID)
    ft, fs = fm.freq_tang[0], fm.freq_sag[0]
    mt, ms = fm.mtf[0]
    o["fft_mtf"] = {"num_rays": PSF_RAYS, "grid_size": PSF_GRID,
                    "tangential": [interp_or_none(ft, mt, f) for f in freqs],
                    "sagittal": [interp_or_none(fs, ms, f) for f in freqs],
                    "step_tangential_lp_mm": fl(ft[1]), "step_sagittal_lp_mm": fl(fs[1]),
                    "last_bin_tangential_lp_mm": fl(ft[-1]), "last_bin_sagittal_lp_mm": fl(fs[-1]),
                    "max_freq_on_axis_cutoff_lp_mm": fl(fm.max_freq),
                    "values_at_frequencies": "linear interpolation between FFT bins (None beyond "
                                             "the last bin)"}
    zq = np.array(case["summary"]["zernike_standard_noll_waves"])
    zo = np.array(o["zernike_noll_waves"])
    fq = np.array(case["summary"]["zernike_fringe_waves"])
    fo = np.array(o["zernike_fringe_waves"])
    o["vs_quadrature"] = {
        "max_abs_diff_zernike_noll_j2_to_37": float(np.max(np.abs(zq[1:] - zo[1:]))),
        "abs_diff_zernike_noll_j1": float(abs(zq[0] - zo[0])),
        "max_abs_diff_zernike_fringe_j2_to_36": float(np.max(np.abs(fq[1:36] - fo[1:36]))),
        "rms_to_chief_minus_opd_std_equal_weights": case["summary"]["rms_to_chief_waves"]
        - o["opd_std_equal_weights"],
        "note": "different point sets (quadrature up to rho=0.9952, area weights; optiland "
                "hexapolar up to rho=1, equal weights) and different vignetting masks"}
    case["optiland"] = o
    case["_seconds"] = round(time.time() - t0, 1)
    return case


def sanity():
    """Closed-form checks: paraboloid mirror on axis (zero OPD, Strehl 1, diffraction MTF)."""
    from optiland.optic import Optic
    op = Optic()
    op.surfaces.add(index=0, thickness=np.inf)
    op.surfaces.add(index=1, radius=-200.0, conic=-1.0, material="mirror", is_stop=True, thickness=-100.0)
    op.surfaces.add(index=2)
    op.set_aperture(aperture_type="EPD", value=20.0)
    op.fields.set_type("angle")
    op.fields.add(y=0.0)
    op.wavelengths.add(0.55, is_primary=True)
    qx, qy, qw = quadrature()
    wf = Wavefront(op, fields=[(0.0, 0.0)], wavelengths=[0.55], distribution=PointsDistribution(qx, qy))
    W = arr(wf.get_data((0.0, 0.0), 0.55).opd)
    psf = FFTPSF(op, (0.0, 0.0), 0.55, num_rays=PSF_RAYS, grid_size=PSF_GRID)
    fno = fl(get_working_FNO(op, (0.0, 0.0), 0.55))
    nu_c = 1.0 / (0.55e-3 * fno)
    sm = SampledMTF(op, (0.0, 0.0), 0.55)
    out = []
    # Defocus sign: the image plane 0.05 mm beyond the focus (further along the reflected beam).
    dz = 0.05
    op2 = Optic()
    op2.surfaces.add(index=0, thickness=np.inf)
    op2.surfaces.add(index=1, radius=-200.0, conic=-1.0, material="mirror", is_stop=True,
                     thickness=-100.0 - dz)
    op2.surfaces.add(index=2)
    op2.set_aperture(aperture_type="EPD", value=20.0)
    op2.fields.set_type("angle")
    op2.fields.add(y=0.0)
    op2.wavelengths.add(0.55, is_primary=True)
    wf2 = Wavefront(op2, fields=[(0.0, 0.0)], wavelengths=[0.55], distribution=PointsDistribution(qx, qy))
    W2 = arr(wf2.get_data((0.0, 0.0), 0.55).opd)
    z4 = float(wls(zernike_noll(qx, qy), W2, qw)[3])
    w020 = dz / (8 * 5.0 ** 2) / 0.55e-3
    defocus = {"image_beyond_focus_mm": dz, "zernike_standard_Z4_waves": z4,
               "closed_form_abs_W020_over_2sqrt3_waves": w020 / (2 * math.sqrt(3)),
               "closed_form_note": "W020 = dz / (8 N^2), N = f/D = 5 (paraxial, small dz)",
               "sign": "image beyond focus -> Z4 %s 0 with optiland's chief - ray sign"
                       % ("<" if z4 < 0 else ">")}
    for fr in (0.25, 0.5, 0.75):
        phi = math.acos(fr)
        exact = 2 / math.pi * (phi - math.cos(phi) * math.sin(phi))
        got = fl(sm.calculate_mtf([(0.0, fr * nu_c)])[0])
        out.append({"nu_over_cutoff": fr, "sampled_mtf": got, "closed_form": exact})
    return {"system": "paraboloid mirror R=-200 mm, conic -1, EPD 20, image at focus (-100 mm), "
                      "0.55 um, on axis",
            "max_abs_opd_waves_quadrature": float(np.max(np.abs(W))),
            "fftpsf_strehl": psf.strehl_ratio(), "working_fno": fno, "efl_mm": fl(op.paraxial.f2()),
            "sampled_mtf_vs_closed_form": out, "defocus": defocus}


OPTILAND_NOTES = {
    "opd_sign": "OPD = (OPL_chief - OPL_ray) / lambda (wavefront/strategy.py ChiefRayStrategy: "
                "opd_wv = (opd_ref - opd) / (wavelength*1e-3)); waves at the case wavelength",
    "reference_sphere": "centre: the chief ray's (Px=Py=0, trace_generic) intersection with the image "
                        "surface; radius: distance from that point to optic.paraxial."
                        "exit_pupil_point_gcs() (paraxial XP, primary wavelength); OPL to the sphere: "
                        "rays.opd - n_image(primary wl) * t, t = distance back along the ray to the "
                        "sphere (reference_geometry.SphericalReference.path_length)",
    "opl_start_infinite_object": "rays launched on a plane z = z_EP - d normal to the axis; "
                                 "_restore_launch_phase adds n_obj * u.(r_launch - r_launch_chief): "
                                 "OPL is counted from the incident plane wavefront through the chief "
                                 "ray's launch point (only for AngleField + infinite object)",
    "opl_start_finite_object": "from the object point (all rays start there)",
    "piston": "chief_ray strategy: no piston removal (chief = 0); remove_tilt=True removes only the "
              "x,y tilt of a joint {1,x,y} fit (piston kept) in exit-pupil mm coordinates",
    "opd_rms": "OPD.rms() = sqrt(mean(W^2)) over intensity>0 samples, equal weights, no removal",
    "zernike_fit": "ZernikeFit: unweighted numpy lstsq on the distribution's normalised entrance-pupil "
                   "points (intensity>0), theta = atan2(y, x)",
    "zernike_noll": "optiland 'noll' = Noll 1976 ordering and normalisation (checked: identical to "
                    "the own code, header.zernike_check)",
    "zernike_standard": "optiland 'standard' = OSA/ANSI: 0-based j = (n(n+2)+m)/2, m<0 sin, same "
                        "normalisation as Noll; only the order differs (mapping in zernike_check)",
    "zernike_fringe": "optiland 'fringe' = unnormalised Fringe j = (1+(n+|m|)/2)^2 - 2|m| + "
                      "(1-sign m)/2; terms 1..36 as University of Arizona, but its term 37 is "
                      "(n,m)=(6,6) cos 6theta rho^6, NOT the 12th-order spherical R_12^0 of "
                      "Zemax/UA Fringe Z37 (see zernike_check)",
    "fftpsf": "psf/fft.py ScalarFFTPSF: pupil = num_rays x num_rays grid linspace(-1,1) in "
              "normalised ENTRANCE-pupil coords (Wavefront 'uniform' distribution, points with "
              "x^2+y^2<=1), P = sqrt(I) exp(-2 pi i W) (I=0 for clipped rays), zero-padded centred to "
              "grid_size, |fftshift(fft2)|^2, divided by (count of |P|>0)^2 and x100. With "
              "grid_size=None: num_rays -> floor(32*2^((log2 N - 5)/2)), grid = 2N (128 -> 64 on "
              "256). Pixel (only used for plot axes): dx = lambda * working_FNO(field) / Q, "
              "Q = grid_size/(num_rays-1). No projection of the pupil off axis.",
    "strehl": "BasePSF.strehl_ratio() = max(psf)/100: the PSF maximum anywhere (not the centre) over "
              "the peak of the same unaberrated clear pupil (clipped points excluded from both)",
    "sampled_mtf": "mtf/sampled.py: uniform num_rays grid (entrance pupil), chief-ray OPD, Fringe-37 "
                   "fit of W (all points incl. clipped ones with OPD set to 0 where invalid); "
                   "OTF(fx,fy) = sum sqrt(I) e^{2 pi i W(p)} sqrt(I) e^{-2 pi i Wfit(p - d)} / sum I, "
                   "d = xpl * lambda * (fx,fy) / (XPD/2) with paraxial XPD, xpl = -XPL (primary "
                   "wl): on-axis paraxial scaling for every field (cutoff XPD/(lambda xpl)); "
                   "(fx,fy) = (0,f) is the y frequency = tangential for a y field",
    "fft_mtf": "mtf/fft.py ScalarFFTMTF: |fftshift(fft2(psf))| / DC, clipped to [0,1]; "
               "'tangential' = data[centre:, centre] = y frequency, 'sagittal' = x frequency; bin "
               "steps per field and per direction: n' |d(P=+1) - d(P=-1)| projected on the image "
               "plane / ((num_rays-1) lambda), d = real marginal-ray direction cosines (Py=+-1 "
               "tangential, Px=+-1 sagittal): projected real pupil bandwidth per field (PR #531)",
    "working_fno": "utils.get_working_FNO: real marginal rays (0,+-1),(+-1,0) vs chief: "
                   "1/(2 sqrt(mean (n' sin angle)^2)), per field",
    "mtf_labels_other_classes": "analysis.MTFvsField and analysis.ThroughFocusMTF call SampledMTF "
                                "with (f, 0) labelled 'tangential' and (0, f) 'sagittal': for a y "
                                "field that is the x frequency, i.e. SWAPPED relative to FFTMTF "
                                "and to OpticStudio (see header.tangential_label_check)",
    "ray_aiming": "default 'paraxial' (RealRayTracer.ray_aiming_config), aims at the paraxial "
                  "entrance pupil; the file's RAIM is not read by optiland's Zemax reader",
    "vignetting_factors": "applied by optiland's ray aimer (P * (1 - v)); set to 0 here",
}


def main():
    t_start = time.time()
    qx, qy, qw = quadrature()
    header = {
        "generator": "scripts/waveref/wave_reference.py",
        "date": DATE,
        "engine": f"optiland {optiland.__version__ if hasattr(optiland, '__version__') else '0.6.3'}",
        "versions": {"python": platform.python_version(), "numpy": np.__version__},
        "command": ".venv-ref/bin/python scripts/waveref/wave_reference.py",
        "units": "mm, waves at the case wavelength, lp/mm, um for PSF pixels",
        "frame": "optiland global frame (z = axis, first surface at first_surface_z_global_mm)",
        "pupil": "normalised entrance-pupil coordinates Px, Py (paraxial EP, radius EPD/2)",
        "quadrature": "rho_i = sqrt(x_i), x_i 12 Gauss-Legendre nodes on [0,1]; theta_j = "
                      "2 pi (j+0.5)/36; weight w_i/36 (sum 1); i outer, j inner",
        "summary": "weights renormalised over the points used; rms_to_chief = piston removed; "
                   "rms_to_centroid = {1,Px,Py} removed by WLS; zernike by WLS (Noll orthonormal "
                   "37, Fringe unnormalised 37 with Z37 = R_12^0)",
        "optiland_notes": OPTILAND_NOTES,
    }
    v = getattr(optiland, "__version__", None)
    if v is None:
        from importlib.metadata import version
        v = version("optiland")
    header["engine"] = f"optiland {v}"
    for mod in ("scipy", "matplotlib"):
        from importlib.metadata import version
        header["versions"][mod] = version(mod)
    header["zernike_check"] = zernike_check()
    lenses_out = []
    only = os.environ.get("WAVEREF_ONLY")
    for lens in LENSES:
        if only and lens["id"] not in only.split(","):
            continue
        print("==", lens["id"], flush=True)
        entry = {"id": lens["id"], "path": lens["path"], "what": lens["what"]}
        try:
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf):
                op, patches, adapt, feat = load(lens)
                field_value, field_rule = choose_field(op, lens, adapt)
            kind = {"AngleField": "angle_deg", "ObjectHeightField": "object_height_mm"}[
                type(op.fields.field_definition).__name__]
            wl = fl(op.primary_wavelength)
            entry.update({"optiland_patches": patches, "adaptations": adapt,
                          "field_type": kind, "off_axis_field_rule": field_rule,
                          "optiland_max_field": fl(be.array(op.fields.max_field)),
                          "ray_aiming": dict(op.ray_tracer.ray_aiming_config),
                          "primary_wavelength_um": wl,
                          "apertures": [None if s.aperture is None else
                                        {"surface": i, "type": type(s.aperture).__name__,
                                         "r_max": getattr(s.aperture, "r_max", None)}
                                        for i, s in enumerate(op.surfaces)],
                          "paraxial": paraxial_numbers(op, wl)})
            entry["apertures"] = [a for a in entry["apertures"] if a is not None]
            fmax = fl(be.array(op.fields.max_field))
            cases = [(0.0, 0.0, wl), (field_value, field_value / fmax, wl)]
            if lens.get("extra_wavelength_um"):
                cases.append((0.0, 0.0, lens["extra_wavelength_um"]))
            entry["cases"] = []
            for fv, Hy, w in cases:
                print("   field", fv, "Hy", Hy, "wl", w, flush=True)
                with contextlib.redirect_stdout(buf):
                    c = run_case(op, fv, kind, Hy, w, qx, qy, qw)
                if c["wavelength_um"] != wl:
                    c["note"] = ("optiland's paraxial pupils (EPD, EPL, XPL, XPD, used for aiming, "
                                 "the reference sphere radius and SampledMTF) and n_image use the "
                                 "PRIMARY wavelength whatever the case wavelength")
                s = c["summary"]
                print(f"      rms chief {s['rms_to_chief_waves']:.6g} cent {s['rms_to_centroid_waves']:.6g} "
                      f"Z4 {s['zernike_standard_noll_waves'][3]:.6g} strehl {c['optiland']['fftpsf']['strehl']:.4g} "
                      f"vig {c['n_vignetted']} ({c.pop('_seconds')} s)", flush=True)
                entry["cases"].append(c)
            msg = buf.getvalue().strip()
            if msg:
                entry["optiland_said"] = msg[:2000]
        except Exception as e:  # record and go on
            import traceback
            traceback.print_exc()
            entry["failed"] = f"{type(e).__name__}: {e}"[:600]
        lenses_out.append(entry)
    out = {"header": header, "sanity": None, "lenses": lenses_out}
    # Tangential label check on an astigmatic off-axis field (the Cooke triplet at 14 deg).
    for e in lenses_out:
        if e["id"] == "cooke-triplet" and "cases" in e:
            c = e["cases"][1]
            o = c["optiland"]
            ft = o["fft_mtf"]["tangential"][:4]
            d_fy = max(abs(a - b) for a, b in zip(ft, o["sampled_mtf"]["tangential_fy"][:4]))
            d_fx = max(abs(a - b) for a, b in zip(ft, o["sampled_mtf"]["sagittal_fx"][:4]))
            header["tangential_label_check"] = {
                "case": "cooke-triplet, 14 deg, primary wavelength (Noll Z6 = %.3f waves astigmatism)"
                        % c["summary"]["zernike_standard_noll_waves"][5],
                "fft_mtf_tangential_10_20_40_80": ft,
                "sampled_mtf_fy_10_20_40_80": o["sampled_mtf"]["tangential_fy"][:4],
                "sampled_mtf_fx_10_20_40_80": o["sampled_mtf"]["sagittal_fx"][:4],
                "max_diff_fft_tangential_vs_sampled_fy": d_fy,
                "max_diff_fft_tangential_vs_sampled_fx": d_fx,
                "conclusion": "FFTMTF 'tangential' is the y frequency (SampledMTF (0, f))"
                              if d_fy < d_fx else "FFTMTF 'tangential' is the x frequency"}
    try:
        out["sanity"] = sanity()
    except Exception as e:
        out["sanity"] = {"failed": f"{type(e).__name__}: {e}"[:400]}
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w") as fh:
        fh.write("{\n")
        keys = list(out)
        for k, key in enumerate(keys):
            val = g.json_finite(out[key])
            if key == "lenses":
                fh.write(json.dumps(key) + ": [\n")
                for i, e in enumerate(val):
                    fh.write(json.dumps(e, separators=(",", ":"), allow_nan=False))
                    fh.write(",\n" if i + 1 < len(val) else "\n")
                fh.write("]")
            else:
                fh.write(json.dumps(key) + ": " + json.dumps(val, separators=(",", ":"), allow_nan=False))
            fh.write(",\n" if k + 1 < len(keys) else "\n")
        fh.write("}\n")
    print("wrote", OUT, round(time.time() - t_start, 1), "s")


if __name__ == "__main__":
    main()
