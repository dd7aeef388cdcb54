#!/usr/bin/env python3
"""tolray against optiland in one run: the same rays through the same lens files.

Nothing in tolray runs this; it measures. Per lens file, one seeded beam of N rays (uniform on the
paraxial entrance-pupil disk, a field angle of a quarter of the file's largest, the primary wavelength,
every ray starting 10 mm before the first vertex) is traced to the image surface

  * by optiland (numpy backend, `SurfaceGroup.trace(rays, skip=1, record=False)`, apertures
    removed), in this process, and
  * by tolray through its C ABI (`tolray_trace` of libtolray.so via ctypes, flags 0: no
    apertures, f64), in child processes of this script with RAYON_NUM_THREADS=1 and =2, which
    trace the identical ray arrays (written once to a temporary .npy file).

Both report the best of `--repeat` wall times; throughput is rays x surfaces / time, where the
surfaces are optiland's surfaces after the object (the image included), the same count for both.
The positions on the image surface are compared ray by ray (rays that arrive in both).

Usage (from the repository root, after `cargo build --release`):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/bench/speed_vs_optiland.py [--rays 1000000] [--repeat 3]
"""
from __future__ import annotations

import argparse
import contextlib
import ctypes
import io
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The beam's field angle as a fraction of the file's largest: small enough that every ray stays
# inside every clear semi-diameter (no ray needs apertures to be meaningful).
FIELD_FRACTION = 0.25
FILES = [
    "tests/data/zemax/real/optiland/lens1.zmx",
    "tests/data/zemax/real/rayoptics/US00583336-2-scaled.zmx",
]


class RaysIn(ctypes.Structure):
    _fields_ = [(k, ctypes.POINTER(ctypes.c_double)) for k in ("x", "y", "z", "dx", "dy", "dz")]


class RaysOut(ctypes.Structure):
    _fields_ = [(k, ctypes.POINTER(ctypes.c_double)) for k in ("x", "y", "z", "dx", "dy", "dz", "opl")] + [
        ("status", ctypes.POINTER(ctypes.c_uint32))
    ]


def ptr(a):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def tolray_child(lib_path, zmx, npy, wavelength_nm, repeat):
    """Traces the rays in `npy` with libtolray; prints JSON (best time, positions file)."""
    lib = ctypes.CDLL(lib_path)
    lens = ctypes.c_void_p()
    st = lib.tolray_lens_load(zmx.encode(), ctypes.byref(lens))
    if st != 0:
        lib.tolray_last_error.restype = ctypes.c_char_p
        raise SystemExit(f"tolray_lens_load {zmx}: status {st}: {lib.tolray_last_error()}")
    system = ctypes.c_void_p()
    st = lib.tolray_system_new(lens, None, ctypes.byref(system))
    if st != 0:
        raise SystemExit(f"tolray_system_new: status {st}")
    r = np.load(npy)
    n = r.shape[1]
    cols = [np.ascontiguousarray(r[k]) for k in range(6)]
    rin = RaysIn(*[ptr(c) for c in cols])
    out = [np.empty(n) for _ in range(7)]
    status = np.empty(n, np.uint32)
    rout = RaysOut(*[ptr(o) for o in out], status.ctypes.data_as(ctypes.POINTER(ctypes.c_uint32)))
    lib.tolray_trace.argtypes = [
        ctypes.c_void_p,
        ctypes.c_double,
        ctypes.c_uint32,
        ctypes.c_size_t,
        ctypes.POINTER(RaysIn),
        ctypes.POINTER(RaysOut),
    ]
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        st = lib.tolray_trace(system, wavelength_nm, 0, n, ctypes.byref(rin), ctypes.byref(rout))
        best = min(best, time.perf_counter() - t)
        if st != 0:
            raise SystemExit(f"tolray_trace: status {st}")
    res = npy.replace(".npy", f"-tolray-{os.environ.get('RAYON_NUM_THREADS', 'all')}.npy")
    np.save(res, np.stack([out[0], out[1], status.astype(float)]))
    print(json.dumps({"seconds": best, "result": res}))


def optiland_optic(path):
    from optiland.fileio import load_zemax_file

    with contextlib.redirect_stdout(io.StringIO()):
        op = load_zemax_file(path)
    for s in op.surfaces:
        s.aperture = None
    return op


def first_vertex_z(op, wl_um):
    """z (optiland's frame) of the first surface that bends light: tolray's frame has its vertex
    at 0 (tolray keeps no leading dummy surface; optiland keeps the file's)."""
    import optiland.backend as be

    f = lambda v: float(np.asarray(be.to_numpy(v)).ravel()[0])
    for sf in op.surfaces[1:]:
        flat = type(sf.geometry).__name__ == "Plane"
        if not flat or f(sf.material_pre.n(wl_um)) != f(sf.material_post.n(wl_um)):
            return f(sf.geometry.cs.z)
    raise SystemExit("no surface bends light")


