#!/usr/bin/env python3
"""Per-ray reference for tolray's Q-type aspheres of type 1 (Forbes' Qcon), traced by optiland.

Versions: optiland 0.6.3 (numpy backend, float64), SciPy 1.x, Python 3.11. Generated once for
the tolray project (2026-11-27); tests read tests/data/zemax/qcon_reference.json and never run
Python.

Usage (outside the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/qcon_reference.py > tests/data/zemax/qcon_reference.json

optiland has no Qcon geometry. A Qcon surface is a conic plus x^2 sum_m a_m Q_m(x),
x = (r / r_n)^2, Q_m(x) = P_m^(0,4)(2x - 1) (Jacobi polynomials; Forbes, Opt. Express 15, 5218
(2007), eq. 3.1): an even polynomial in r of degree 2m + 4. So the surfaces of
tests/data/zemax/qcon.zmx (a hand-made singlet in inches) are built here as optiland
`even_asphere` surfaces whose power-series coefficients come from SciPy's Jacobi polynomials,
written independently of tolray's three-term relation. Constant index 1.5168; optiland's
Newton tolerance 1e-15 mm. The document also holds the sag at a few radii from the same
power series, for the tests' direct check of the shape.
"""
import json
import math
import warnings

import numpy as np
import optiland.backend as be
from numpy.polynomial import Polynomial
from optiland.materials.ideal import IdealMaterial
from optiland.optic import Optic
from scipy.special import jacobi

# The same ray sets and optiland trace as the Qbfs reference (three directions on a square grid).
from qbfs_reference import rays, trace

warnings.filterwarnings("ignore")
be.set_backend("numpy")
be.set_precision("float64")

IN = 25.4


def qcon_power_series(a, norm_mm):
    """Coefficients C_i on r^(2i), i = 1.., of x^2 sum a_m P_m^(0,4)(2x - 1), x = r^2 / norm^2."""
    total = Polynomial([0.0])
    for m, am in enumerate(a):
        p = Polynomial(jacobi(m, 0, 4).coeffs[::-1])  # in t = 2x - 1, ascending powers
        total = total + am * p(Polynomial([-1.0, 2.0]))
    total = total * Polynomial([0.0, 0.0, 1.0])  # times x^2
    c = total.coef  # on x^0, x^1, ...
    return [c[i] / norm_mm ** (2 * i) if i < len(c) else 0.0 for i in range(1, len(c))]


def conic_sag(c, k, r2):
    return c * r2 / (1 + math.sqrt(1 - (1 + k) * c * c * r2))


FRONT = dict(c=1.1111111111111112 / IN, k=-0.5, norm=0.28 * IN,
             a=[v * IN for v in [0.002, -0.001, 0.0005, -0.00025, 0.00012, -0.00006, 0.00003,
                                 -0.000015]])
BACK = dict(c=-0.4 / IN, k=0.0, norm=0.28 * IN, a=[v * IN for v in [-0.0002, 0.00006, -0.00002]])


def lens():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=0.08 * IN, is_stop=True)
    op.add_surface(index=2, surface_type="even_asphere", radius=1.0 / FRONT["c"], conic=FRONT["k"],
                   coefficients=qcon_power_series(FRONT["a"], FRONT["norm"]),
                   thickness=0.2 * IN, material=IdealMaterial(n=1.5168))
    op.add_surface(index=3, surface_type="even_asphere", radius=1.0 / BACK["c"], conic=BACK["k"],
                   coefficients=qcon_power_series(BACK["a"], BACK["norm"]), thickness=1.21 * IN)
    op.add_surface(index=4)
    return op


def sags(s):
    coef = qcon_power_series(s["a"], s["norm"])
    out = []
    for rho in np.linspace(0.0, 1.2 * s["norm"], 13):
        r2 = rho * rho
        z = conic_sag(s["c"], s["k"], r2) + sum(ci * r2 ** (i + 1) for i, ci in enumerate(coef))
        out.append([float(rho), float(z)])
    return out


if __name__ == "__main__":
    doc = {
        "generator": "scripts/zmxref/qcon_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64), even_asphere geometry with the Qcon "
                  "departure expanded by scipy.special.jacobi",
        "lenses": {
            "qcon.zmx": {
                "wavelength_nm": 587.5618, "index": 1.5168,
                "sag_mm": {"front": sags(FRONT), "back": sags(BACK)},
                "rays": trace(lens(), rays(0.16 * IN * 0.999, 9), 0.5875618, 0.32 * IN)},
        },
    }
    print(json.dumps(doc))
