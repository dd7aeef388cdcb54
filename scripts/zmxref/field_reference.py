#!/usr/bin/env python3
"""Per-ray reference for a .zmx file's own field points, with their vignetting factors.

Versions: optiland 0.6.3, numpy 2.4.6, Python 3.11 (the venv of gen_reference.py). Generated once
for the tolray project (2026-11-26); tests read the output, never run this.

Usage (from the repository root):
    .venv-ref/bin/python scripts/zmxref/field_reference.py
writes tests/data/zemax/real/field_reference.json.

For each file in FILES and each of its field points (FTYP/XFLN/YFLN: angles, object heights,
paraxial or real image heights, as optiland's field types of the same names define them):
  * the pupil: tolray's `grid:16` pattern (16 x 16 cell-centred points of [-1, 1]^2 kept inside
    the unit disk, x fastest), moved into the field's vignetted pupil as OpticStudio defines it,
    Px' = VDX + Px (1 - VCX), Py' = VDY + Py (1 - VCY) (VDXN/VDYN/VCXN/VCYN of the file, read
    here from the text; optiland 0.6.3 reads the compressions VCXN/VCYN alone, as its field's
    vx, vy: they are set to 0 in optiland so that the map is applied once, here);
  * optiland's own ray generator for that field (normalized field Hx, Hy = field / optiland's
    largest radial field; its field sign is OpticStudio's: a positive angle is a positive ray
    slope) with optiland's default paraxial aiming, every aperture removed, traced to the image
    surface; each ray's (x, y) in the image surface's frame, mm, or null when optiland's
    intensity says it failed; and the rays optiland moved backwards to a surface
    (`optiland_backward`: tolray stops those as backward@k).
Glasses resolve as gen_reference.load_optic resolves them (the file's GCAT order).
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import gen_reference as g  # noqa: E402
from scan_zmx import scan  # noqa: E402

import optiland.backend as be  # noqa: E402

FILES = [
    # Vignetting factors on two of three angle fields, real ray aiming in the file.
    "rayoptics/US00583336-2-scaled.zmx",
    # Coordinate breaks (a decentred, tilted system) and fields off both axes: a field of the
    # wrong sign would be another field here. (skzemax/e07 would do too, but optiland 0.6.3
    # misreads its coordinate breaks' order flag: see the corpus test.)
    "rayoptics/US08011793-1.zmx",
    # Object-height fields at a finite object.
    "deeplens/zemax_double_gaussian.zmx",
    # Paraxial image heights (FTYP 2), a catadioptric system at infinity (added 2026-11-27:
    # optiland's ParaxialImageHeightField, its unit chief ray at the primary wavelength).
    "rayoptics/US05331467-1.zmx",
    # Real image heights (FTYP 3) at a finite object (added 2026-11-27: optiland's
    # RealImageHeightField, Newton on the chief ray through the paraxial pupil centre at the
    # primary wavelength, to the image surface's global x, y; the image plane is not tilted).
    "rayoptics/US05831776-1.zmx",
    # The object on the first surface (object distance 0), two hand-made lenses beside the
    # corpus (added 2026-12-01): object heights with an object-space NA (a source on a flat
    # face), and real image heights with the first surface convex toward the object.
    "../object-on-surface.zmx",
    "../object-on-curved-surface.zmx",
]
NGRID = 16


def grid():
    c = (2 * np.arange(NGRID) + 1) / NGRID - 1.0
    pts = [(x, y) for y in c for x in c if x * x + y * y <= 1.0]
    return np.array([p[0] for p in pts]), np.array([p[1] for p in pts])


def lines_of(path):
    raw = open(path, "rb").read()
    for enc in ("utf-16", "utf-8", "latin-1"):
        try:
            text = raw.decode(enc)
            if "SURF" in text:
                return text.splitlines()
        except UnicodeDecodeError:
            continue
    raise ValueError("cannot decode " + path)


def numbers(lines, cmd):
    for ln in lines:
        t = ln.split()
        if t and t[0] == cmd:
            return [float(v) for v in t[1:]]
    return []


def backward_rays(op):
    """Indices of the rays that optiland moved backwards to a surface (a negative distance
    along the ray between consecutive surfaces, below -1e-9 mm): optiland intersects a surface
    behind a ray and goes on, where tolray stops the ray as `backward@k`."""
    sg = op.surface_group
    pos = [np.asarray(be.to_numpy(a), float) for a in (sg.x, sg.y, sg.z)]
    dirs = [np.asarray(be.to_numpy(a), float) for a in (sg.L, sg.M, sg.N)]
    t = sum((p[2:] - p[1:-1]) * d[1:-1] for p, d in zip(pos, dirs))
    bad = np.any(np.nan_to_num(t, nan=0.0) < -1e-9, axis=0)
    return [int(i) for i in np.flatnonzero(bad)]


def main():
    out = {"header": {
        "generator": "scripts/zmxref/field_reference.py",
        "engine": "optiland 0.6.3 (ray generator and real-ray trace, apertures removed)",
        "pupil": "tolray grid:16 (cell-centred, inside the unit disk, x fastest), vignetted as "
                 "OpticStudio: P' = VD + P (1 - VC)",
        "units": "mm; fields as the file writes them (degrees or lens units)",
    }, "files": []}
    for rel in FILES:
        path = os.path.join(g.CORPUS, rel)
        feat = scan(path)
        op, patches, _, _ = g.load_optic(path, feat)
        for s in op.surfaces:
            s.aperture = None
        for f in op.fields.fields:
            f.vx = 0.0
            f.vy = 0.0
        wl = g.fl(op.primary_wavelength)
        lines = lines_of(path)
        n = int(feat["ftyp_raw"].split()[2])
        xs = numbers(lines, "XFLN")[:n] or [0.0] * n
        ys = numbers(lines, "YFLN")[:n]
        vig = {k: (numbers(lines, k)[:n] or [0.0] * n) for k in ("VDXN", "VDYN", "VCXN", "VCYN")}
        fmax = g.fl(be.array(op.fields.max_field))
        Px0, Py0 = grid()
        entry = {"path": rel, "wavelength_um": wl, "field_type": feat["field_type"],
                 "optiland_patches": patches, "fields": []}
        for i in range(n):
            vdx, vdy, vcx, vcy = (vig[k][i] for k in ("VDXN", "VDYN", "VCXN", "VCYN"))
            Px = vdx + Px0 * (1.0 - vcx)
            Py = vdy + Py0 * (1.0 - vcy)
            Hx, Hy = xs[i] / fmax, ys[i] / fmax
            rays = op.trace_generic(Hx, Hy, Px, Py, wl)
            img = op.surfaces[-1]
            img.geometry.localize(rays)
            x = np.asarray(be.to_numpy(rays.x), float)
            y = np.asarray(be.to_numpy(rays.y), float)
            inten = np.asarray(be.to_numpy(rays.i), float)
            hits = [[float(a), float(b)] if (np.isfinite(a) and np.isfinite(b) and w > 0) else None
                    for a, b, w in zip(x, y, inten)]
            backward = backward_rays(op)
            entry["fields"].append({
                "x": xs[i], "y": ys[i],
                "vignetting": {"vdx": vdx, "vdy": vdy, "vcx": vcx, "vcy": vcy},
                "pupil": [[float(a), float(b)] for a, b in zip(Px, Py)],
                "image_xy_mm": hits,
                "optiland_backward": backward,
            })
            print(rel, i, sum(h is not None for h in hits), "rays", flush=True)
        out["files"].append(entry)
    with open(os.path.join(g.CORPUS, "field_reference.json"), "w") as fh:
        json.dump(g.json_finite(out), fh, indent=1, allow_nan=False)


if __name__ == "__main__":
    main()
