#!/usr/bin/env python3
"""Generate reference numbers for a corpus of Zemax .zmx files.

Versions: optiland 0.6.3, rayoptics 0.9.8 (fallback only), numpy (see venv),
Python 3.11.7, numpy 2.4.6 (scripts/requirements.txt).  Generated 2026-11-25 for the tolray project.

Usage (from the repository root; nothing in tolray runs this, tests read its output):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/gen_reference.py
writes tests/data/zemax/real/reference.json for every tests/data/zemax/real/<source>/*.zmx.
`... gen_reference.py --only rayoptics/HoO-V2C18Ex46.zmx` regenerates just the entries named
(paths as in the JSON) and keeps the others as they are (so used on 2026-11-27 for patch 7,
optiland 0.6.3), and for patch 8 on optiland/complicated_fold_mirrors_setup_v2.zmx; on
2026-11-29 for patch 9 on the two files whose glasses are LightPath's and RPO's, with
ZEMAXGLASS_AGF set (see ZemaxAgfGlass).

Per file:
  * feature inventory (scan_zmx.scan, pure python)
  * optiland 0.6.3 load_zemax_file -> paraxial EFL (f2), BFD, EPD, EP position,
    glass indices at the primary wavelength
  * explicit real-ray spot: 64x64 cell-centred grid on the paraxial entrance
    pupil disk, traced with optiland's real-ray tracer with ALL physical
    apertures removed (surface.aperture = None on every surface), onto the
    image surface as given (no refocus).

Frame: z = optical axis of object space, origin at the vertex of the first
optiland surface after the object (Zemax surface 1 unless surface 1 is a
coordinate break), y meridional.  optiland's own global frame is translated
so that this vertex is at z=0 (optiland puts it at z=0 for infinite objects
and also for finite objects; we subtract its z anyway).

Angle fields: ray direction (0, sin t, cos t), t = frac * max_angle with
max_angle the file's largest |y field| (degrees) taken as positive.  The rays
therefore rise (positive slope), and with a positive-EFL lens the chief ray /
centroid lands at POSITIVE image y (+f tan t).  Same as Zemax: a positive field
angle means positive ray slope (object at -y, image at +y).
Object-height fields (finite object): rays start at (0, frac*h_max, -d_obj)
and go through the pupil grid points at z = z_EP.
"""
from __future__ import annotations

import contextlib
import glob
import io
import json
import math
import os
import sys
import traceback
import warnings

import numpy as np

warnings.filterwarnings("ignore")
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from scan_zmx import scan  # noqa: E402

import optiland  # noqa: E402
import optiland.backend as be  # noqa: E402
from optiland.fileio.zemax.reader.converter import ZemaxToOpticConverter  # noqa: E402
from optiland.fileio.zemax.reader.parser import ZemaxDataParser  # noqa: E402
from optiland.materials import AbbeMaterial, BaseMaterial  # noqa: E402
from optiland.materials.ideal import IdealMaterial  # noqa: E402
from optiland.rays import RealRays  # noqa: E402

be.set_backend("numpy")
try:
    be.set_precision("float64")
except Exception:
    pass

NGRID = 64
FRACS = [0.0, 0.7, 1.0]

# The corpus: tests/data/zemax/real/<source>/*.zmx of the tolray repository.
CORPUS = os.environ.get("ZMXREF_CORPUS") or os.path.normpath(
    os.path.join(HERE, "..", "..", "tests", "data", "zemax", "real"))



