#!/usr/bin/env python3
"""tolray against DeepLens (PyPI `deeplens-core`, PyTorch on the CPU) in one run: the same work
on the same lens.

Nothing in tolray runs this (no test, no CI job); it measures. The lens is one tolray opens by
name or path (default: the built-in `lens1`, the paper's lens); tolray writes it as DeepLens
JSON (`tolray_lens_to_json`) and DeepLens reads that file (`GeoLens(file, dtype=...)`), so both
hold the same prescription. Two adjustments to DeepLens' copy, both printed and recorded:

  * Index match (turn off with --no-index-match). A model glass "n_d/V_d" is a two-term Cauchy
    law in both tools, but DeepLens puts n_d at 587.6 nm and tolray at 587.5618 nm, so at the
    traced primary wavelength DeepLens' are higher by 2e-6 to 3.4e-6 (lens1), which moves image
    points by about 2e-6 mm. The script sets DeepLens' Cauchy A so that its index at the
    primary wavelength is n_d, as tolray's is; then the f64 traces agree to about 1e-10 mm
    (both deviations are reported). The cost of the trace does not change.
  * Paraxial entrance pupil for DeepLens' PSFs. DeepLens samples PSF rays over its real-ray
    entrance pupil; for lens1 that search fails ("No intersection points found, use the first
    surface as entrance pupil") and it would sample surface 0's disk (radius 9.5 mm; the
    paraxial entrance pupil's radius is 6.44 mm, so the stop blocks roughly half). The script gives it its own paraxial entrance pupil, which is what
    tolray samples (same number of rays traced either way).

Compared, each as best of --repeat wall times with 1 and 2 threads (torch.set_num_threads for
DeepLens in this process; tolray in child processes with RAYON_NUM_THREADS):

1. Ray tracing. One seeded beam of --rays rays (uniform on the paraxial entrance-pupil disk, an
   object point at --field of the sensor's half-diagonal, the primary wavelength, starting on the
   plane 10 mm before the first vertex) traced to the image plane, with clear apertures clipping:
   DeepLens `GeoLens.trace2sensor(Ray(o, d, wvln))` under torch.no_grad() in float32 (its
   default) and float64 (Ray construction not timed), and tolray `tolray_trace` (f64, flag
   TOLRAY_TRACE_APERTURES). Throughput = rays x surfaces / time, surfaces = the lens' surfaces
   plus the image plane. The image-plane x, y are compared ray by ray over rays that arrive in
   both, and the arrival sets are compared.
2. PSF map. --grid x --grid fields, --ks x --ks kernels at the sensor pitch, --spp rays per PSF,
   one wavelength (primary), chief-ray centred, bilinear splat, unit sum: DeepLens
   `GeoLens.psf_map(grid, ks, spp)` (all fields in one batch; float32 and float64) and tolray
   `tolray_psf` once per field (f64; each call traces serially, so the child runs the fields on
   a thread pool of 1 or 2 threads), at DeepLens' own field points (its `point_source_grid`, as
   object heights). Also `tolray psf-map` (the CLI: f32 tracing, rayon over fields, at the cell
   centres of the grid) as whole-process wall time, with `tolray info` as the process baseline.
   Sameness: per field, the PSFs' centroids and RMS widths (pixels), and the L1 distance between
   the two tools' PSFs next to the L1 distance between two tolray PSFs of different seeds (the
   Monte Carlo noise floor).
3. Rendering. A --image x --image RGB float32 image (seeded uniform noise) blurred by a
   --grid x --grid map of RGB --ks kernels (each tile by its own PSF, halo from the
   reflect-padded image, no blending: the same scheme in both): DeepLens
   `imgsim.psf.conv_psf_map` (direct F.conv2d per tile) on a precomputed map (convolution only)
   and `GeoLens.render_psf_map` (`psf_map_rgb` + conv_psf_map; `render(method="psf_map")` would
   also warp the image for distortion and needs the sensor's resolution, so it is not used),
   against `tolray_render` (RGB PSF map traced in f32 + FFT convolution per tile; noise 0).
   The C ABI has no convolution-only call; `tolray_render` with 512 rays per PSF (1/16 of the
   rays: the PSFs then cost a few ms) stands for the convolution alone. DeepLens' RGB map
   traces two bundles of --spp rays per field and colour (the colour's, and one at the primary
   wavelength for the shared chief-ray centre); tolray traces one (and its chief ray). Sameness:
   the PSFs tolray_render uses (read back by rendering an image with one lit pixel per tile)
   fed to DeepLens' conv_psf_map give tolray_render's image (max |diff|; the same PSFs rotated
   by 180 degrees are the control that shows the check can fail).

Other differences (the README next to results.json lists them): DeepLens' chief ray is the
sampled ray nearest the stop centre and its three colours share the primary one; tolray's is
the ray through the paraxial entrance pupil's centre, one per colour. tolray's render PSFs sit
at the cell centres of the grid, DeepLens' map at its point_source_grid (+-(1 - 1/(2 (grid -
1)))). The random pupil samples differ (torch's generator vs ChaCha8).

The machine's other load is recorded (load averages, and the share of all CPU time that other
processes used during the run, from /proc/stat): the numbers mean something only when it is
near 0. --source names the git tree the library was built from (for the commit recorded).

Usage (from the repository root; DeepLens 2.5.x needs Python 3.12):
    cargo build --release                      # libtolray.so and the tolray CLI
    python3.12 -m venv /tmp/dlvenv
    /tmp/dlvenv/bin/pip install torch deeplens-core==2.5.6   # torch from PyPI (CUDA wheels, CPU used)
    /tmp/dlvenv/bin/python scripts/bench/speed_vs_deeplens.py [--lens lens1] [--rays 1000000] \\
        [--repeat 3] [--out validation/speed-vs-deeplens/results.json]
"""
from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import ctypes
import io
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

