#!/usr/bin/env python
"""Reference GRIN ray traces with the goldengrape/optiland fork (numpy backend).

At the fork's HEAD the RK4 GRIN solver (optiland.propagation.grin.GRINPropagation ->
optiland.propagation.gradient_propagation.propagate_through_gradient) is NOT wired
into Optic.trace / SurfaceGroup.trace (GradientMaterial has no `propagation_model`,
so Optic.trace raises AttributeError).  This script therefore builds the lens with
the fork's Optic/SurfaceGroup (geometry, coordinate systems, materials), creates
RealRays directly at z = -1, and drives the surface sequence by hand:

  * air gaps + refraction at a surface: the fork's own Surface.trace (or, for the
    "local_index" mode at a GRIN boundary, the same pieces with the local index);
  * inside a GradientMaterial: GRINPropagation(step_size).propagate(rays, surface_in,
    exit_proxy), with the rays expressed in the frame of the surface where the medium
    starts (so the polynomial's z is measured from that surface's vertex) and the exit
    surface's geometry placed at its position relative to that vertex;
  * image plane: the fork's ImageSurface.trace.

Two boundary-refraction modes are computed:
  fork_native : exactly what the fork's components do: Snell at GRIN boundaries uses
                GradientMaterial.n(w) == n0 (position-independent).
  local_index : Snell at GRIN boundaries uses the local index n(x,y,z) at the hit point
                (evaluated with the fork's GradientMaterial.get_index in the medium's
                frame) and the fork's RealRays.refract.  The RK4 interior is identical.

Usage: venv/bin/python trace.py [--steps 1e-4 5e-5] [--out results.json]

Environment (2026-12-01): Python 3.11.7, numpy 2.4.6, the fork github:goldengrape/optiland at
a31216b87a0a642cd6627a8898c68a9f2582bc3a (optiland 0.6.0) installed with `pip install -e` in a
venv of its own. The stored tests/data/zemax/grin_optiland_fork.json keeps, of results.json,
the `local_index` rays' start point, start direction, image point, image direction cosines
and optical path (steps of 1e-5 mm; 2e-5 mm for the convergence figure).
"""
from __future__ import annotations

import argparse
import copy
import json
import subprocess
import sys
import time
import warnings

import numpy as np

import optiland
import optiland.backend as be
from optiland.coordinate_system import CoordinateSystem
from optiland.geometries.standard import StandardGeometry
from optiland.materials import GradientMaterial, IdealMaterial
from optiland.optic import Optic
from optiland.propagation.grin import GRINPropagation
from optiland.rays import RealRays

warnings.simplefilter("ignore", DeprecationWarning)
be.set_backend("numpy")

WL = 0.5875618  # um
FORK_GITDIR = "/work/.mirror/goldengrape+optiland/repo"


# ----------------------------------------------------------------------------- systems
def build_rod():
    air = IdealMaterial(n=1.0)
    grin = GradientMaterial(n0=1.6, nr2=-0.072)
    op = Optic()
    op.surfaces.add(index=0, thickness=np.inf, material=air)
    op.surfaces.add(index=1, thickness=5.0, material=grin, is_stop=True, aperture=10.0)
    op.surfaces.add(index=2, thickness=2.5, material=IdealMaterial(n=1.0), aperture=10.0)
    op.surfaces.add(index=3, material=IdealMaterial(n=1.0))  # image plane
    return op


def build_doublet():
    g1 = GradientMaterial(n0=1.6, nr2=-0.004, nr4=2e-5, nr6=0.0,
                          nz1=0.003, nz2=-0.0002, nz3=0.0, name="medium1")
    g2 = GradientMaterial(n0=1.65, nr2=-0.006, name="medium2")
    op = Optic()
    op.surfaces.add(index=0, thickness=np.inf, material=IdealMaterial(n=1.0))
    op.surfaces.add(index=1, thickness=2.0, material=IdealMaterial(n=1.0),
                    is_stop=True, aperture=4.0)
    op.surfaces.add(index=2, thickness=4.0, radius=20.0, material=g1, aperture=6.0)
    op.surfaces.add(index=3, thickness=3.0, radius=-30.0, material=g2, aperture=6.0)
    op.surfaces.add(index=4, thickness=7.4, radius=-40.0,
                    material=IdealMaterial(n=1.0), aperture=6.0)
    op.surfaces.add(index=5, material=IdealMaterial(n=1.0))  # image plane z = 16.4
    return op


