#!/usr/bin/env python3
"""Per-ray reference for tolray's diffractive phase surfaces (OpticStudio BINARY_2), traced by
optiland.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once for the tolray
project (2026-11-30); tests read tests/data/zemax/binary2_reference.json and never run Python.

Usage (outside the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/binary2_reference.py > tests/data/zemax/binary2_reference.json

optiland 0.6.3 does not read OpticStudio's Binary 2 surfaces, so the lens is built here from the
file's numbers: the even-asphere geometry with optiland's phase interaction
(PhaseInteractionModel: the tangential wave vector gains the phase's gradient, k0 = 2π/λ) and
its RadialPhaseProfile, whose coefficients are on the unnormalized r^2, r^4, ...: Binary 2's
M A_i / R^(2i). Written independently of tolray.

- binary2.zmx: a hand-made singlet (tests/data/zemax/binary2.zmx): a conic front with an r^4
  term and three phase terms (A_1 = -1133.35, A_2 = 341.92, A_3 = -25 rad over R = 10 mm, the
  first two the magnitudes of OpticStudio's short-course sample sc_diffract2), first order, a
  spherical back, constant index 1.5168, at 486.1327, 587.5618 and 656.2725 nm.

optiland's phase interaction adds -Φ/k0 to the path (the opposite sign to OpticStudio's
λΦ/2π), so only positions and directions are compared; tolray's path is checked against
Hamilton's characteristic function in the tests. Rays start 1 mm before the first vertex.
"""
import json
import math
import warnings

import numpy as np
import optiland.backend as be
from optiland.materials.ideal import IdealMaterial
from optiland.optic import Optic
from optiland.phase.radial import RadialPhaseProfile
from optiland.rays import RealRays

warnings.filterwarnings("ignore")
be.set_backend("numpy")
be.set_precision("float64")

R = 10.0
A = [-1133.35, 341.92, -25.0]


def singlet():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, surface_type="even_asphere", radius=25.0, conic=-0.5,
                   coefficients=[0.0, -2e-5], thickness=5.0, material=IdealMaterial(n=1.5168),
                   phase_profile=RadialPhaseProfile([a / R ** (2 * (i + 1))
                                                     for i, a in enumerate(A)]))
    op.add_surface(index=3, radius=-60.0, thickness=28.0)
    op.add_surface(index=4)
    return op


def grid_rays(radius, n):
    g = np.linspace(-radius, radius, n)
    pts = [(x, y) for x in g for y in g if x * x + y * y <= radius ** 2 * (1 + 1e-12)]
    dirs = [(0.0, 0.0, 1.0), (0.0, math.sin(math.radians(3)), math.cos(math.radians(3)))]
    t = math.tan(math.radians(2))
    m = math.sqrt(2 * t * t + 1)
    dirs.append((t / m, t / m, 1 / m))
    return [(x, y, -1.0, *d) for d in dirs for (x, y) in pts]


def trace(rs, wl_um):
    op = singlet()
    op.set_aperture(aperture_type="EPD", value=8.0)
    op.set_field_type("angle")
    op.add_field(y=0.0)
    op.add_wavelength(value=wl_um, is_primary=True)
    for s in op.surface_group.surfaces:
        if hasattr(s.geometry, "tol"):
            s.geometry.tol = 1e-15
    z0 = float(be.to_numpy(op.surface_group.positions[1]).ravel()[0])
    a = np.array(rs, float)
    n = len(a)
    r = RealRays(a[:, 0], a[:, 1], a[:, 2] + z0, a[:, 3], a[:, 4], a[:, 5], np.ones(n),
                 np.full(n, wl_um))
    op.surface_group.trace(r, skip=1)
    f = lambda v: np.asarray(be.to_numpy(v), float)
    x, y, z, L, M, N = f(r.x), f(r.y), f(r.z) - z0, f(r.L), f(r.M), f(r.N)
    return [{"start": a[k, :3].tolist(), "dir": a[k, 3:].tolist(),
             "image": [x[k], y[k], z[k]], "image_dir": [L[k], M[k], N[k]]} for k in range(n)]


if __name__ == "__main__":
    rs = grid_rays(3.9, 9)
    doc = {
        "generator": "scripts/zmxref/binary2_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64): even_asphere geometry, PhaseInteractionModel "
                  "with RadialPhaseProfile",
        "file": "binary2.zmx",
        "wavelengths": {str(wl): trace(rs, wl / 1000.0) for wl in (486.1327, 587.5618, 656.2725)},
    }
    print(json.dumps(doc))
