#!/usr/bin/env python3
"""Per-ray reference for tolray's toroidal and odd-asphere surfaces and a virtual image plane,
traced by optiland.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once for the tolray
project; tests read tests/data/zemax/shapes_reference.json and never run Python.

Usage (outside the repository root, so that nothing here is imported by tolray's tools):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/shapes_reference.py > tests/data/zemax/shapes_reference.json

The lenses are tests/data/zemax/toroid.zmx, oddasphere.zmx and virtual-image.zmx (added
2026-11-26; the first two entries unchanged), built here in optiland from
the same numbers (not read from the .zmx: optiland 0.6.3's TOROIDAL reader takes PARM 2 as the
radius of rotation, which OpticStudio and ray-optics put in PARM 1). The glass is a constant
index 1.5168 on both sides (the files' `___BLANK 1 0 1.5168 0` model glass with V_d = 0), so
the comparison is of the surfaces and the tracing alone. optiland's Newton tolerance is set to
1e-15 mm (its default 1e-10 stops early).

Rays: 3 directions x the points of a 9 x 9 grid (pitch 0.975 mm, inside a radius of 3.9 mm)
at z = -1 mm, 1 mm before the stop at z = 0 (global frame: the stop's vertex at the origin).
Recorded per ray: start, direction, and position and direction at the image plane.
"""
import json
import warnings
import math

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


def toroid():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, surface_type="toroidal", radius_x=40.0, radius_y=25.0, conic=-0.5,
                   toroidal_coeffs_poly_y=[0.0, -2e-6, 3e-9], thickness=5.0,
                   material=IdealMaterial(n=N_GLASS))
    op.add_surface(index=3, surface_type="toroidal", radius_x=np.inf, radius_y=-100.0, conic=0.0,
                   toroidal_coeffs_poly_y=[], thickness=40.0)
    op.add_surface(index=4)
    return op


def oddasphere():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, surface_type="odd_asphere", radius=20.0, conic=-0.3,
                   coefficients=[1e-4, 0.0, -5e-5, 2e-6, -1e-7], thickness=5.0,
                   material=IdealMaterial(n=N_GLASS))
    op.add_surface(index=3, radius=-100.0, thickness=36.0)
    op.add_surface(index=4)
    return op


def virtual_image():
    """A biconcave lens whose image plane lies 39.0265 mm in front of its last surface: the
    rays are extended backwards to it (optiland, like OpticStudio, propagates by the negative
    thickness)."""
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, radius=-40.0, thickness=2.0, material=IdealMaterial(n=N_GLASS))
    op.add_surface(index=3, radius=40.0, thickness=-39.0265)
    op.add_surface(index=4)
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
        "generator": "scripts/zmxref/shapes_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64)",
        "index": N_GLASS,
        "lenses": {"toroid.zmx": trace(toroid(), rs), "oddasphere.zmx": trace(oddasphere(), rs),
                   "virtual-image.zmx": trace(virtual_image(), rs)},
    }
    print(json.dumps(doc))