ROD_STARTS = [(0, 0), (0.3, 0), (0, -0.7), (0.5, 0.6), (-1.1, 0.2)]
DOUBLET_STARTS = [(0, 0), (1, 0), (0, 1.9), (-1.2, 1.2), (0.7, -1.5)]
DIRS = [(0.0, 0.0, 1.0), (0.05, -0.02, 1.0), (-0.1, 0.08, 1.0)]


def make_rays(starts):
    pts, dirs, raw = [], [], []
    for (x, y) in starts:
        for d in DIRS:
            v = np.array(d, float)
            pts.append((float(x), float(y), -1.0))
            dirs.append(v / np.linalg.norm(v))
            raw.append(d)
    pts, dirs = np.array(pts), np.array(dirs)
    n = len(pts)
    rays = RealRays(x=pts[:, 0], y=pts[:, 1], z=pts[:, 2],
                    L=dirs[:, 0], M=dirs[:, 1], N=dirs[:, 2],
                    intensity=np.ones(n), wavelength=np.full(n, WL))
    rays.opd = np.zeros(n)
    return rays, pts, dirs, raw


# ----------------------------------------------------------------------------- helpers
def is_grin(m):
    return isinstance(m, GradientMaterial)


def translate(rays, dz):
    rays.translate(0.0, 0.0, dz)


class _ExitProxy:
    """Minimal stand-in for the exit surface: only `.geometry` is used by the solver."""

    def __init__(self, geometry):
        self.geometry = geometry


def exit_proxy(surface_in, surface_out):
    g = copy.deepcopy(surface_out.geometry)
    g.cs = CoordinateSystem(z=float(surface_out.geometry.cs.z - surface_in.geometry.cs.z))
    return _ExitProxy(g)


def local_index_at(rays, surf_medium_start, grin):
    """n(x,y,z) at the rays' current (global) positions, z from the medium's start vertex."""
    z0 = float(surf_medium_start.geometry.cs.z)
    # (GradientMaterial.get_index's icontract precondition is broken: TypeError, so use
    #  get_index_and_gradient, which is what the RK4 solver itself calls)
    n, _ = grin.get_index_and_gradient(be.copy(rays.x), be.copy(rays.y), rays.z - z0, WL)
    return n


def record(rays, tag, log):
    log.append({
        "after": tag,
        "x": be.to_numpy(rays.x).tolist(), "y": be.to_numpy(rays.y).tolist(),
        "z": be.to_numpy(rays.z).tolist(), "L": be.to_numpy(rays.L).tolist(),
        "M": be.to_numpy(rays.M).tolist(), "N": be.to_numpy(rays.N).tolist(),
        "opl": be.to_numpy(rays.opd).tolist(), "intensity": be.to_numpy(rays.i).tolist(),
    })