def json_finite(o):
    """JSON has no inf / nan: they are written as strings."""
    if isinstance(o, dict):
        return {k: json_finite(v) for k, v in o.items()}
    if isinstance(o, list):
        return [json_finite(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return str(o)
    return o

def corpus():
    out = []
    for d in sorted(glob.glob(os.path.join(CORPUS, "*"))):
        for f in sorted(glob.glob(os.path.join(d, "*"))):
            if not f.lower().endswith(".zmx"):
                continue
            out.append((os.path.basename(d), f, os.path.relpath(f, CORPUS)))
    return out


# Glass names resolve as OpticStudio (and tolray) resolve them: in the file's GCAT order, then a
# fixed vendor order, by exact name; optiland 0.6.3 matches names loosely (it reads "SF5" as
# N-SF5 and "F2" under GCAT SCHOTT as Hikari's F2), which would compare tolray with a glass the
# file does not name.
GLASS_DB = os.path.join(os.path.dirname(optiland.__file__), "database", "data-nk", "glass")
GCAT_DIR = {"SCHOTT": "schott", "OHARA": "ohara", "HOYA": "hoya", "CDGM": "cdgm",
            "HIKARI": "hikari", "NIKON-HIKARI": "hikari", "SUMITA": "sumita"}
VENDOR_ORDER = ["schott", "ohara", "hoya", "cdgm", "hikari", "sumita"]


def exact_glass_file(name, gcat):
    order = [GCAT_DIR[g.upper()] for g in gcat if g.upper() in GCAT_DIR]
    order += [v for v in VENDOR_ORDER if v not in order]
    for v in order:
        hits = [f for f in glob.glob(os.path.join(GLASS_DB, v, "**", "*.yml"), recursive=True)
                if os.path.splitext(os.path.basename(f))[0].upper() == name.upper()]
        if hits:
            return sorted(hits)[0]
    return None


def fl(x):
    """to python float (full precision)."""
    a = np.asarray(be.to_numpy(x) if hasattr(be, "to_numpy") else x, dtype=float).ravel()
    return float(a[0])


def pupil_grid(r):
    c = (2 * np.arange(NGRID) + 1) / NGRID - 1.0
    X, Y = np.meshgrid(c * r, c * r, indexing="xy")
    X = X.ravel()
    Y = Y.ravel()
    keep = X * X + Y * Y <= r * r
    return X[keep], Y[keep]


def material_desc(m):
    if isinstance(m, str):
        return m
    return type(m).__name__ + (":" + str(getattr(m, "name", "")) if getattr(m, "name", None) else "")


def raw_glas(path, i):
    return glas_lines(path).get(int(i), "")


class TolrayModelGlass(IdealMaterial):
    """tolray's model glass: n = A + B / λ², exact n_d at 587.5618 nm and V_d from F and C."""

    def __init__(self, nd, vd):
        super().__init__(n=nd)
        inv2 = lambda l: 1.0 / (l * l)
        self.b = (nd - 1.0) / vd / (inv2(0.4861327) - inv2(0.6562725))
        self.a = nd - self.b * inv2(0.5875618)

    def _calculate_n(self, wavelength, **kwargs):
        return self.a + self.b / be.asarray(wavelength) ** 2


class ZemaxMiscSilica(IdealMaterial):
    """Fused silica as Zemax's MISC catalog writes it (F_SILICA and SILICA): Malitson's
    Sellmeier terms with the C coefficients squared and rounded as in MISC.AGF. optiland's own
    SiO2/Malitson page squares the unrounded C, which moves n by 1.4e-9 at 248 nm."""

    B = (0.6961663, 0.4079426, 0.8974794)
    C = (0.004679148, 0.013512063, 97.9340025)

    def __init__(self):
        super().__init__(n=1.0)

    def _calculate_n(self, wavelength, **kwargs):
        l2 = be.asarray(wavelength) ** 2
        n2 = 1.0 + sum(b * l2 / (l2 - c) for b, c in zip(self.B, self.C))
        return be.sqrt(n2)


class ZemaxAgfGlass(IdealMaterial):
    """A glass of a Zemax AGF catalog that optiland's database lacks (LightPath's D-ZK3M, RPO's
    L-TIM28_MOLD), evaluated from the AGF's own formula and coefficients: 1 (Schott) or
    2 (Sellmeier 1). The AGF files are those tolray's built-in table is generated from
    (scripts/glass/generate_agf_catalogs.py): set ZEMAXGLASS_AGF to that checkout's AGF_files."""

    def __init__(self, name, formula, cd):
        super().__init__(n=1.0)
        self.name, self.formula, self.cd = name, formula, cd

    def _calculate_n(self, wavelength, **kwargs):
        l2 = be.asarray(wavelength) ** 2
        c = self.cd
        if self.formula == 1:
            n2 = c[0] + c[1] * l2 + c[2] / l2 + c[3] / l2 ** 2 + c[4] / l2 ** 3 + c[5] / l2 ** 4
        elif self.formula == 2:
            n2 = 1.0 + sum(c[2 * k] * l2 / (l2 - c[2 * k + 1]) for k in range(3))
        else:
            raise ValueError(f"AGF formula {self.formula} not evaluated here")
        return be.sqrt(n2)


AGF_FILES = {"LIGHTPATH": ("lightpath.agf", "latin-1"), "RPO": ("rpo.agf", "latin-1")}


def agf_glass(name, gcat):
    """The ZemaxAgfGlass `name` of the first GCAT catalog in AGF_FILES that has it, or None."""
    root = os.environ.get("ZEMAXGLASS_AGF")
    if not root:
        return None
    for g in gcat:
        if g.upper() not in AGF_FILES:
            continue
        fname, enc = AGF_FILES[g.upper()]
        cur = None
        for ln in open(os.path.join(root, fname), "rb").read().decode(enc).splitlines():
            t = ln.split()
            if t and t[0] == "NM":
                cur = t if t[1].upper() == name.upper() else None
            elif t and t[0] == "CD" and cur is not None:
                return ZemaxAgfGlass(cur[1], int(float(cur[2])), [float(x) for x in t[1:]])
    return None


def load_optic(path, feat):
    """Parse + convert with optiland.  Returns (optic, patches, parser_model)."""
    patches = []
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        model = ZemaxDataParser(path).parse()
    # Patch 1: Zemax model glass with Vd == 0 (e.g. "GLAS ___BLANK 1 0 nd 0 ...")
    # is a non-dispersive medium of index nd; optiland builds an AbbeMaterial
    # that evaluates to NaN (or raises).  Replace by IdealMaterial(nd).
    for i, s in model.surfaces.items():
        m = s.get("material")
        if isinstance(m, AbbeMaterial) and s.get("abbe") in (0.0, None) and s.get("index"):
            s["material"] = IdealMaterial(n=s["index"])
            patches.append(f"surface {i}: model glass nd={s['index']!r} Vd=0 -> IdealMaterial")
        elif isinstance(m, AbbeMaterial) and raw_glas(path, i).upper().startswith("GLAS ___BLANK"):
            # Patch 5: a model glass (n_d, V_d) follows tolray's dispersion law (exact n_d and
            # V_d; OpticStudio's own model-glass law is not public), so that both tracers see
            # the same indices; the comparison is of the reading and the tracing.
            s["material"] = TolrayModelGlass(s["index"], s["abbe"])
            patches.append(f"surface {i}: model glass nd={s['index']!r} Vd={s['abbe']!r} -> tolray's Cauchy law")
    # Patch 7 (2026-11-27): TOROIDAL parameters as OpticStudio (and ray-optics) number them:
    # PARM 1 is the radius of rotation and PARM 2..8 the y^2 .. y^14 terms. optiland 0.6.3 keys
    # PARM k as param_{k-1} and takes the radius from param_1 (PARM 2) and the terms from
    # param_2 on (PARM 3..): shift them by one. Only HoO-V2C18Ex46 has a non-zero TOROIDAL PARM
    # in the corpus (PARM 1 = 1035), so only its entry changes (regenerated with --only).
    for i, s in model.surfaces.items():
        if s.get("type") == "toroidal":
            old = {k: s.get(f"param_{k}", 0.0) for k in range(0, 10)}
            if any(old.values()):
                for k in range(1, 10):
                    s[f"param_{k}"] = old[k - 1]
                s["param_0"] = 0.0
                patches.append(f"surface {i}: TOROIDAL PARM 1 (radius of rotation {old[0]!r}) "
                               "and PARM 2.. (y^2.. terms) moved to where optiland reads them")
    # Patch 3: F_SILICA / SILICA as Zemax MISC.AGF defines them (optiland 0.6.3 does not know
    # F_SILICA and reads SILICA as its own SiO2 page); see ZemaxMiscSilica.
    # (falls back to AbbeMaterial(0, 0) -> NaN).  Use optiland's 'fused silica'
    # (refractiveindex.info SiO2/Malitson, the same Sellmeier as Zemax F_SILICA).
    raw = glas_lines(path)
    for i, s in model.surfaces.items():
        m = s.get("material")
        name = raw.get(int(i), "").split()[1:2]
        if name and name[0].upper() in ("F_SILICA", "SILICA"):
            s["material"] = ZemaxMiscSilica()
            patches.append(f"surface {i}: {name[0]} -> Zemax MISC.AGF fused silica (Sellmeier 1, "
                           "C given squared to 10 digits as the AGF writes them)")
    # Patch 9: a glass that only an AGF catalog the file's GCAT names has (LIGHTPATH, RPO), which
    # optiland replaced by the GLAS line's n_d / V_d (see ZemaxAgfGlass).
    for i, s in model.surfaces.items():
        m = s.get("material")
        name = raw.get(int(i), "").split()[1:2]
        if not name or not isinstance(m, AbbeMaterial):
            continue
        if exact_glass_file(name[0], feat.get("gcat") or []):
            continue
        agf = agf_glass(name[0], feat.get("gcat") or [])
        if agf is not None:
            s["material"] = agf
            patches.append(f"surface {i}: GLAS {name[0]} -> {agf.name} of the file's GCAT "
                           f"catalog, AGF formula {agf.formula} (optiland chose {material_desc(m)})")
    # Patch 4: exact glass names in GCAT order (see exact_glass_file).
    from optiland.materials import MaterialFile
    for i, s in model.surfaces.items():
        m = s.get("material")
        name = raw.get(int(i), "").split()[1:2]
        if not name or isinstance(m, (str, AbbeMaterial, IdealMaterial, ZemaxMiscSilica, ZemaxAgfGlass)):
            continue
        if name[0].upper() in ("SILICA", "F_SILICA"):
            continue
        f = exact_glass_file(name[0], feat.get("gcat") or [])
        if f and os.path.abspath(f) != os.path.abspath(getattr(m, "filename", "") or ""):
            s["material"] = MaterialFile(f)
            patches.append(f"surface {i}: GLAS {name[0]} -> {os.path.relpath(f, GLASS_DB)} "
                           f"(optiland chose {material_desc(m)} "
                           f"{os.path.relpath(getattr(m, 'filename', '') or '-', GLASS_DB)})")
    with contextlib.redirect_stdout(buf):
        op = ZemaxToOpticConverter(model).convert()
    # Patch 6: optiland stops its asphere Newton iteration at a 1e-10 mm sag residual, which
    # leaves ray positions 1e-8 mm off after four aspheric mirrors; iterate to round-off.
    for srf in op.surface_group.surfaces:
        if hasattr(srf.geometry, "tol"):
            srf.geometry.tol = 1e-15
    # Patch 2: FLOA.  optiland passes the stop's DIAM (a Zemax SEMI-diameter)
    # as the stop *diameter*; double it so EPD has Zemax semantics.
    raw_epd = None
    if feat.get("system_aperture") and feat["system_aperture"]["type"] == "FLOA":
        raw_epd = fl(op.paraxial.EPD())
        op.set_aperture(aperture_type="float_by_stop_size", value=2.0 * float(op.aperture.value))
        patches.append("FLOA: stop DIAM is a semi-diameter; aperture value doubled")
    msg = buf.getvalue().strip()
    if msg:
        patches.append("optiland said: " + msg.replace("\n", " | "))
    return op, patches, model, raw_epd


def glas_lines(path):
    """Zemax surface index -> raw GLAS line (stripped)."""
    from scan_zmx import read_text
    text, _ = read_text(path)
    cur, out = None, {}
    for ln in text.splitlines():
        t = ln.split()
        if not t:
            continue
        if t[0] == "SURF":
            cur = int(t[1])
        elif t[0] == "GLAS" and cur is not None:
            out[cur] = " ".join(t)
    return out


def glass_indices(model, wl_um, path):
    raw = glas_lines(path)
    out = []
    for i in sorted(model.surfaces):
        s = model.surfaces[i]
        m = s.get("material")
        if isinstance(m, str):
            continue
        try:
            n = fl(m.n(wl_um))
        except Exception as e:  # pragma: no cover
            n = None
        line = raw.get(int(i))
        out.append({"surface": int(i), "glas_line": line,
                    "glas_name": line.split()[1] if line else None,
                    "optiland_material": material_desc(m),
                    "optiland_material_file": getattr(m, "filename", None) and os.path.relpath(getattr(m, "filename"), os.path.dirname(optiland.__file__)),
                    "catalog_fallback_to_abbe_model": isinstance(m, AbbeMaterial),
                    "nd_on_glas_line": s.get("index"), "vd_on_glas_line": s.get("abbe"), "n": n})
    return out


def field_spec(op, feat, efl, wl_um):
    """Return list of (frac, kind, value) and notes.  kind: 'angle' (deg) or 'height' (mm)."""
    notes = []
    n_f = None
    try:
        n_f = int(feat["ftyp_raw"].split()[2])
    except Exception:
        pass
    ys = feat.get("yfln") or [0.0]
    if n_f is not None and n_f > 0:
        ys = ys[:n_f]
    ymax = max(abs(v) for v in ys)
    ftype = feat.get("field_type") or "angle"
    infinite = op.object_surface.is_infinite
    if ftype == "angle":
        kind, vmax = "angle", ymax
    elif ftype == "object_height":
        kind, vmax = "height", ymax
    elif ftype in ("paraxial_image_height", "real_image_height"):
        if infinite:
            kind, vmax = "angle", math.degrees(math.atan(ymax / abs(efl)))
            notes.append(f"{ftype} field {ymax!r} mm converted to object angle atan(h/|EFL|) (paraxial); angle is what was traced")
        else:
            m = fl(op.paraxial.magnification())
            kind, vmax = "height", abs(ymax / m)
            notes.append(f"{ftype} field {ymax!r} mm converted to object height h/|m| with paraxial m={m!r}; height is what was traced")
    else:
        raise ValueError(f"field type {ftype} not handled")
    return kind, vmax, ymax, notes


def trace_spot(op, z1, z_ep, r_ep, kind, value, wl_um, d_obj):
    X, Y = pupil_grid(r_ep)
    n = X.size
    if kind == "angle" and op.object_surface.is_infinite:
        t = math.radians(value)
        x0, y0, z0 = X, Y, np.full(n, z_ep)
        L = np.zeros(n); M = np.full(n, math.sin(t)); N = np.full(n, math.cos(t))
        start = {"type": "parallel", "direction": [0.0, math.sin(t), math.cos(t)]}
    else:
        if kind == "angle":  # finite object with angle field: object point on chief ray through EP centre
            t = math.radians(value)
            yo = -(d_obj + z_ep) * math.tan(t)
        else:
            yo = value
        x0 = np.zeros(n); y0 = np.full(n, yo); z0 = np.full(n, -d_obj)
        dx, dy, dz = X - x0, Y - y0, z_ep - z0
        nn = np.sqrt(dx * dx + dy * dy + dz * dz)
        L, M, N = dx / nn, dy / nn, dz / nn
        x0 = x0.copy(); y0 = y0.copy()
        start = {"type": "point", "object_point": [0.0, yo, -d_obj]}
    # optiland global frame: shift by z1
    rays = RealRays(x0, y0, z0 + z1, L, M, N, np.ones(n), np.full(n, wl_um))
    rays = op.surfaces.trace(rays, skip=1)
    # optiland takes an intersection behind the ray (negative distance) as readily as one ahead,
    # so without apertures it passes rays that would have to travel backwards between surfaces
    # (their path crosses a later surface before an earlier one): no physical ray does that, and
    # tolray stops them. Count them out here, from the recorded global hit points and directions.
    # Flat surfaces between equal media (OpticStudio's dummy surfaces, which tolray does not
    # keep) bend nothing and may sit behind a tilted neighbour: they are left out of the check.
    def dummy(s):
        r = np.asarray(be.to_numpy(getattr(s.geometry, "radius", np.inf)), float).ravel()[0]
        same = fl(s.material_pre.n(wl_um)) == fl(s.material_post.n(wl_um))
        return not np.isfinite(r) and same and type(s.geometry).__name__ == "Plane"
    all_s = [s for s in op.surface_group.surfaces[1:] if be.size(s.x) > 0]
    surfs = [s for s in all_s[:-1] if not dummy(s)] + all_s[-1:]
    arr = lambda v: np.asarray(be.to_numpy(v), float)
    back = np.zeros(n, bool)
    for a_, b_ in zip(surfs[:-1], surfs[1:]):
        seg = [arr(b_.x) - arr(a_.x), arr(b_.y) - arr(a_.y), arr(b_.z) - arr(a_.z)]
        t = seg[0] * arr(a_.L) + seg[1] * arr(a_.M) + seg[2] * arr(a_.N)
        scale = 1.0 + np.abs(arr(a_.x)) + np.abs(arr(a_.y)) + np.abs(arr(a_.z))
        back |= t < -1e-9 * scale
    img = op.surfaces[-1]
    # image-local coordinates
    img.geometry.localize(rays)
    x = np.asarray(be.to_numpy(rays.x), float); y = np.asarray(be.to_numpy(rays.y), float)
    i = np.asarray(be.to_numpy(rays.i), float)
    ok = np.isfinite(x) & np.isfinite(y) & (i > 0) & ~back
    if ok.sum() == 0:
        return None, 0, None, start
    xc, yc = x[ok].mean(), y[ok].mean()
    rms = math.sqrt(np.mean((x[ok] - xc) ** 2 + (y[ok] - yc) ** 2))
    return rms * 1000.0, int(ok.sum()), [float(xc), float(yc)], start


def spots(op, feat, res, efl, wl_um, z1, epl, epd, d_obj):
    """The RMS spot, centroid and surviving count at each field fraction, into `res`."""
    kind, vmax, ymax, notes = field_spec(op, feat, efl, wl_um)
    res["field_notes"] = notes
    res["field_kind"] = kind
    res["field_max"] = vmax
    fields = []
    for fr in FRACS:
        v = fr * vmax
        rms, nr, cen, start = trace_spot(op, z1, epl, epd / 2.0, kind, v, wl_um, d_obj)
        e = {"frac": fr}
        e["angle_deg" if kind == "angle" else "height_mm"] = v
        e.update({"rms_um": rms, "n_rays": nr, "n_rays_launched": int(pupil_grid(epd / 2.0)[0].size),
                  "centroid_mm": cen, "launch": start})
        fields.append(e)
    res["fields"] = fields
    return res


def paraxial_refused(op, feat, res, model, err):
    """Patch 8 (2026-11-27): optiland 0.6.3 refuses a paraxial model for folded systems whose
    legs are not collinear (optiland/complicated_fold_mirrors_setup_v2.zmx: decentred fold
    mirrors), but traces their real rays. When the stop comes first behind flat surfaces in
    air and the aperture is ENPD, the entrance pupil is the stop itself (diameter ENPD, at
    the stop's vertex) and the rays are traced as for any file; EFL and BFD are left out."""
    ap = feat["system_aperture"]
    stop = op.surfaces.stop_index
    wl_um = fl(op.primary_wavelength)
    before = op.surfaces[1:stop + 1]
    flat_air = all(type(s.geometry).__name__ == "Plane"
                   and fl(s.material_post.n(wl_um)) == 1.0 for s in before)
    if ap["type"] != "ENPD" or not flat_air:
        raise err
    res["paraxial_refused"] = f"{type(err).__name__}: {err}"[:400]
    res["efl_mm"] = None
    res["bfd_mm"] = None
    res["bfd_caveat"] = "optiland has no paraxial model of this file"
    epd = float(ap["values"][0])
    res["epd_mm"] = epd
    z1 = fl(op.surfaces[1].geometry.cs.z)
    epl = fl(op.surfaces[stop].geometry.cs.z) - z1
    res["ep_z_mm"] = epl
    res["ep_z_reference"] = "the stop's vertex (the entrance pupil: only flat air surfaces precede it)"
    res["object_infinite"] = bool(op.object_surface.is_infinite)
    if not op.object_surface.is_infinite:
        raise err
    return spots(op, feat, res, None, wl_um, z1, epl, epd, None)


def optiland_reference(path, feat):
    res = {}
    op, patches, model, raw_epd = load_optic(path, feat)
    res["optiland_patches"] = patches
    wl_um = fl(op.primary_wavelength)
    res["wavelength_nm"] = wl_um * 1000.0
    # strip all physical apertures (CLAP/FLAP/OBDC...) so nothing clips
    for s in op.surfaces:
        s.aperture = None
    res["glass_indices"] = glass_indices(model, wl_um, path)
    res["glass_fallback_warning"] = any(g["catalog_fallback_to_abbe_model"] for g in res["glass_indices"])
    try:
        efl = fl(op.paraxial.f2())
    except Exception as e:
        if type(e).__name__ != "UnsupportedParaxialGeometryError":
            raise
        return paraxial_refused(op, feat, res, model, e)
    res["efl_mm"] = efl
    # BFD: paraxial back focus measured from the last surface before the image:
    # F2 (optiland: relative to image surface) + axial gap last->image.
    pos = np.asarray(be.to_numpy(op.surfaces.build_paraxial_path().axial_positions), float).ravel()
    F2 = fl(op.paraxial.F2())
    res["bfd_mm"] = F2 + (pos[-1] - pos[-2])
    res["F2_from_image_mm"] = F2
    if feat["coordbrk_surfaces"] or feat["mirror_surfaces"]:
        res["bfd_caveat"] = ("folded / coordinate-break / mirror system: bfd = F2 + gap between the last two "
                             "non-CB surfaces on optiland's unfolded signed axial coordinate; CB thicknesses "
                             "are not separate surfaces in optiland, so compare with care")
    epd = fl(op.paraxial.EPD())
    res["epd_mm"] = epd
    if raw_epd is not None:
        res["epd_mm_optiland_unpatched"] = raw_epd
    epl = fl(op.paraxial.EPL())
    res["ep_z_mm"] = epl
    res["ep_z_reference"] = "optiland Paraxial.EPL(): relative to vertex of first surface after object (z=0 in our frame)"
    res["object_infinite"] = bool(op.object_surface.is_infinite)
    z1 = fl(op.surfaces[1].geometry.cs.z)
    d_obj = None
    if not op.object_surface.is_infinite:
        d_obj = z1 - fl(op.object_surface.geometry.cs.z)
        res["object_distance_mm"] = d_obj
    return spots(op, feat, res, efl, wl_um, z1, epl, epd, d_obj)


def rayoptics_reference(path):
    """Fallback: paraxial numbers from ray-optics."""
    # rayoptics writes a *_tmpl.smx file next to the input: work on a temp copy
    import shutil
    import tempfile
    from rayoptics.environment import open_model
    tmpd = tempfile.mkdtemp(prefix="zmxref_ro_")
    tpath = os.path.join(tmpd, os.path.basename(path))
    shutil.copyfile(path, tpath)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        opm = open_model(tpath)
        pm = opm["parax_model"]
        fod = pm.opt_model["analysis_results"]["parax_data"].fod
        sm = opm["seq_model"]
        wl = sm.central_wavelength()
    return {"engine": "rayoptics 0.9.8", "wavelength_nm": float(wl), "efl_mm": float(fod.efl),
            "bfd_mm": float(fod.bfl), "epd_mm": float(fod.enp_radius * 2.0),
            "ep_z_mm": float(fod.enp_dist),
            "ep_z_reference": "rayoptics fod.enp_dist: distance from first interface to entrance pupil",
            "note": "paraxial only; rayoptics ignores unsupported surface types (QED_TYPE Q-asphere terms do not "
                    "affect paraxial values; DGRATING diffraction is NOT modelled, so grating files are the "
                    "zero-order/no-grating system)"}


def main():
    # `--only REL [REL ...]`: regenerate just those entries (paths relative to the corpus, as in
    # the JSON) and keep every other entry of the existing reference.json as it is.
    only = sys.argv[sys.argv.index("--only") + 1:] if "--only" in sys.argv else None
    old = {}
    if only:
        with open(os.path.join(CORPUS, "reference.json")) as fh:
            old = {e["path"]: e for e in json.load(fh)}
    # ray-optics writes zmx_read_lens.log into the working directory: keep it out of the repo.
    import tempfile
    os.chdir(tempfile.mkdtemp(prefix="zmxref-"))
    out = []
    for source, path, rel in corpus():
        if only and rel not in only:
            out.append(old[rel])
            continue
        feat = scan(path)
        entry = {"source": source, "path": rel, "features": feat}
        print("==", rel, flush=True)
        try:
            entry.update(optiland_reference(path, feat))
            entry["engine"] = "optiland 0.6.3"
        except Exception as e:
            reason = f"{type(e).__name__}: {e}"
            entry["refused"] = "optiland: " + reason[:400]
            print("   optiland refused:", reason[:200])
            try:
                entry["rayoptics_fallback"] = rayoptics_reference(path)
                print("   rayoptics:", entry["rayoptics_fallback"])
            except Exception as e2:
                entry["rayoptics_refused"] = f"{type(e2).__name__}: {e2}"[:400]
                print("   rayoptics refused:", str(e2)[:200])
        out.append(entry)
    with open(os.path.join(CORPUS, "reference.json"), "w") as fh:
        json.dump(json_finite(out), fh, indent=1, default=repr, allow_nan=False)


if __name__ == "__main__":
    main()
