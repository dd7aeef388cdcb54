#!/usr/bin/env python3
"""Angular (afocal image space) spot reference for an afocal lens, traced by optiland.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once (2026-11-27) for
the tolray project; tests read tests/data/zemax/afocal_reference.json and never run Python.

Usage (from outside the repository, which is the first argument):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    cd /tmp && REPO/.venv-ref/bin/python REPO/scripts/zmxref/afocal_reference.py REPO \
        > REPO/tests/data/zemax/afocal_reference.json

Lens: tests/data/zemax/keplerian.zmx (hand-made: two N-BK7 plano-convex lenses of 100 and 50 mm
focal length, spaced 145.385011188302 mm, which makes a unit-height paraxial ray leave with
slope -1.7e-18 at 587.5618 nm in this script's y-nu trace with optiland's N-BK7 index).

Rays: for each of the file's fields (0, 0.5 and 1 degree in y, OpticStudio's sign), parallel
rays through the centres of the cells of a 64 x 64 grid over the entrance pupil (the stop,
SURF 1, radius 5 mm) that lie inside it, plus the chief ray through its centre, started 1 mm in
front of the stop and traced to the image surface without apertures. Recorded per field: the
number of rays, the centroid of the rays' angles (atan(L/|N|), atan(M/|N|)) in mrad, the RMS
angular radius about that centroid and about the chief ray's angles in µrad, and the first
rays' directions.
"""
import json
import math
import os
import sys
import warnings

import numpy as np
import optiland.backend as be
from optiland.fileio import load_zemax_file
from optiland.rays import RealRays

warnings.filterwarnings("ignore")
be.set_backend("numpy")
be.set_precision("float64")

PATH = "tests/data/zemax/keplerian.zmx"
R_EP = 5.0
WL_UM = 0.5875618


def main(root):
    op = load_zemax_file(root + PATH)
    for s in op.surfaces:
        s.aperture = None
    f = lambda v: np.asarray(be.to_numpy(v), float).ravel()
    stop = op.surfaces.stop_index
    z_stop = float(f(op.surfaces[stop].geometry.cs.z)[0])
    g = ((2 * np.arange(64) + 1) / 64 - 1) * R_EP
    pts = [(x, y) for x in g for y in g if x * x + y * y <= R_EP * R_EP]
    pts.append((0.0, 0.0))  # the chief ray, last
    out = {"file": "keplerian.zmx", "wavelength_nm": WL_UM * 1e3, "fields": []}
    for deg in [0.0, 0.5, 1.0]:
        d = np.array([0.0, math.sin(math.radians(deg)), math.cos(math.radians(deg))])
        a = np.array([(x - d[0] / d[2], y - d[1] / d[2], z_stop - 1.0) for (x, y) in pts])
        n = len(a)
        r = RealRays(a[:, 0], a[:, 1], a[:, 2], np.full(n, d[0]), np.full(n, d[1]),
                     np.full(n, d[2]), np.ones(n), np.full(n, WL_UM))
        op.surfaces.trace(r, skip=1)
        L, M, N = f(r.L), f(r.M), f(r.N)
        ax = np.arctan2(L, np.abs(N)) * 1e3
        ay = np.arctan2(M, np.abs(N)) * 1e3
        cx, cy = ax[:-1].mean(), ay[:-1].mean()
        rms = math.sqrt(((ax[:-1] - cx) ** 2 + (ay[:-1] - cy) ** 2).mean()) * 1e3
        rms_chief = math.sqrt(((ax[:-1] - ax[-1]) ** 2 + (ay[:-1] - ay[-1]) ** 2).mean()) * 1e3
        out["fields"].append({
            "angle_deg": deg,
            "n_rays": n - 1,
            "centroid_mrad": [cx, cy],
            "rms_urad": rms,
            "rms_chief_urad": rms_chief,
            "first_directions": [[L[k], M[k], N[k]] for k in range(3)],
            "first_origins": [list(a[k]) for k in range(3)],
        })
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main(os.path.abspath(sys.argv[1]) + "/")
