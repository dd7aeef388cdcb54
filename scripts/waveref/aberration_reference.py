#!/usr/bin/env python3
"""Reference aberration curves (field curvature, distortion f-tan and f-theta) from optiland 0.6.3.

Versions: optiland 0.6.3, numpy 2.4.6, Python 3.11 (the environment of scripts/requirements.txt, as
wave_reference.py). Generated once, 2026-11-28, for the tolray project; the Rust tests
(tests/optics/aberrations.rs) read the output and never run this.

Usage (from the repository root):
    .venv-ref/bin/python scripts/waveref/aberration_reference.py
writes tests/data/wave/optiland_aberrations.json (a few seconds).

Lenses and their adaptations are those of wave_reference.py (its LENSES, `load`, `choose_field`:
the same glass patches, the WAVL rewrite, vignetting factors set to 0, a nominal field added to a
file that has only the axis). Fields: Hy = 0, 0.25, 0.5, 0.75, 1 of optiland's largest field
(angle fields: angle = Hy x max angle; for a finite object the object point is at
y = -tan(angle) (z_EP - z_object), so tolray gives it as that object height).

What optiland computes (read from its source, optiland/analysis):
  field_curvature.py FieldCurvature._intersection_parabasal_tangential / _sagittal(wavelength,
    delta=1e-5): pairs of rays at (Px, Py) = (0, -+1e-5) (tangential) and (-+1e-5, 0)
    (sagittal) traced with the paraxial aimer; t1 solves the crossing of the two rays'
    projections on the y-z (x-z) plane from the first ray's image-surface point; the value is
    t1 * N1 (mm along z from the image surface; positive beyond it).
  distortion_strategies/model.py RotationalDistortionModel (method "paraxial"): chief-ray
    (Px = Py = 0) image points relative to the on-axis chief ray's; scale k = y(H = 1e-10) /
    tan(1e-10 theta_max) (f-tan) or / (1e-10 theta_max) (f-theta); percent (signed) =
    100 (y_real - k proj(H theta_max)) / (k proj(H theta_max)). The script calls the model's
    `compute` at the chosen Hy (Hy = 0 is replaced by 1e-10 as optiland's own Distortion does).
    f-theta is recorded only for an object at infinity.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import wave_reference as wr  # noqa: E402

import optiland.backend as be  # noqa: E402
from optiland.analysis.distortion_strategies.model import create_distortion_model  # noqa: E402
from optiland.analysis.field_curvature import FieldCurvature  # noqa: E402

OUT = os.path.join(wr.ROOT, "tests", "data", "wave", "optiland_aberrations.json")
HYS = [0.0, 0.25, 0.5, 0.75, 1.0]


def main():
    out = {"header": {
        "generator": "scripts/waveref/aberration_reference.py",
        "date": "2026-11-28",
        "engine": "optiland 0.6.3 (numpy backend, float64)",
        "units": "mm (field curvature), percent (distortion), degrees or mm (fields)",
        "fields": "Hy x optiland max field (angle fields); finite object: object at "
                  "y = -tan(angle) (z_EP - z_object)",
        "methods": __doc__.split("What optiland computes")[1].strip(),
    }, "lenses": []}
    for lens in wr.LENSES:
        print("==", lens["id"], flush=True)
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            op, patches, adapt, feat = wr.load(lens)
            wr.choose_field(op, lens, adapt)
        wl = float(op.primary_wavelength)
        fmax = float(be.to_numpy(be.array(op.fields.max_field)))
        para = wr.paraxial_numbers(op, wl)
        entry = {"id": lens["id"], "path": lens["path"], "adaptations": adapt,
                 "optiland_max_field": fmax, "wavelength_um": wl, "paraxial": para,
                 "hy": HYS, "field_deg": [h * fmax for h in HYS]}
        fc = FieldCurvature.__new__(FieldCurvature)
        fc.optic = op
        fc.num_points = len(HYS)
        # optiland's own linspace(0, 1, n) is HYS.
        assert np.allclose(np.linspace(0, 1, len(HYS)), HYS)
        t = be.to_numpy(fc._intersection_parabasal_tangential(wl))
        s = be.to_numpy(fc._intersection_parabasal_sagittal(wl))
        entry["field_curvature_tangential_mm"] = [float(v) for v in t]
        entry["field_curvature_sagittal_mm"] = [float(v) for v in s]
        # optiland's tangential crossing loses digits for a distant finite object (the Cooke
        # triplet's 20 m: its value at delta 1e-5 moves by 1e-4 mm between delta 1e-4 and 1e-6).
        # Richardson's extrapolation (4 T(d) - T(2d)) / 3 of larger pairs, at d = 4e-3, 2e-3
        # and 1e-3: their mean, and their spread as the reference's own uncertainty.
        rich = []
        for d in (4e-3, 2e-3, 1e-3):
            t1 = be.to_numpy(fc._intersection_parabasal_tangential(wl, delta=d))
            t2 = be.to_numpy(fc._intersection_parabasal_tangential(wl, delta=2 * d))
            rich.append((4 * t1 - t2) / 3)
        rich = np.array(rich)
        entry["field_curvature_tangential_richardson_mm"] = [float(v) for v in rich.mean(axis=0)]
        entry["field_curvature_tangential_richardson_spread_mm"] = [
            float(v) for v in rich.max(axis=0) - rich.min(axis=0)]
        hy = be.array([max(h, 1e-10) for h in HYS])
        hx = be.zeros(len(HYS))
        kinds = ["f-tan"] + (["f-theta"] if para["object_infinite"] else [])
        for kind in kinds:
            m = create_distortion_model("paraxial", distortion_type=kind)
            r = m.compute(op, hx, hy, wl)
            entry[f"distortion_{kind.replace('-', '_')}_percent"] = [
                float(v) for v in be.to_numpy(m.percent(r, signed=True))]
        print("   T", entry["field_curvature_tangential_mm"], flush=True)
        print("   f-tan", entry["distortion_f_tan_percent"], flush=True)
        out["lenses"].append(entry)
    with open(OUT, "w") as fh:
        json.dump(out, fh, indent=1)
        fh.write("\n")
    print("wrote", OUT)


if __name__ == "__main__":
    main()
