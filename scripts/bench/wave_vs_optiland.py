#!/usr/bin/env python3
"""tolray's wave optics against optiland's in one run: the same analyses of the same lens file.

Nothing in tolray runs this; it measures. The Cooke triplet (tests/data/zemax/cooke-triplet.zmx)
at 0.7 of its largest field, primary wavelength, timed as the best of `--repeat` wall times:

  * wavefront + 37 Zernike terms: optiland `ZernikeOPD` (noll, 15 hexapolar rings: 721 rays)
    against `tolray_wavefront` (16 x 48 polar quadrature: 768 rays, Standard = Noll);
  * FFT PSF, 128 pupil samples in a 256 grid: optiland `FFTPSF(num_rays=128, grid_size=256)`
    against `tolray_diffraction_psf` (FFT, 128, 256; with its Strehl ratio);
  * Huygens PSF, 64 pupil samples onto 64 x 64 image points: optiland `HuygensPSF(num_rays=64,
    image_size=64)` against `tolray_diffraction_psf` (Huygens, 64, 64, the FFT's pixel pitch);
  * MTF of one field: optiland `FFTMTF(num_rays=64, grid_size=256)` (its whole curve) against
    `tolray_mtf` (FFT, 64 in 256, three frequencies) and the direct method (64, three
    frequencies);
tolray through its C ABI (libtolray.so via ctypes) in child processes with RAYON_NUM_THREADS=1
and =2; optiland (numpy backend, float64) in this process. Both sides' fields are the same
normalised field (optiland's 0.7 of its largest angle measured at the entrance pupil, tolray's
TOLRAY_FIELD_FRACTION 0.7): the work is the same, the numbers are not compared here (the
cross-check is tests/optics/wave_reference.rs).

Usage (from the repository root, after `cargo build --release`):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/bench/wave_vs_optiland.py [--repeat 5]
"""
from __future__ import annotations

import argparse
import contextlib
import ctypes
import io
import json
import os
import subprocess
import sys
import time
import warnings

warnings.filterwarnings("ignore")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LENS = "tests/data/zemax/cooke-triplet.zmx"
FIELD = 0.7
FREQS = [10.0, 20.0, 40.0]


class Field(ctypes.Structure):
    _fields_ = [("kind", ctypes.c_uint32), ("x", ctypes.c_double), ("y", ctypes.c_double)]


class WaveOptions(ctypes.Structure):
    _fields_ = [(k, ctypes.c_uint32) for k in
                ("rings", "spokes", "zernike_terms", "reference", "zernike_pupil", "aim", "apertures")]


class WavefrontStats(ctypes.Structure):
    _fields_ = [(k, ctypes.c_double) for k in
                ("rms_to_chief_waves", "rms_to_centroid_waves", "pv_to_chief_waves",
                 "pv_to_centroid_waves", "strehl_marechal", "zernike_residual_waves",
                 "reference_radius_mm")] + [("n_launched", ctypes.c_uint64), ("n_rays", ctypes.c_uint64)]


class DiffractionOptions(ctypes.Structure):
    _fields_ = [("method", ctypes.c_uint32), ("pupil_samples", ctypes.c_uint32),
                ("grid", ctypes.c_uint32), ("pitch_um", ctypes.c_double),
                ("aim", ctypes.c_uint32), ("apertures", ctypes.c_uint32)]


def best(f, repeat):
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        t.append(time.perf_counter() - t0)
    return min(t)