def beam(op, n, seed, z0):
    """Rays in tolray's frame (first vertex at z = 0; `z0` is that vertex in optiland's):
    origins and unit directions, 6 x n."""
    import optiland.backend as be

    f = lambda v: float(np.asarray(be.to_numpy(v)).ravel()[0])
    # EPL is measured from optiland's first surface after the object.
    epd = f(op.paraxial.EPD())
    epl = f(op.paraxial.EPL()) + f(op.surfaces[1].geometry.cs.z) - z0
    ymax = max(abs(float(fl.y)) for fl in op.fields.fields)
    t = math.radians(FIELD_FRACTION * ymax)
    rng = np.random.default_rng(seed)
    r = 0.5 * epd * np.sqrt(rng.random(n))
    a = 2 * math.pi * rng.random(n)
    px, py = r * np.cos(a), r * np.sin(a)
    d = np.array([0.0, math.sin(t), math.cos(t)])
    # Back from the pupil point to the plane 10 mm before the first vertex.
    s = (epl + 10.0) / d[2]
    x, y, z = px - s * d[0], py - s * d[1], np.full(n, -10.0)
    return np.stack([x, y, z, np.full(n, d[0]), np.full(n, d[1]), np.full(n, d[2])]), math.degrees(t)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lib", default=os.path.join(ROOT, "target/release/libtolray.so"))
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("files", nargs="*", default=[os.path.join(ROOT, f) for f in FILES])
    ap.add_argument("--child", nargs=4, metavar=("ZMX", "NPY", "WL_NM", "REPEAT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        tolray_child(a.lib, a.child[0], a.child[1], float(a.child[2]), int(a.child[3]))
        return
    from optiland.rays import RealRays
    import optiland.backend as be

    tmp = tempfile.mkdtemp(prefix="tolray-vs-optiland-")
    rows = []
    for path in a.files:
        op = optiland_optic(path)
        wl_um = float(op.primary_wavelength)
        z1 = first_vertex_z(op, wl_um)
        rays, angle = beam(op, a.rays, a.seed, z1)
        npy = os.path.join(tmp, os.path.basename(path) + ".npy")
        np.save(npy, rays)
        # Surfaces traced: those from the first that bends light to the image (tolray's count
        # with the image plane); optiland also traces the file's leading dummies, uncounted.
        surfaces = sum(1 for sf in op.surfaces[1:]
                       if float(np.asarray(be.to_numpy(sf.geometry.cs.z)).ravel()[0]) >= z1)
        best = math.inf
        for _ in range(a.repeat):
            rr = RealRays(rays[0], rays[1], rays[2] + z1, rays[3], rays[4], rays[5], np.ones(a.rays),
                          np.full(a.rays, wl_um))
            t = time.perf_counter()
            rr = op.surfaces.trace(rr, skip=1, record=False)
            best = min(best, time.perf_counter() - t)
        ox = np.asarray(be.to_numpy(rr.x), float)
        oy = np.asarray(be.to_numpy(rr.y), float)
        row = {"file": os.path.relpath(path, ROOT), "rays": a.rays, "surfaces": surfaces,
               "field_deg": angle, "wavelength_nm": wl_um * 1000, "optiland_s": best}
        for threads in (1, 2):
            env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
            out = subprocess.run(
                [sys.executable, __file__, "--lib", a.lib, "--child", path, npy, str(wl_um * 1000),
                 str(a.repeat)],
                env=env, check=True, capture_output=True, text=True).stdout
            res = json.loads(out.strip().splitlines()[-1])
            row[f"tolray_{threads}t_s"] = res["seconds"]
            tx, ty, status = np.load(res["result"])
        ok = (status == 0) & np.isfinite(ox) & np.isfinite(oy)
        row["arrived_both"] = int(ok.sum())
        row["max_dev_mm"] = (float(max(np.abs(tx[ok] - ox[ok]).max(), np.abs(ty[ok] - oy[ok]).max()))
                             if ok.any() else math.nan)
        rows.append(row)
    import optiland

    print(f"optiland {getattr(optiland, '__version__', '0.6.3')} (numpy {np.__version__}), "
          f"libtolray {a.lib}; best of {a.repeat}; {a.rays} rays per file")
    print(f"{'file':58} {'surf':>4} {'optiland':>16} {'tolray 1 thread':>22} {'tolray 2 threads':>22} {'max |dev| mm':>13}")
    for r in rows:
        rs = r["rays"] * r["surfaces"]
        cell = lambda s: f"{s * 1e3:8.1f} ms {rs / s / 1e6:6.1f} M"
        print(f"{r['file']:58} {r['surfaces']:4} {cell(r['optiland_s']):>16} "
              f"{cell(r['tolray_1t_s']):>22} {cell(r['tolray_2t_s']):>22} {r['max_dev_mm']:13.1e}")
        print(f"{'':58}      speed-up: {r['optiland_s'] / r['tolray_1t_s']:.0f}x on 1 thread, "
              f"{r['optiland_s'] / r['tolray_2t_s']:.0f}x on 2; {r['arrived_both']} rays arrived in both")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