def trace_system(op, rays, step, mode, log):
    surfs = op.surfaces.surfaces
    grin_entry = None  # surface where the current GRIN medium starts
    for i in range(1, len(surfs)):
        s = surfs[i]
        pre, post = s.material_pre, s.material_post
        s.geometry.localize(rays)
        if is_grin(pre):
            # rays already on this surface (left there by the RK4 solver): no propagation
            if mode == "fork_native":
                rays = s.interaction_model.interact_real_rays(rays)
            else:
                nx, ny, nz = s.geometry.surface_normal(rays)
                s.geometry.globalize(rays)
                n1 = local_index_at(rays, grin_entry, pre)
                s.geometry.localize(rays)
                n2 = (local_index_at_local(rays, post) if is_grin(post) else post.n(rays.w))
                rays.refract(nx, ny, nz, n1, n2)
            if s.aperture:
                s.aperture.clip(rays)
        else:
            # homogeneous medium before this surface: the fork's own kernel
            t = s.geometry.distance(rays)
            pre.propagation_model.propagate(rays, t)
            rays.opd = rays.opd + be.abs(t * pre.n(rays.w))
            if s.aperture:
                s.aperture.clip(rays)
            if is_grin(post) and mode == "local_index":
                nx, ny, nz = s.geometry.surface_normal(rays)
                n2 = local_index_at_local(rays, post)
                rays.refract(nx, ny, nz, pre.n(rays.w), n2)
            else:
                rays = s.interaction_model.interact_real_rays(rays)
        s.geometry.globalize(rays)
        record(rays, f"surface {i}", log)

        if is_grin(post):
            grin_entry = s
            nxt = surfs[i + 1]
            z0 = float(s.geometry.cs.z)
            translate(rays, -z0)  # into the frame of the vertex where the medium starts
            model = GRINPropagation(step_size=step, max_steps=10_000_000)
            rays = model.propagate(rays, s, exit_proxy(s, nxt))
            translate(rays, z0)
            record(rays, f"GRIN {i}->{i+1} (before exit refraction)", log)
    return rays


def local_index_at_local(rays, grin):
    """Index at the rays' position when rays are in the local frame of the surface
    where `grin` starts (z = 0 at that vertex)."""
    n, _ = grin.get_index_and_gradient(be.copy(rays.x), be.copy(rays.y), be.copy(rays.z), WL)
    return n