TRACE_APERTURES = 1
FIELD_FRACTION, FIELD_ANGLE_DEG, FIELD_HEIGHT_MM = 0, 1, 2
PUPIL_RANDOM = 2
CENTRE_CHIEF = 0
# Rays per PSF of the render that stands for tolray's convolution alone (fewer can leave a
# strongly blurred corner PSF of lens1 with no ray in its window, which tolray refuses).
FEW_RAYS = 512


# ---------------------------------------------------------------------------------------------
# tolray's C ABI (include/tolray.h)
# ---------------------------------------------------------------------------------------------
class RaysIn(ctypes.Structure):
    _fields_ = [(k, ctypes.POINTER(ctypes.c_double)) for k in ("x", "y", "z", "dx", "dy", "dz")]


class RaysOut(ctypes.Structure):
    _fields_ = [(k, ctypes.POINTER(ctypes.c_double)) for k in ("x", "y", "z", "dx", "dy", "dz", "opl")] + [
        ("status", ctypes.POINTER(ctypes.c_uint32))
    ]


class Paraxial(ctypes.Structure):
    _fields_ = [(k, ctypes.c_double) for k in (
        "wavelength_nm", "efl_mm", "bfd_mm", "image_distance_mm", "entrance_pupil_z_mm",
        "entrance_pupil_diameter_mm", "exit_pupil_z_mm", "exit_pupil_diameter_mm", "fnum",
        "working_fnum", "magnification", "half_fov_deg", "total_track_mm")] + [
        ("stop_surface", ctypes.c_uint32), ("num_surfaces", ctypes.c_uint32)]


class Field(ctypes.Structure):
    _fields_ = [("kind", ctypes.c_uint32), ("x", ctypes.c_double), ("y", ctypes.c_double)]


class Pupil(ctypes.Structure):
    _fields_ = [("pattern", ctypes.c_uint32), ("n", ctypes.c_uint32), ("seed", ctypes.c_uint64),
                ("scale", ctypes.c_double), ("aim", ctypes.c_uint32)]


class PsfOptions(ctypes.Structure):
    _fields_ = [("kernel_px", ctypes.c_uint32), ("pitch_mm", ctypes.c_double),
                ("centre", ctypes.c_uint32), ("pupil", Pupil)]


def ptr(a, t=ctypes.c_double):
    return a.ctypes.data_as(ctypes.POINTER(t))


