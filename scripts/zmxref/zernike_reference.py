#!/usr/bin/env python3
"""Per-ray reference for tolray's Zernike sag surfaces (OpticStudio FZERNSAG and SZERNSAG),
traced by optiland.

Versions: optiland 0.6.3 (numpy backend, float64), Python 3.11. Generated once for the tolray
project (2026-11-30); tests read tests/data/zemax/zernike_reference.json and never run Python.

Usage (outside the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/zmxref/zernike_reference.py > tests/data/zemax/zernike_reference.json

optiland 0.6.3 does not read OpticStudio's Zernike sag surfaces, so the lenses are built here
from the files' numbers. Its ZernikePolynomialGeometry (`zernike_type` "fringe": OpticStudio's
Fringe terms up to Z36; "noll": OpticStudio's Standard) has a conic base but no r^2..r^16
terms, no Zernike decenter and refuses points beyond the normalization radius; the geometry
below (`ZernikeSag`) is optiland's NewtonRaphsonGeometry whose sag is the conic, the even
polynomial sum a_i r^(2i) and optiland's Zernike sum (a flat ZernikePolynomialGeometry, its
sag and normal taken at (x - dx, y - dy), its range check off: the terms extrapolated, as the
files ask), written independently of tolray:

- zernike.zmx: a hand-made singlet (tests/data/zemax/zernike.zmx): a Fringe front (17 of 36
  terms, normalization radius 6 mm), a Standard back (12 of 45 terms, r^4 and r^6 terms,
  decentred by (0.3, -0.2) mm, normalization radius 7 mm), constant index 1.5168.
- zernike-mirrors.zmx: the two Zernike Fringe Sag mirrors of F_07g_04_Blenda_PI_Zern_Real.zmx
  (YuryStrelkov/ZemaxUtils, commit e6f32068a807590468b2ca4f172d3d99ea32dc51): 8 terms each,
  the secondary with r^4..r^12 terms; rays start 20 mm before the primary's vertex (its rim
  lies 10 mm before it) in its annulus (85 to 175 mm).

optiland's Newton tolerance is set to 1e-15 mm.
"""
import json
import math
import warnings

import numpy as np
import optiland.backend as be
from optiland.geometries.newton_raphson import NewtonRaphsonGeometry
from optiland.geometries.zernike import ZernikePolynomialGeometry
from optiland.materials.ideal import IdealMaterial
from optiland.optic import Optic
from optiland.rays import RealRays

warnings.filterwarnings("ignore")
be.set_backend("numpy")
be.set_precision("float64")


class ZernikeSag(NewtonRaphsonGeometry):
    """Conic + sum a_i r^(2i) + optiland's Zernike sum centred at (dx, dy)."""

    def __init__(self, cs, radius, conic, alphas, terms, kind, norm_radius, decenter):
        super().__init__(cs, radius, conic, tol=1e-15, max_iter=100)
        coeffs = np.zeros(max(terms) if terms else 1)
        for j, a in terms.items():
            coeffs[j - 1] = a
        self.flat = ZernikePolynomialGeometry(cs, np.inf, 0.0, coefficients=coeffs,
                                              zernike_type=kind, norm_radius=norm_radius)
        self.flat._validate_inputs = lambda xn, yn: None
        self.alphas = alphas
        self.dx, self.dy = decenter
        self.is_symmetric = False

    def __str__(self):
        return "Zernike sag (reference)"

    def sag(self, x=0, y=0):
        r2 = x ** 2 + y ** 2
        z = r2 / (self.radius * (1 + be.sqrt(1 - (1 + self.k) * r2 / self.radius ** 2)))
        for i, a in enumerate(self.alphas):
            z = z + a * r2 ** (i + 1)
        return z + self.flat.sag(x - self.dx, y - self.dy)

    def _surface_normal(self, x, y):
        r2 = x ** 2 + y ** 2
        den = self.radius * be.sqrt(1 - (1 + self.k) * r2 / self.radius ** 2)
        g = 1.0 / den
        for i, a in enumerate(self.alphas):
            g = g + 2 * (i + 1) * a * r2 ** i
        nx, ny, nz = self.flat._surface_normal(x - self.dx, y - self.dy)
        dzdx = x * g - nx / nz
        dzdy = y * g - ny / nz
        n = be.sqrt(dzdx ** 2 + dzdy ** 2 + 1)
        return dzdx / n, dzdy / n, -be.ones_like(x) / n


def swap(op, index, **kw):
    s = op.surface_group.surfaces[index]
    s.geometry = ZernikeSag(s.geometry.cs, **kw)


