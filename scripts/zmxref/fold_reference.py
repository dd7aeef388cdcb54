#!/usr/bin/env python3
"""Per-ray reference for fold mirrors, traced by optiland reading the .zmx files itself.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once (2026-11-27) for
the tolray project; tests read tests/data/zemax/fold_reference.json and never run Python.

Usage (outside the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/fold_reference.py > tests/data/zemax/fold_reference.json

Lenses: tests/data/zemax/fold.zmx (hand-made: a singlet, a 45-degree fold mirror about x, a
30-degree fold mirror about y on a decentred frame; constant index 1.5168) and
tests/data/zemax/real/optiland/complicated_fold_mirrors_setup_v2.zmx (optiland's own test file:
five fold mirrors, two of them decentred off their incoming leg, then an N-BK7 singlet; its
legacy "BK7" is N-BK7 in both tracers). optiland's readers place every surface by the file's
coordinate breaks, as OpticStudio does.

Rays: 3 directions (along the axis, tilted in y, skew; 3 and 2 degrees for fold.zmx, 0.5 and
0.3 degrees for the periscope, whose field is 0) x the points of a 9 x 9 grid over 0.95 of the entrance beam's radius (the
stop's semi-diameter), starting 1 mm in front of the stop, in the file's frame (the vertex of
SURF 1 at the origin). Recorded per ray: start, direction, and the position and direction where
it meets the image surface, in the file's frame and in the image surface's own frame.
"""
import json
import math
import warnings

import numpy as np
import optiland.backend as be
from optiland.fileio import load_zemax_file
from optiland.materials.ideal import IdealMaterial
from optiland.rays import RealRays

warnings.filterwarnings("ignore")
be.set_backend("numpy")
be.set_precision("float64")

# path, the stop's semi-diameter (mm), wavelength (µm), the field angles (degrees) of the
# tilted and the skew directions (the periscope's field is 0: its singlet sees 0.5 degrees).
FILES = {
    "fold.zmx": ("tests/data/zemax/fold.zmx", 4.0, 0.5875618, 3.0, 2.0),
    "real/optiland/complicated_fold_mirrors_setup_v2.zmx":
        ("tests/data/zemax/real/optiland/complicated_fold_mirrors_setup_v2.zmx", 10.0, 0.55, 0.5,
         0.3),
}


def rays(r, z0, a_tilt, a_skew):
    g = np.arange(-4, 5) * (0.95 * r / 4)
    pts = [(x, y) for x in g for y in g if x * x + y * y <= (0.95 * r) ** 2 + 1e-12]
    dirs = [(0.0, 0.0, 1.0),
            (0.0, math.sin(math.radians(a_tilt)), math.cos(math.radians(a_tilt)))]
    t = math.tan(math.radians(a_skew))
    n = math.sqrt(2 * t * t + 1)
    dirs.append((t / n, t / n, 1 / n))
    return [(x, y, z0, *d) for d in dirs for (x, y) in pts]


def trace(path, r_stop, wl_um, a_tilt, a_skew, root):
    op = load_zemax_file(root + path)
    for s in op.surfaces:
        s.aperture = None
    if path.endswith("/fold.zmx"):
        # The singlet's `___BLANK 1 0 1.5168 0` is a constant index (V_d = 0), which optiland
        # 0.6.3 reads as an Abbe glass with V_d = 0 (NaN indices): set it as the file means.
        glass = IdealMaterial(n=1.5168)
        op.surfaces[2].material_post = glass
    f = lambda v: np.asarray(be.to_numpy(v), float).ravel()
    stop = op.surfaces.stop_index
    z_stop = float(f(op.surfaces[stop].geometry.cs.z)[0])
    a = np.array(rays(r_stop, z_stop - 1.0, a_tilt, a_skew), float)
    n = len(a)
    r = RealRays(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], np.ones(n),
                 np.full(n, wl_um))
    op.surfaces.trace(r, skip=1)
    g = [f(v).copy() for v in (r.x, r.y, r.z, r.L, r.M, r.N)]
    op.surfaces[-1].geometry.localize(r)
    loc = [f(v) for v in (r.x, r.y, r.z, r.L, r.M, r.N)]
    out = []
    for k in range(n):
        out.append({"start": a[k, :3].tolist(), "dir": a[k, 3:].tolist(),
                    "image": [g[0][k], g[1][k], g[2][k]], "image_dir": [g[3][k], g[4][k], g[5][k]],
                    "local": [loc[0][k], loc[1][k], loc[2][k]],
                    "local_dir": [loc[3][k], loc[4][k], loc[5][k]]})
    return {"wavelength_um": wl_um, "rays": out}


if __name__ == "__main__":
    import os
    import sys
    root = os.path.abspath(sys.argv[1]) + "/" if len(sys.argv) > 1 else os.getcwd() + "/"
    doc = {
        "generator": "scripts/zmxref/fold_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64)",
        "frame": "the file's: the vertex of SURF 1 at the origin",
        "lenses": {k: trace(*v, root) for k, v in FILES.items()},
    }
    print(json.dumps(doc))