def tolray_child(lib_path, repeat):
    lib = ctypes.CDLL(lib_path)
    lib.tolray_last_error.restype = ctypes.c_size_t
    lens, system = ctypes.c_void_p(), ctypes.c_void_p()

    def check(st, what):
        if st != 0:
            buf = ctypes.create_string_buffer(4096)
            lib.tolray_last_error(buf, 4096)
            raise SystemExit(f"{what}: status {st}: {buf.value.decode()}")

    check(lib.tolray_lens_load(os.path.join(ROOT, LENS).encode(), ctypes.byref(lens)), "load")
    check(lib.tolray_system_new(lens, None, ctypes.byref(system)), "system")
    field = Field(0, 0.0, FIELD)
    wl = ctypes.c_double(587.5618)
    lib.tolray_wavefront.argtypes = [ctypes.c_void_p, ctypes.POINTER(Field), ctypes.c_double,
                                     ctypes.POINTER(WaveOptions), ctypes.POINTER(WavefrontStats),
                                     ctypes.POINTER(ctypes.c_double), ctypes.c_size_t]
    lib.tolray_diffraction_psf.argtypes = [ctypes.c_void_p, ctypes.POINTER(Field), ctypes.c_double,
                                           ctypes.POINTER(DiffractionOptions),
                                           ctypes.POINTER(ctypes.c_double), ctypes.c_size_t,
                                           ctypes.POINTER(ctypes.c_double),
                                           ctypes.POINTER(ctypes.c_double)]
    lib.tolray_mtf.argtypes = [ctypes.c_void_p, ctypes.POINTER(Field), ctypes.c_double,
                               ctypes.POINTER(DiffractionOptions), ctypes.POINTER(ctypes.c_double),
                               ctypes.c_size_t] + [ctypes.POINTER(ctypes.c_double)] * 3
    wo = WaveOptions(16, 48, 37, 0, 0, 0, 1)
    stats = WavefrontStats()
    z = (ctypes.c_double * 37)()
    out = {}
    out["wavefront_zernike"] = best(lambda: check(lib.tolray_wavefront(
        system, ctypes.byref(field), wl, ctypes.byref(wo), ctypes.byref(stats), z, 37), "wf"), repeat)
    img = (ctypes.c_double * (256 * 256))()
    strehl, pitch = ctypes.c_double(), (ctypes.c_double * 2)()
    fft = DiffractionOptions(0, 128, 256, 0.0, 0, 1)
    out["fft_psf_128_256"] = best(lambda: check(lib.tolray_diffraction_psf(
        system, ctypes.byref(field), wl, ctypes.byref(fft), img, 256 * 256, ctypes.byref(strehl),
        pitch), "fft psf"), repeat)
    out["fft_psf_strehl"] = strehl.value
    hp = pitch[1]
    hug = DiffractionOptions(1, 64, 64, hp, 0, 1)
    small = (ctypes.c_double * (64 * 64))()
    out["huygens_psf_64_64"] = best(lambda: check(lib.tolray_diffraction_psf(
        system, ctypes.byref(field), wl, ctypes.byref(hug), small, 64 * 64, ctypes.byref(strehl),
        pitch), "huygens psf"), repeat)
    freqs = (ctypes.c_double * 3)(*FREQS)
    t, s, lim = (ctypes.c_double * 3)(), (ctypes.c_double * 3)(), (ctypes.c_double * 3)()
    for name, method in (("mtf_fft_64_256", 0), ("mtf_direct_64", 1)):
        m = DiffractionOptions(method, 64, 256, 0.0, 0, 1)
        out[name] = best(lambda: check(lib.tolray_mtf(
            system, ctypes.byref(field), wl, ctypes.byref(m), freqs, 3, t, s, lim), "mtf"), repeat)
        out[name + "_values"] = [list(t), list(s)]
    print(json.dumps(out))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lib", default=os.path.join(ROOT, "target/release/libtolray.so"))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--child", action="store_true")
    a = ap.parse_args()
    if a.child:
        tolray_child(a.lib, a.repeat)
        return
    import optiland.backend as be
    from optiland.fileio import load_zemax_file
    from optiland.mtf import FFTMTF
    from optiland.psf import FFTPSF, HuygensPSF
    from optiland.wavefront import ZernikeOPD
    be.set_backend("numpy")
    with contextlib.redirect_stdout(io.StringIO()):
        op = load_zemax_file(os.path.join(ROOT, LENS))
    wl = op.primary_wavelength
    f = (0.0, FIELD)
    rows = {}
    rows["wavefront_zernike"] = best(lambda: ZernikeOPD(op, f, wl, num_rings=15,
                                                        zernike_type="noll", num_terms=37), a.repeat)
    rows["fft_psf_128_256"] = best(lambda: FFTPSF(op, f, wl, num_rays=128, grid_size=256).strehl_ratio(),
                                   a.repeat)
    rows["huygens_psf_64_64"] = best(lambda: HuygensPSF(op, f, wl, num_rays=64, image_size=64),
                                     max(1, a.repeat // 2))
    rows["mtf_fft_64_256"] = best(lambda: FFTMTF(op, [f], wl, num_rays=64, grid_size=256), a.repeat)
    res = {"lens": LENS, "field": FIELD, "optiland_s": rows}
    for threads in (1, 2):
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        out = subprocess.run([sys.executable, __file__, "--child", "--lib", a.lib, "--repeat",
                              str(a.repeat)], env=env, capture_output=True, text=True, check=True)
        res[f"tolray_{threads}t_s"] = json.loads(out.stdout)
    print(f"{'analysis':<22} {'optiland ms':>12} {'tolray 1t ms':>13} {'tolray 2t ms':>13} {'ratio 1t':>9}")
    for k in ("wavefront_zernike", "fft_psf_128_256", "huygens_psf_64_64", "mtf_fft_64_256",
              "mtf_direct_64"):
        o = rows.get(k)
        t1, t2 = res["tolray_1t_s"][k], res["tolray_2t_s"][k]
        ratio = f"{o / t1:9.1f}" if o else f"{'-':>9}"
        print(f"{k:<22} {o * 1e3 if o else float('nan'):12.2f} {t1 * 1e3:13.2f} {t2 * 1e3:13.2f} {ratio}")
    print(json.dumps(res))


if __name__ == "__main__":
    main()
