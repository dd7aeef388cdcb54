#!/usr/bin/env python3
"""Per-ray reference for tolray's curved (and conic) image surface, traced by optiland.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once for the tolray
project; tests read tests/data/zemax/curved_image_reference.json and never run Python.

Usage (outside the repository root, so that nothing here is imported by tolray's tools):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/curved_image_reference.py > tests/data/zemax/curved_image_reference.json

The lenses are tests/data/zemax/curved-image.zmx (a singlet focusing on a concave image surface
of radius -30 mm and conic -0.5, 36 mm behind it) and curved-image-convex.zmx (the same singlet
with a convex image surface of radius 60 mm, 34 mm behind it), built here in optiland from the
same numbers. The glass is a constant index 1.5168 (the files' `___BLANK 1 0 1.5168 0` model
glass with V_d = 0), so the comparison is of the surfaces and the tracing alone. optiland's
Newton tolerance is set to 1e-15 mm.

Rays: 3 directions x the points of a 9 x 9 grid (pitch 0.975 mm, inside a radius of 3.9 mm)
at z = -1 mm, 1 mm before the stop at z = 0 (global frame: the stop's vertex at the origin).
Recorded per ray: start, direction, and position and direction at the image surface.
"""
import json
import math
import warnings

import numpy as np
import optiland.backend as be
from optiland.materials.ideal import IdealMaterial
from optiland.optic import Optic
from optiland.rays import RealRays

warnings.filterwarnings("ignore")
be.set_backend("numpy")
be.set_precision("float64")

N_GLASS = 1.5168
WL_UM = 0.5875618


def singlet(image_radius, image_conic, gap):
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, radius=20.0, thickness=5.0, material=IdealMaterial(n=N_GLASS))
    op.add_surface(index=3, radius=-100.0, thickness=gap)
    op.add_surface(index=4, radius=image_radius, conic=image_conic)
    return op


def rays():
    g = np.arange(-4, 5) * 0.975
    pts = [(x, y) for x in g for y in g if x * x + y * y <= 3.9 ** 2]
    dirs = [(0.0, 0.0, 1.0), (0.0, math.sin(math.radians(3)), math.cos(math.radians(3)))]
    t = math.tan(math.radians(2))
    n = math.sqrt(2 * t * t + 1)
    dirs.append((t / n, t / n, 1 / n))
    return [(x, y, -1.0, *d) for d in dirs for (x, y) in pts]


def trace(op, rs):
    op.set_aperture(aperture_type="EPD", value=8.0)
    op.set_field_type("angle")
    op.add_field(y=0.0)
    op.add_wavelength(value=WL_UM, is_primary=True)
    for s in op.surface_group.surfaces:
        if hasattr(s.geometry, "tol"):
            s.geometry.tol = 1e-15
    z_stop = float(be.to_numpy(op.surface_group.positions[1]).ravel()[0])
    a = np.array(rs, float)
    n = len(a)
    r = RealRays(a[:, 0], a[:, 1], a[:, 2] + z_stop, a[:, 3], a[:, 4], a[:, 5], np.ones(n),
                 np.full(n, WL_UM))
    op.surface_group.trace(r, skip=1)
    f = lambda v: np.asarray(be.to_numpy(v), float)
    x, y, z, L, M, N = f(r.x), f(r.y), f(r.z) - z_stop, f(r.L), f(r.M), f(r.N)
    out = []
    for k in range(n):
        out.append({"start": a[k, :3].tolist(), "dir": a[k, 3:].tolist(),
                    "image": [x[k], y[k], z[k]], "image_dir": [L[k], M[k], N[k]]})
    return out


if __name__ == "__main__":
    rs = rays()
    doc = {
        "generator": "scripts/zmxref/curved_image_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64)",
        "index": N_GLASS,
        "lenses": {
            "curved-image.zmx": trace(singlet(-30.0, -0.5, 36.0), rs),
            "curved-image-convex.zmx": trace(singlet(60.0, 0.0, 34.0), rs),
        },
    }
    print(json.dumps(doc))