# ----------------------------------------------------------------------------- main
def run_case(name, builder, starts, step, mode):
    op = builder()
    rays, pts, dirs, raw = make_rays(starts)
    log = []
    t0 = time.time()
    out = trace_system(op, rays, step, mode, log)
    dt = time.time() - t0
    res = []
    for k in range(len(pts)):
        res.append({
            "start_point": pts[k].tolist(),
            "start_direction_unnormalised": list(raw[k]),
            "start_direction": dirs[k].tolist(),
            "image_position": [float(out.x[k]), float(out.y[k]), float(out.z[k])],
            "image_direction_cosines": [float(out.L[k]), float(out.M[k]), float(out.N[k])],
            "opl_from_z_minus1_to_image": float(out.opd[k]),
            "intensity": float(out.i[k]),
            "surfaces": [{"after": e["after"],
                          "pos": [e["x"][k], e["y"][k], e["z"][k]],
                          "dir": [e["L"][k], e["M"][k], e["N"][k]],
                          "opl": e["opl"][k]} for e in log],
        })
    zs = [float(s.geometry.cs.z) for s in op.surfaces.surfaces[1:]]
    return res, dt, zs


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=float, nargs=2, default=[1e-4, 5e-5],
                    help="coarse and fine RK4 step (mm); fine should be coarse/2")
    ap.add_argument("--out", default="results.json")
    ap.add_argument("--modes", nargs="+", default=["local_index", "fork_native"])
    ap.add_argument("--merge", nargs="+", help="merge per-mode result files into --out")
    args = ap.parse_args()
    if args.merge:
        return merge(args.merge, args.out)
    h1, h2 = args.steps

    commit = subprocess.run(["git", f"--git-dir={FORK_GITDIR}", "rev-parse", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    cases = {"A_rod": (build_rod, ROD_STARTS), "B_doublet": (build_doublet, DOUBLET_STARTS)}
    results = {}
    timing = {}
    for cname, (builder, starts) in cases.items():
        results[cname] = {}
        for mode in args.modes:
            r1, dt1, zs = run_case(cname, builder, starts, h1, mode)
            r2, dt2, _ = run_case(cname, builder, starts, h2, mode)
            timing[f"{cname}/{mode}"] = [dt1, dt2]
            dpos = max(float(np.max(np.abs(np.subtract(a["image_position"], b["image_position"]))))
                       for a, b in zip(r1, r2))
            ddir = max(float(np.max(np.abs(np.subtract(a["image_direction_cosines"],
                                                       b["image_direction_cosines"]))))
                       for a, b in zip(r1, r2))
            dopl = max(abs(a["opl_from_z_minus1_to_image"] - b["opl_from_z_minus1_to_image"])
                       for a, b in zip(r1, r2))
            for a, b in zip(r1, r2):
                b["image_position_coarse_step"] = a["image_position"]
                b["image_direction_cosines_coarse_step"] = a["image_direction_cosines"]
                b["opl_coarse_step"] = a["opl_from_z_minus1_to_image"]
            results[cname][mode] = {
                "surface_vertex_z": zs,
                "rays": r2,
                "convergence_halving_step": {
                    "coarse_step_mm": h1, "fine_step_mm": h2,
                    "max_abs_change_image_position_mm": dpos,
                    "max_abs_change_direction_cosine": ddir,
                    "max_abs_change_opl_mm": dopl,
                },
            }
            print(f"{cname} {mode}: dpos={dpos:.3e} ddir={ddir:.3e} dopl={dopl:.3e} "
                  f"t=({dt1:.0f}s,{dt2:.0f}s)", flush=True)

    meta = {
        "engine": "goldengrape/optiland fork (GRIN RK4), numpy backend",
        "fork_commit": commit,
        "optiland_version": optiland.__version__,
        "numpy_version": np.__version__,
        "python": sys.version.split()[0],
        "wavelength_um": WL,
        "units": "mm",
        "reported_values_use_step_mm": h2,
        "convergence_reference_step_mm": h1,
        "rk4_step_meaning": "fixed arc-length step ds of the ray equation d(n dr/ds)/ds = grad n "
                            "(state r, k = n*dr/ds)",
        "grin_z_origin": "z measured from the vertex of the surface where the medium starts "
                         "(rays translated into that frame before calling the fork's solver)",
        "opl_definition": "RealRays.opd as accumulated by the fork: sum of |t|*n in air segments "
                          "(from the start plane z=-1) + trapezoid 0.5*(n_i+n_{i+1})*ds per RK4 "
                          "step inside GRIN, last partial step scaled linearly by (chord distance to "
                          "exit surface)/(chord length); ends on the image plane. Geometric optical "
                          "path length in mm, not a wavefront OPD (no reference sphere subtracted).",
        "modes": {
            "local_index": "Snell at GRIN boundaries with the local n(x,y,z) at the hit point "
                           "(physically standard; recommended reference)",
            "fork_native": "Snell at GRIN boundaries with GradientMaterial.n() == n0, as the fork's "
                           "Surface/interaction code does",
        },
        "timing_s": timing,
    }
    with open(args.out, "w") as f:
        json.dump({"metadata": meta, "cases": results}, f, indent=1)


def merge(files, out):
    """Merge result files produced by separate runs (e.g. one per mode, run in parallel)
    and attach the deviation from the independent DOP853 check (check_scipy.json)."""
    merged = None
    for fn in files:
        d = json.load(open(fn))
        if merged is None:
            merged = d
        else:
            for c, modes in d["cases"].items():
                merged["cases"].setdefault(c, {}).update(modes)
            merged["metadata"]["timing_s"].update(d["metadata"]["timing_s"])
    try:
        chk = json.load(open("check_scipy.json"))
        for c, modes in merged["cases"].items():
            for m, blk in modes.items():
                ref = chk[f"{c}/{m}"]
                R = blk["rays"]
                blk["deviation_from_independent_DOP853_check"] = {
                    "max_abs_image_position_mm": max(float(np.max(np.abs(np.subtract(
                        a["image_position"], b["pos"])))) for a, b in zip(R, ref)),
                    "max_abs_direction_cosine": max(float(np.max(np.abs(np.subtract(
                        a["image_direction_cosines"], b["cos"])))) for a, b in zip(R, ref)),
                    "max_abs_opl_mm": max(abs(a["opl_from_z_minus1_to_image"] - b["opl"])
                                          for a, b in zip(R, ref)),
                    "note": "check_scipy.py: independent adaptive DOP853 (rtol 1e-13) + exact "
                            "surface events, same boundary convention; not part of the fork",
                }
    except FileNotFoundError:
        pass
    with open(out, "w") as f:
        json.dump(merged, f, indent=1)


if __name__ == "__main__":
    main()
