#!/usr/bin/env python3
"""Per-ray reference for tolray's Q-type (Qbfs) aspheres, traced by optiland.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once for the tolray
project (2026-11-27); tests read tests/data/zemax/qbfs_reference.json and never run Python.

Usage (outside the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/qbfs_reference.py > tests/data/zemax/qbfs_reference.json

optiland 0.6.3 does not read OpticStudio's QED_TYPE surfaces, so the lenses are built here from
the files' numbers with optiland's `forbes_qbfs` geometry (ForbesQNormalSlopeGeometry: Forbes'
slope-orthogonal Q polynomials on a conic, the departure projected by
sqrt((1 - k c^2 r^2) / (1 - (1+k) c^2 r^2))), written independently of tolray:

- ASL5040-UV: Thorlabs' asphere, tests/data/zemax/real/rayoptics/ASL5040-UV-Zemax(ZMX).zmx
  (XDAT 1 type 0, XDAT 2 = 6 terms, XDAT 3 = 27 mm normalization radius, XDAT 4..9 the
  coefficients), glass C79-80 (Corning 7980 fused silica) as a constant index: Malitson's
  fused-silica Sellmeier formula at 405 nm, the file's primary wavelength (tolray reads C79-80
  as its F_SILICA, the same formula; the test checks the index).
- qbfs.zmx: a hand-made singlet in centimetres (tests/data/zemax/qbfs.zmx) with an 8-term Qbfs
  front on a conic and a 4-term Qbfs back, constant index 1.5168.

Rays stay inside the normalization radius (optiland sets the departure to 0 beyond it; tolray
continues the formula). optiland's Newton tolerance is set to 1e-15 mm.
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

# tolray's F_SILICA (Malitson 1965): B and C (µm^2) of the three-term Sellmeier formula.
B = [0.6961663, 0.4079426, 0.8974794]
C = [0.004679148, 0.013512063, 97.9340025]


def n_silica(wl_um):
    l2 = wl_um * wl_um
    return math.sqrt(1.0 + sum(b * l2 / (l2 - c) for b, c in zip(B, C)))


def asl5040():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, surface_type="forbes_qbfs", is_stop=True,
                   radius=1.0 / 5.756078762782423225E-02, conic=-0.67609120640407927,
                   radial_terms={0: -8.148370167576E-01, 1: -3.231100E-01, 2: 1.059100E-01,
                                 3: -5.058000E-02, 4: 9.870000E-03, 5: -2.200000E-03},
                   norm_radius=27.0, thickness=29.850000000000001,
                   material=IdealMaterial(n=n_silica(0.405)))
    op.add_surface(index=2, thickness=19.687453064998852)
    op.add_surface(index=3)
    return op


def handmade():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, surface_type="forbes_qbfs", radius=25.0, conic=-0.8,
                   radial_terms={0: 0.02, 1: -0.01, 2: 0.005, 3: -0.003, 4: 0.002, 5: -0.001,
                                 6: 5e-4, 7: -2e-4},
                   norm_radius=7.0, thickness=5.0, material=IdealMaterial(n=1.5168))
    op.add_surface(index=3, surface_type="forbes_qbfs", radius=-60.0, conic=0.5,
                   radial_terms={0: -0.01, 1: 0.004, 2: -0.002, 3: 0.001},
                   norm_radius=7.0, thickness=32.4)
    op.add_surface(index=4)
    return op


def rays(radius, n):
    g = np.linspace(-radius, radius, n)
    pts = [(x, y) for x in g for y in g if x * x + y * y <= radius ** 2 * (1 + 1e-12)]
    dirs = [(0.0, 0.0, 1.0), (0.0, math.sin(math.radians(3)), math.cos(math.radians(3)))]
    t = math.tan(math.radians(2))
    m = math.sqrt(2 * t * t + 1)
    dirs.append((t / m, t / m, 1 / m))
    return [(x, y, -1.0, *d) for d in dirs for (x, y) in pts]


def trace(op, rs, wl_um, epd):
    op.set_aperture(aperture_type="EPD", value=epd)
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
    doc = {
        "generator": "scripts/zmxref/qbfs_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64), forbes_qbfs geometry",
        "lenses": {
            "real/rayoptics/ASL5040-UV-Zemax(ZMX).zmx": {
                "wavelength_nm": 405.0, "index": n_silica(0.405),
                "rays": trace(asl5040(), rays(21.0, 11), 0.405, 45.72)},
            "qbfs.zmx": {
                "wavelength_nm": 587.5618, "index": 1.5168,
                "rays": trace(handmade(), rays(3.9, 9), 0.5875618, 8.0)},
        },
    }
    print(json.dumps(doc))