class Tolray:
    """The few tolray calls the benchmark needs, on one lens."""

    def __init__(self, lib_path, lens_name):
        self.lib = lib = ctypes.CDLL(lib_path)
        lib.tolray_last_error.restype = ctypes.c_size_t
        lib.tolray_trace.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_uint32, ctypes.c_size_t,
                                     ctypes.POINTER(RaysIn), ctypes.POINTER(RaysOut)]
        lib.tolray_psf.argtypes = [ctypes.c_void_p, ctypes.POINTER(Field), ctypes.c_double,
                                   ctypes.POINTER(PsfOptions), ctypes.POINTER(ctypes.c_double), ctypes.c_size_t]
        lib.tolray_render.argtypes = [ctypes.c_void_p, ctypes.POINTER(PsfOptions), ctypes.c_uint32,
                                      ctypes.c_double, ctypes.c_uint64, ctypes.c_uint32, ctypes.c_uint32,
                                      ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_float),
                                      ctypes.c_size_t]
        lib.tolray_lens_paraxial.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.POINTER(Paraxial)]
        self.lens = ctypes.c_void_p()
        self.check(lib.tolray_lens_load(lens_name.encode(), ctypes.byref(self.lens)), "tolray_lens_load")
        self.sys = ctypes.c_void_p()
        self.check(lib.tolray_system_new(self.lens, None, ctypes.byref(self.sys)), "tolray_system_new")

    def check(self, st, what):
        if st != 0:
            buf = ctypes.create_string_buffer(2000)
            self.lib.tolray_last_error(buf, ctypes.c_size_t(2000))
            raise SystemExit(f"{what}: status {st}: {buf.value.decode()}")

    def json(self):
        n = ctypes.c_size_t()
        self.check(self.lib.tolray_lens_to_json(self.lens, None, ctypes.c_size_t(0), ctypes.byref(n)),
                   "tolray_lens_to_json")
        buf = ctypes.create_string_buffer(n.value + 1)
        self.check(self.lib.tolray_lens_to_json(self.lens, buf, ctypes.c_size_t(n.value + 1), ctypes.byref(n)),
                   "tolray_lens_to_json")
        return json.loads(buf.value.decode())

    def paraxial(self, wl_nm):
        p = Paraxial()
        self.check(self.lib.tolray_lens_paraxial(self.lens, wl_nm, ctypes.byref(p)), "tolray_lens_paraxial")
        return {k: getattr(p, k) for k, _ in Paraxial._fields_}

    def psf_options(self, ks, spp, seed):
        o = PsfOptions()
        self.check(self.lib.tolray_psf_options_default(self.sys, ctypes.byref(o)), "tolray_psf_options_default")
        o.kernel_px, o.centre = ks, CENTRE_CHIEF
        o.pupil = Pupil(PUPIL_RANDOM, spp, seed, 1.0, 0)
        return o

    def trace(self, rays, wl_nm, flags):
        n = rays.shape[1]
        cols = [np.ascontiguousarray(rays[k]) for k in range(6)]
        rin = RaysIn(*[ptr(c) for c in cols])
        out = [np.empty(n) for _ in range(7)]
        status = np.empty(n, np.uint32)
        rout = RaysOut(*[ptr(o) for o in out], ptr(status, ctypes.c_uint32))

        def run():
            self.check(self.lib.tolray_trace(self.sys, wl_nm, flags, n, ctypes.byref(rin), ctypes.byref(rout)),
                       "tolray_trace")
            return out, status
        return run

    def psf(self, field, wl_nm, opts):
        ks = opts.kernel_px
        out = np.empty(ks * ks)
        self.check(self.lib.tolray_psf(self.sys, ctypes.byref(field), wl_nm, ctypes.byref(opts), ptr(out),
                                       out.size), "tolray_psf")
        return out.reshape(ks, ks)

    def render(self, img, opts, grid):
        c, h, w = img.shape
        src = np.ascontiguousarray(img, np.float32)
        out = np.empty_like(src)
        self.check(self.lib.tolray_render(self.sys, ctypes.byref(opts), grid, 0.0, 0, w, h,
                                          ptr(src, ctypes.c_float), ptr(out, ctypes.c_float), out.size),
                   "tolray_render")
        return out