def singlet():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    op.add_surface(index=1, thickness=2.0, is_stop=True)
    op.add_surface(index=2, radius=25.0, conic=-0.8, thickness=5.0,
                   material=IdealMaterial(n=1.5168))
    op.add_surface(index=3, radius=-60.0, conic=0.5, thickness=32.0)
    op.add_surface(index=4)
    swap(op, 2, radius=25.0, conic=-0.8, alphas=[], kind="fringe", norm_radius=6.0,
         decenter=(0.0, 0.0),
         terms={1: 0.001, 2: 0.002, 3: -0.001, 4: 0.02, 5: 0.005, 6: -0.003, 7: 0.002,
                8: -0.0015, 9: 0.004, 10: 0.001, 11: -0.0008, 13: 0.0005, 16: -0.0006,
                20: 0.0003, 25: -0.0002, 27: 0.0001, 36: 0.0001})
    swap(op, 3, radius=-60.0, conic=0.5, alphas=[0.0, -2e-5, 3e-7], kind="noll",
         norm_radius=7.0, decenter=(0.3, -0.2),
         terms={4: -0.01, 5: 0.002, 6: 0.001, 7: -0.001, 8: 0.0008, 11: 0.0015, 12: -0.0004,
                16: 0.0003, 22: 0.0002, 29: -0.0001, 37: 0.0001, 45: -5e-5})
    return op


def mirrors():
    op = Optic()
    op.add_surface(index=0, thickness=np.inf)
    r1 = 1.0 / -6.594044113963999600E-004
    r2 = 1.0 / -9.684142398008999600E-004
    op.add_surface(index=1, radius=r1, conic=-1.62726899808, thickness=-452.8,
                   material="mirror")
    op.add_surface(index=2, radius=r2, conic=-1.710157008158E+2, thickness=420.5,
                   material="mirror", is_stop=True)
    op.add_surface(index=3)
    swap(op, 1, radius=r1, conic=-1.62726899808, alphas=[], kind="fringe", norm_radius=72.5,
         decenter=(0.0, 0.0),
         terms={1: 1.79709711693646e-07, 2: -2.1907376192618002e-08, 3: 3.01255997867367e-12,
                4: -1.90276206580141e-07, 5: -1.61359060033201e-08, 6: 5.70762011431987e-12,
                7: 5.848777109006371e-09, 8: 2.6689531064756202e-12})
    swap(op, 2, radius=r2, conic=-1.710157008158E+2,
         alphas=[0.0, -1.782108052818E-8, 1.508139984834E-12, -1.362289706015E-16,
                 1.015416198607E-20, -3.996119986487E-25],
         kind="fringe", norm_radius=75.0, decenter=(0.0, 0.0),
         terms={1: 1.1818827991619301e-07, 2: 1.7906037620665103e-08, 3: 1.90411131438827e-12,
                4: -1.63664176493735e-07, 5: -1.0088245290930401e-08, 6: 7.08724985183732e-12,
                7: -2.11679434895916e-08, 8: 6.1276432914260805e-12})
    return op


def grid_rays(radius, n, inner, angles_deg, z0=-1.0):
    g = np.linspace(-radius, radius, n)
    pts = [(x, y) for x in g for y in g
           if inner ** 2 <= x * x + y * y <= radius ** 2 * (1 + 1e-12)]
    dirs = [(0.0, 0.0, 1.0)]
    a = math.radians(angles_deg[0])
    dirs.append((0.0, math.sin(a), math.cos(a)))
    t = math.tan(math.radians(angles_deg[1]))
    m = math.sqrt(2 * t * t + 1)
    dirs.append((t / m, t / m, 1 / m))
    return [(x, y, z0, *d) for d in dirs for (x, y) in pts]


def trace(op, rs, wl_um, epd):
    op.set_aperture(aperture_type="EPD", value=epd)
    op.set_field_type("angle")
    op.add_field(y=0.0)
    op.add_wavelength(value=wl_um, is_primary=True)
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
        "generator": "scripts/zmxref/zernike_reference.py",
        "engine": "optiland 0.6.3 (numpy, float64): NewtonRaphsonGeometry with the conic, the "
                  "even terms and ZernikePolynomialGeometry's Zernike sum (fringe, noll)",
        "lenses": {
            "zernike.zmx": {
                "wavelength_nm": 587.5618,
                "rays": trace(singlet(), grid_rays(3.9, 9, 0.0, (3.0, 2.0)), 0.5875618, 8.0)},
            "zernike-mirrors.zmx": {
                "wavelength_nm": 550.0,
                "rays": trace(mirrors(), grid_rays(175.0, 15, 85.0, (1.0, 2.5), -20.0), 0.55, 350.0)},
        },
    }
    print(json.dumps(doc))