def cpu_jiffies():
    """(busy, total) jiffies of the whole machine from /proc/stat (None where unavailable)."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
        idle = v[3] + (v[4] if len(v) > 4 else 0)
        return sum(v) - idle, sum(v)
    except (OSError, ValueError, IndexError):
        return None


def best_of(repeat, fn):
    best, res = math.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        res = fn()
        best = min(best, time.perf_counter() - t)
    return best, res


def tolray_child(a, task):
    """All tolray work for one thread count (RAYON_NUM_THREADS set by the parent); prints JSON."""
    threads = int(os.environ["RAYON_NUM_THREADS"])
    t = Tolray(a.lib, a.lens)
    tmp = task["tmp"]
    res = {}
    # 1. Trace.
    rays = np.load(os.path.join(tmp, "rays.npy"))
    res["trace_s"], (out, status) = best_of(a.repeat, t.trace(rays, task["wl_nm"], TRACE_APERTURES))
    np.save(os.path.join(tmp, f"trace-tolray-{threads}.npy"), np.stack([out[0], out[1], status.astype(float)]))
    # 2. PSF map: tolray_psf per field at DeepLens' field points, on a pool of `threads` threads.
    fields = [Field(task["field_kind"], x, y) for x, y in task["psf_fields"]]
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=threads)

    def psf_map(seed):
        opts = t.psf_options(a.ks, a.spp, seed)
        return np.stack(list(pool.map(lambda f: t.psf(f, task["wl_nm"], opts), fields)))
    res["psf_map_s"], m = best_of(a.repeat, lambda: psf_map(0))
    np.save(os.path.join(tmp, f"psf-tolray-{threads}.npy"), m)
    if threads == 1:
        np.save(os.path.join(tmp, "psf-tolray-seed1.npy"), psf_map(1))
    pool.shutdown()
    # 3. Render: the full call, and with FEW_RAYS rays per PSF (the convolution; PSFs nearly free).
    img = np.load(os.path.join(tmp, "image.npy"))
    res["render_s"], y = best_of(a.repeat, lambda: t.render(img, t.psf_options(a.ks, a.spp, 0), a.grid))
    res["render_few_rays_s"], _ = best_of(a.repeat, lambda: t.render(img, t.psf_options(a.ks, FEW_RAYS, 0), a.grid))
    if threads == 1 and min(img.shape[1:]) // a.grid >= a.ks:  # each kernel fits in its tile
        np.save(os.path.join(tmp, "render-tolray.npy"), y)
        # The PSFs tolray_render uses (f32 tracing), read back by rendering an image of one lit
        # pixel at the centre of each tile (a tile is far larger than a kernel), for DeepLens'
        # convolution (sameness check); and the same PSFs from tolray_psf (f64) for comparison.
        opts = t.psf_options(a.ks, a.spp, 0)
        c, hh, ww = img.shape
        g, h = a.grid, a.ks // 2
        centres = [(((2 * r + 1) * hh) // (2 * g), ((2 * q + 1) * ww) // (2 * g)) for r in range(g) for q in range(g)]
        imp = np.zeros_like(img)
        for r0, q0 in centres:
            imp[:, r0, q0] = 1.0
        y_imp = t.render(imp, opts, g)
        used = np.array([y_imp[:, r0 - h:r0 + h + 1, q0 - h:q0 + h + 1] for r0, q0 in centres])
        np.save(os.path.join(tmp, "render-psfs-tolray.npy"), used)
        rgb = [[t.psf(Field(FIELD_FRACTION, x, yy), wl, opts) for wl in task["rgb_nm"]]
               for x, yy in task["render_fields"]]
        np.save(os.path.join(tmp, "render-psfs-tolray-f64.npy"), np.array(rgb))
    print(json.dumps(res))


# ---------------------------------------------------------------------------------------------
# DeepLens side
# ---------------------------------------------------------------------------------------------
def deeplens_lens(path, dtype, index_match, paraxial_pupil):
    from deeplens import GeoLens

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        L = GeoLens(path, dtype=dtype)
    notes = {"load_messages": [s for s in buf.getvalue().splitlines() if s.strip()],
             "real_entrance_pupil": [float(L.entr_pupilz), float(L.entr_pupilr)],
             "paraxial_entrance_pupil": [float(L.entr_pupilz_parax), float(L.entr_pupilr_parax)]}
    wl_nm = round(L.primary_wvln * 1000.0, 9)
    if index_match:
        dn = []
        for s in L.surfaces:
            m = s.mat2
            if getattr(m, "dispersion", None) == "cauchy":
                before = m.A + m.B / wl_nm**2
                m.A = m.n - m.B / wl_nm**2
                dn.append(m.n - before)
        notes["index_match_dn"] = dn
    if paraxial_pupil:
        L.entr_pupilz, L.entr_pupilr = L.entr_pupilz_parax, L.entr_pupilr_parax
    return L, notes


def beam(lens_json, para, n, seed, field):
    """Seeded rays from an object point at `field` x the sensor half-diagonal (image side,
    paraxially) through uniform points of the paraxial entrance-pupil disk, starting on the
    plane z = -10 mm (first vertex at 0). Returns 6 x n (origins, unit directions)."""
    r_ep = 0.5 * para["entrance_pupil_diameter_mm"]
    z_ep = para["entrance_pupil_z_mm"]
    tan_y = field * lens_json["r_sensor"] / para["efl_mm"]
    rng = np.random.default_rng(seed)
    r = r_ep * np.sqrt(rng.random(n))
    a = 2 * math.pi * rng.random(n)
    px, py = r * np.cos(a), r * np.sin(a)
    depth = object_distance(lens_json)
    if depth is None:  # parallel rays toward -y, as an object above the axis
        d = np.array([0.0, -tan_y, 1.0]) / math.hypot(tan_y, 1.0)
        d = np.repeat(d[:, None], n, axis=1)
    else:
        obj = np.array([0.0, depth * tan_y, -depth])
        d = np.stack([px - obj[0], py - obj[1], np.full(n, z_ep) - obj[2]])
        d /= np.linalg.norm(d, axis=0)
    s = (z_ep + 10.0) / d[2]
    o = np.stack([px, py, np.full(n, z_ep)]) - s * d
    o[2] = -10.0
    return np.concatenate([o, d])


def object_distance(lens_json):
    if str(lens_json.get("(object)", "")).lower() == "inf" or "obj_depth" not in lens_json:
        return None
    return abs(float(lens_json["obj_depth"]))


def psf_stats(m):
    """Per PSF (n x ks x ks): centroid (col, row) and RMS radius, pixels."""
    n, ks, _ = m.shape
    yy, xx = np.mgrid[0:ks, 0:ks]
    s = m.sum(axis=(1, 2))
    cx = (m * xx).sum(axis=(1, 2)) / s
    cy = (m * yy).sum(axis=(1, 2)) / s
    rms = np.sqrt((m * ((xx - cx[:, None, None]) ** 2 + (yy - cy[:, None, None]) ** 2)).sum(axis=(1, 2)) / s)
    return cx, cy, rms


def render_sameness(tmp, g, ks, img_t, conv_psf_map):
    """DeepLens' conv_psf_map on the PSFs tolray_render used, against tolray_render's image."""
    import torch

    rp = np.load(os.path.join(tmp, "render-psfs-tolray.npy"))  # [g*g, 3, ks, ks], f32 as rendered
    rp64 = np.load(os.path.join(tmp, "render-psfs-tolray-f64.npy"))
    tmap = torch.from_numpy(rp.reshape(g, g, 3, ks, ks).astype(np.float32))
    with torch.no_grad():
        y_dl = conv_psf_map(img_t, tmap)[0].numpy()
    y_t = np.load(os.path.join(tmp, "render-tolray.npy"))
    # Control: the same PSFs rotated by 180 degrees (a wrong orientation) differ by this much.
    with torch.no_grad():
        y_rot = conv_psf_map(img_t, torch.flip(tmap, dims=(-2, -1)))[0].numpy()
    d = np.abs(y_dl - y_t)
    d_rot = np.abs(y_rot - y_t)
    d_psf = np.abs(rp - rp64)
    return {
        "max_abs_diff": float(d.max()),
        "mean_abs_diff": float(d.mean()),
        "control_psfs_rotated_max_abs_diff": float(d_rot.max()),
        "control_psfs_rotated_mean_abs_diff": float(d_rot.mean()),
        "image_mean": float(y_t.mean()),
        "render_psfs_sum": [float(rp.sum(axis=(2, 3)).min()), float(rp.sum(axis=(2, 3)).max())],
        "render_psfs_peak": float(rp.max()),
        # Per PSF, the largest |difference| between tolray_render's f32 PSF and tolray_psf's f64
        # one (same rays): median over PSFs (rounding) and maximum (a ray or two that lands in
        # another pixel, or leaves the window, in f32).
        "render_psfs_f32_vs_f64_median_max_abs_diff": float(np.median(d_psf.max(axis=(2, 3)))),
        "render_psfs_f32_vs_f64_max_abs_diff": float(d_psf.max()),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lib", default=os.path.join(ROOT, "target/release/libtolray.so"))
    ap.add_argument("--cli", default=None, help="tolray binary (default: next to --lib)")
    ap.add_argument("--source", default=ROOT, help="git tree --lib was built from (for the commit recorded)")
    ap.add_argument("--lens", default="lens1", help="built-in name or file tolray opens")
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--field", type=float, default=0.7, help="beam field, fraction of the half-diagonal")
    ap.add_argument("--grid", type=int, default=8)
    ap.add_argument("--ks", type=int, default=51)
    ap.add_argument("--spp", type=int, default=8192)
    ap.add_argument("--image", type=int, default=2048)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--no-index-match", action="store_true")
    ap.add_argument("--out", default=None, help="write the results JSON here")
    ap.add_argument("--keep-tmp", action="store_true", help="keep the temporary folder of arrays")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        with open(a.child) as f:
            tolray_child(a, json.load(f))
        return
    t_start = time.perf_counter()
    load_before = os.getloadavg()
    jiffies_before = cpu_jiffies()
    import torch
    from importlib.metadata import version
    from deeplens.imgsim.psf import conv_psf_map

    threads = [int(x) for x in a.threads.split(",")]
    cli = a.cli or os.path.join(os.path.dirname(os.path.abspath(a.lib)), "tolray")
    tmp = tempfile.mkdtemp(prefix="tolray-vs-deeplens-")
    tol = Tolray(a.lib, a.lens)
    lens_json = tol.json()
    lens_path = os.path.join(tmp, "lens.json")
    with open(lens_path, "w") as f:
        json.dump(lens_json, f)
    wl_nm = round(1000.0 * float(lens_json["primary_wvln"]), 9)
    rgb_nm = [round(1000.0 * w, 9) for w in lens_json["wvln_rgb"]]
    para = tol.paraxial(wl_nm)
    n_surf = len(lens_json["surfaces"]) + 1
    depth = object_distance(lens_json)
    lenses = {}
    for name, dt in (("f32", torch.float32), ("f64", torch.float64)):
        lenses[name] = deeplens_lens(lens_path, dt, not a.no_index_match, True)
    notes = lenses["f64"][1]
    print(f"lens {a.lens}: {n_surf - 1} surfaces + image; DeepLens load: {notes['load_messages']}; "
          f"index match at {wl_nm} nm: dn = {notes.get('index_match_dn')}", file=sys.stderr)

    # Shared inputs.
    rays = beam(lens_json, para, a.rays, a.seed, a.field)
    np.save(os.path.join(tmp, "rays.npy"), rays)
    L64 = lenses["f64"][0]
    pts = L64.point_source_grid(depth=L64.obj_depth, grid=(a.grid, a.grid)).reshape(-1, 3).numpy()
    scale = float(L64.calc_scale(L64.obj_depth))
    sw, sh = L64.sensor_size
    if depth is not None:
        psf_fields = [(float(p[0] * scale * sw / 2), float(p[1] * scale * sh / 2)) for p in pts]
        field_kind = FIELD_HEIGHT_MM
    else:  # DeepLens places the points at its DEPTH (20 m); tolray takes their angles
        psf_fields = [(math.degrees(math.atan(p[0] * scale * sw / 2 / -L64.obj_depth)),
                       math.degrees(math.atan(p[1] * scale * sh / 2 / -L64.obj_depth))) for p in pts]
        field_kind = FIELD_ANGLE_DEG
    cols, rows = lens_json["sensor_res"]
    g = a.grid
    wx, wy = cols / math.hypot(cols, rows), rows / math.hypot(cols, rows)  # half-size / half-diagonal
    render_fields = [(((2 * c + 1) / g - 1) * wx, (1 - (2 * r + 1) / g) * wy) for r in range(g) for c in range(g)]
    img = np.random.default_rng(a.seed).random((3, a.image, a.image), dtype=np.float32)
    np.save(os.path.join(tmp, "image.npy"), img)

    # tolray, one child per thread count.
    task = {"tmp": tmp, "wl_nm": wl_nm, "psf_fields": psf_fields, "field_kind": field_kind,
            "render_fields": render_fields, "rgb_nm": rgb_nm}
    task_path = os.path.join(tmp, "task.json")
    with open(task_path, "w") as f:
        json.dump(task, f)
    tolray_res = {}
    for th in threads:
        env = dict(os.environ, RAYON_NUM_THREADS=str(th))
        p = subprocess.run([sys.executable, __file__, "--lib", a.lib, "--lens", a.lens, "--repeat",
                            str(a.repeat), "--ks", str(a.ks), "--spp", str(a.spp), "--grid", str(a.grid),
                            "--child", task_path], env=env, capture_output=True, text=True)
        if p.returncode != 0:
            raise SystemExit(f"tolray child ({th} threads) failed:\n{p.stderr}")
        tolray_res[th] = json.loads(p.stdout.strip().splitlines()[-1])
        # The CLI's psf-map (f32, rayon over fields), whole process, and `tolray info` as baseline.
        cmd = [cli, "psf-map", a.lens, "--grid", str(a.grid), "--ks", str(a.ks), "--spp", str(a.spp)]
        tolray_res[th]["cli_psf_map_s"], _ = best_of(a.repeat, lambda: subprocess.run(
            cmd, env=env, check=True, capture_output=True))
        tolray_res[th]["cli_info_s"], _ = best_of(a.repeat, lambda: subprocess.run(
            [cli, "info", a.lens], env=env, check=True, capture_output=True))

    from deeplens.light.ray import Ray

    # 1. Trace.
    tx, ty, tstatus = np.load(os.path.join(tmp, f"trace-tolray-{threads[0]}.npy"))
    t_ok = tstatus == 0
    trace_rows = []

    def dl_trace(L, dt):
        def run():
            ray = Ray(torch.tensor(rays[:3].T, dtype=dt), torch.tensor(rays[3:].T, dtype=dt), L.primary_wvln)
            t = time.perf_counter()
            with torch.no_grad():
                out = L.trace2sensor(ray)
            return time.perf_counter() - t, out
        return run

    def compare(out):
        x = out.o[:, 0].double().numpy()
        y = out.o[:, 1].double().numpy()
        ok = (out.is_valid.numpy() > 0) & np.isfinite(x) & np.isfinite(y)
        both = ok & t_ok
        dev = float(max(np.abs(x[both] - tx[both]).max(), np.abs(y[both] - ty[both]).max())) if both.any() else math.nan
        return {"arrived_deeplens": int(ok.sum()), "arrived_tolray": int(t_ok.sum()), "arrived_both": int(both.sum()),
                "arrival_mismatch": int((ok != t_ok).sum()), "max_dev_mm": dev}

    for name, dt in (("f32", torch.float32), ("f64", torch.float64)):
        L = lenses[name][0]
        row = {"engine": f"DeepLens {name}", "call": "GeoLens.trace2sensor"}
        for th in threads:
            torch.set_num_threads(th)
            dl_trace(L, dt)()  # warm-up
            best, out = math.inf, None
            for _ in range(a.repeat):
                s, out = dl_trace(L, dt)()
                best = min(best, s)
            row[f"{th}t_s"] = best
        row.update(compare(out))
        trace_rows.append(row)
    # The lens as DeepLens reads it, without the index match (f64): the deviation it leaves.
    L_raw, _ = deeplens_lens(lens_path, torch.float64, False, True)
    _, out = dl_trace(L_raw, torch.float64)()
    unmatched = compare(out)
    del L_raw, out
    row = {"engine": "tolray f64", "call": "tolray_trace"}
    for th in threads:
        row[f"{th}t_s"] = tolray_res[th]["trace_s"]
    row.update({"arrived_tolray": int(t_ok.sum())})
    if len(threads) > 1:
        o = np.load(os.path.join(tmp, f"trace-tolray-{threads[-1]}.npy"))
        row["identical_across_threads"] = bool(np.array_equal(o, np.stack([tx, ty, tstatus])))
    trace_rows.append(row)

    # 2. PSF map (one wavelength).
    psf_rows = []
    dl_maps = {}
    for name in ("f32", "f64"):
        L = lenses[name][0]
        row = {"engine": f"DeepLens {name}", "call": f"GeoLens.psf_map(grid={g}, ks={a.ks}, spp={a.spp})"}
        for th in threads:
            torch.set_num_threads(th)

            def run():
                torch.manual_seed(a.seed)
                with torch.no_grad():
                    # wvln None = the primary wavelength exactly: DeepLens then reuses the bundle for
                    # the chief ray (any other float would trace a second bundle of spp rays).
                    return L.psf_map(depth=L.obj_depth, grid=(g, g), ks=a.ks, spp=a.spp, wvln=None)
            run()
            row[f"{th}t_s"], m = best_of(a.repeat, run)
        dl_maps[name] = m.reshape(g * g, a.ks, a.ks).double().numpy()
        psf_rows.append(row)
    row = {"engine": "tolray f64", "call": f"tolray_psf x {g * g} fields (thread pool)"}
    for th in threads:
        row[f"{th}t_s"] = tolray_res[th]["psf_map_s"]
    psf_rows.append(row)
    row = {"engine": "tolray f32 (CLI)", "call": "tolray psf-map (whole process; cell-centre fields)"}
    for th in threads:
        row[f"{th}t_s"] = tolray_res[th]["cli_psf_map_s"]
        row[f"{th}t_process_baseline_s"] = tolray_res[th]["cli_info_s"]
    psf_rows.append(row)
    tm = np.load(os.path.join(tmp, f"psf-tolray-{threads[0]}.npy"))
    tm1 = np.load(os.path.join(tmp, "psf-tolray-seed1.npy"))
    dm = dl_maps["f64"][:, ::-1, ::-1]  # DeepLens' PSFs are upright images: rotated 180 degrees
    (tcx, tcy, trms), (dcx, dcy, drms) = psf_stats(tm), psf_stats(dm)
    ncx, ncy, nrms = psf_stats(tm1)  # tolray with another pupil seed: the Monte Carlo noise
    l1 = np.abs(tm - dm).sum(axis=(1, 2))
    l1_noise = np.abs(tm - tm1).sum(axis=(1, 2))
    psf_check = {
        "max_centroid_offset_px": float(np.hypot(tcx - dcx, tcy - dcy).max()),
        "mean_centroid_offset_px": float(np.hypot(tcx - dcx, tcy - dcy).mean()),
        "tolray_seed0_vs_seed1_max_centroid_offset_px": float(np.hypot(tcx - ncx, tcy - ncy).max()),
        "tolray_seed0_vs_seed1_mean_centroid_offset_px": float(np.hypot(tcx - ncx, tcy - ncy).mean()),
        "rms_radius_px_tolray": [float(trms.min()), float(trms.max())],
        "max_rel_rms_radius_diff": float(np.abs(drms / trms - 1).max()),
        "tolray_seed0_vs_seed1_max_rel_rms_radius_diff": float(np.abs(nrms / trms - 1).max()),
        "mean_l1_tolray_vs_deeplens": float(l1.mean()),
        "mean_l1_tolray_seed0_vs_seed1": float(l1_noise.mean()),
        "tolray_identical_across_threads": bool(np.array_equal(
            tm, np.load(os.path.join(tmp, f"psf-tolray-{threads[-1]}.npy")))),
    }

    # 3. Rendering.
    L = lenses["f32"][0]
    torch.manual_seed(a.seed)
    with torch.no_grad():
        dl_map_rgb = L.psf_map_rgb(grid=(g, g), ks=a.ks, depth=L.obj_depth, spp=a.spp)
    img_t = torch.from_numpy(img).unsqueeze(0)
    render_rows = []
    row_c = {"engine": "DeepLens f32", "call": "conv_psf_map (convolution only, direct conv2d)"}
    row_f = {"engine": "DeepLens f32", "call": "render_psf_map (RGB PSF map + conv_psf_map)"}
    for th in threads:
        torch.set_num_threads(th)

        def conv():
            with torch.no_grad():
                return conv_psf_map(img_t, dl_map_rgb)
        row_c[f"{th}t_s"], _ = best_of(a.repeat, conv)

        def full():
            torch.manual_seed(a.seed)
            with torch.no_grad():
                return L.render_psf_map(img_t, depth=L.obj_depth, psf_grid=(g, g), psf_ks=a.ks, psf_spp=a.spp)
        row_f[f"{th}t_s"], _ = best_of(a.repeat, full)
    row_t16 = {"engine": "tolray f32", "call": f"tolray_render, {FEW_RAYS} rays per PSF (~ convolution only, FFT)"}
    row_t = {"engine": "tolray f32", "call": f"tolray_render (RGB PSF map, {a.spp} rays, + FFT convolution)"}
    for th in threads:
        row_t16[f"{th}t_s"] = tolray_res[th]["render_few_rays_s"]
        row_t[f"{th}t_s"] = tolray_res[th]["render_s"]
    render_rows = [row_c, row_t16, row_f, row_t]
    # Sameness: DeepLens' convolution with tolray's own RGB PSFs against tolray_render.
    render_check = None
    if os.path.exists(os.path.join(tmp, "render-tolray.npy")):
        render_check = render_sameness(tmp, g, a.ks, img_t, conv_psf_map)

    def commit():
        try:
            return subprocess.run(["git", "-C", a.source, "describe", "--always", "--dirty", "--abbrev=7"],
                                  capture_output=True, text=True, check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return None
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except (OSError, StopIteration):
        cpu = platform.processor()
    # How busy the machine was with other work during the run: the CPU time of the whole
    # machine (/proc/stat) less this script's and its children's, over wall time x CPUs.
    others = None
    jiffies_after = cpu_jiffies()
    if jiffies_before and jiffies_after:
        hz = os.sysconf("SC_CLK_TCK")
        busy = (jiffies_after[0] - jiffies_before[0]) / hz
        tm = os.times()
        own = tm.user + tm.system + tm.children_user + tm.children_system
        others = max(0.0, busy - own) / ((time.perf_counter() - t_start) * os.cpu_count())
    result = {
        "meta": {
            "lens": a.lens, "surfaces_traced": n_surf, "object_distance_mm": depth,
            "primary_wavelength_nm": wl_nm, "rgb_nm": rgb_nm,
            "pitch_mm": tol.psf_options(a.ks, a.spp, 0).pitch_mm,
            "deeplens_pixel_size_mm": float(L64.pixel_size),
            "rays": a.rays, "field_fraction": a.field, "grid": g, "ks": a.ks, "spp": a.spp,
            "image": [3, a.image, a.image], "repeat": a.repeat, "seed": a.seed, "threads": threads,
            "index_match": not a.no_index_match, "deeplens_notes": notes,
            "versions": {"deeplens-core": version("deeplens-core"), "torch": torch.__version__,
                         "numpy": np.__version__, "python": platform.python_version(),
                         "tolray_commit": commit(), "tolray_source": os.path.abspath(a.source),
                         "libtolray": os.path.abspath(a.lib)},
            "machine": {"cpu": cpu, "cpus": os.cpu_count(), "loadavg_before": load_before,
                        "loadavg_after": os.getloadavg(), "other_processes_cpu_share": others},
            "script_seconds": None,
        },
        "trace": trace_rows,
        "trace_check": {"deeplens_f64_without_index_match": unmatched},
        "psf_map": psf_rows,
        "psf_check": psf_check,
        "render": render_rows,
        "render_check": render_check,
    }
    result["meta"]["script_seconds"] = time.perf_counter() - t_start

    # Report.
    rs = a.rays * n_surf
    th_hdr = "".join(f"{f'{t} thread' + ('s' if t > 1 else ''):>22}" for t in threads)
    print(f"DeepLens {version('deeplens-core')} (torch {torch.__version__}, CPU), libtolray {a.lib}; "
          f"lens {a.lens}; best of {a.repeat}; load average {load_before[0]:.2f} before, "
          f"{os.getloadavg()[0]:.2f} after")
    print(f"\n1. Trace: {a.rays} rays x {n_surf} surfaces, field {a.field}, {wl_nm:.4f} nm, apertures clip")
    print(f"{'engine':14}{th_hdr}   arrived (both)   max |dev| vs tolray")
    for r in trace_rows:
        cells = "".join(f"{f'{r[f'{t}t_s'] * 1e3:8.1f} ms {rs / r[f'{t}t_s'] / 1e6:6.1f} M':>22}" for t in threads)
        tail = (f"   {r.get('arrived_both', r.get('arrived_tolray'))}"
                + (f"   {r['max_dev_mm']:.1e} mm" if "max_dev_mm" in r else ""))
        print(f"{r['engine']:14}{cells}{tail}")
    print(f"   (DeepLens f64 without the index match: max |dev| {unmatched['max_dev_mm']:.1e} mm)")
    print(f"\n2. PSF map: {g}x{g} fields, {a.ks}x{a.ks} px at {result['meta']['pitch_mm'] * 1e3:.3f} um, "
          f"{a.spp} rays each, one wavelength")
    for r in psf_rows:
        cells = "".join(f"{f'{r[f'{t}t_s'] * 1e3:8.1f} ms':>22}" for t in threads)
        base = (f" (`tolray info`: {r[f'{threads[0]}t_process_baseline_s'] * 1e3:.1f} ms)"
                if f"{threads[0]}t_process_baseline_s" in r else "")
        print(f"{r['engine']:18}{cells}   {r['call']}{base}")
    print(f"   check: {json.dumps(psf_check)}")
    print(f"\n3. Render: {a.image}x{a.image} RGB, {g}x{g} map of {a.ks}x{a.ks} kernels")
    for r in render_rows:
        cells = "".join(f"{f'{r[f'{t}t_s'] * 1e3:9.1f} ms':>22}" for t in threads)
        print(f"{r['engine']:14}{cells}   {r['call']}")
    print(f"   check (DeepLens conv_psf_map on tolray's PSFs vs tolray_render): {json.dumps(render_check)}")
    print(f"\nscript: {result['meta']['script_seconds']:.0f} s; other processes used "
          f"{100 * (others or 0):.0f} % of the machine's CPU time meanwhile")
    if not a.keep_tmp:
        shutil.rmtree(tmp, ignore_errors=True)
    text = json.dumps(result, indent=1)
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        with open(a.out, "w") as f:
            f.write(text + "\n")
    else:
        print(text)


if __name__ == "__main__":
    main()
