#!/usr/bin/env python3
"""Check tolray's .zmx writer against an independent reader (optiland 0.6.3).

For every corpus file (tests/data/zemax/real/<source>/*.zmx) that tolray opens, `tolray convert
IN.zmx OUT.zmx` writes the lens back through tolray's writer; the WRITTEN file is loaded and
evaluated exactly as gen_reference.py evaluates an original (its scan + optiland_reference, with
all its patches), and the numbers are compared with the reference.json entry of the ORIGINAL file.

Usage (from any directory outside the repository; optiland may write logs into the cwd):
    .venv-ref/bin/python scripts/zmxref/roundtrip_check.py \
        --tolray /path/to/tolray --json OUT.json [--keep DIR]
with ZEMAXGLASS_AGF set as for gen_reference.py (its patch 9: the LightPath and RPO glasses of
two corpus files, which optiland's database lacks).

Quantities and tolerances (those of tests/zemax/, corpus_mismatches; lengths in mm, the
reference's file units converted by its UNIT):
  * wavelength, EFL (optiland f2), BFD, EPD: relative 1e-9; the field's kind and maximum (angle or
    object height that was traced): relative 1e-9;
  * glass indices at the primary wavelength, surface by surface in order (surfaces whose glass
    optiland did not resolve from a catalog are skipped, as in the Rust test): relative 1e-9;
  * EP position: |a - b| <= 1e-9 (1 + |b|).  tolray's writer starts the file at tolray's first
    surface, so where the original has dummy surfaces or coordinate breaks before its first lens
    surface the written file's frame origin lies dz further along z.  dz is measured with optiland
    on both files as the shift of the image plane relative to each file's frame origin (optiland
    surface 1), and the reference EP z is compared as ep_z - dz (tests/zemax/ does the same with
    tolray's own first_vertex_mm);
  * per field (0, 0.7, 1 of the maximum): rays launched and rays reaching the image: exact;
    RMS spot: |a - b| <= 1e-9 b + 1e-6 um; centroid: each coordinate within 1e-9 (1 + |y_ref|) mm,
    compared in global x, y (optiland's image-local centroid plus the image surface's own lateral
    position), since tolray writes the image plane on the axis.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import shlex
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import gen_reference as gr  # noqa: E402  (sets optiland's numpy backend, float64)

REPO = os.path.normpath(os.path.join(HERE, "..", ".."))
UNITS = {"IN": 25.4, "CM": 10.0, "METER": 1000.0}


def unit_mm(feat):
    u = (feat or {}).get("unit") or "MM"
    return UNITS.get(u.split()[0].upper(), 1.0) if u.split() else 1.0


def rel(a, b):
    return 0.0 if a == b else abs((a - b) / b)


def frame(path):
    """(image vertex x, y, z) relative to optiland's frame origin (surface 1's vertex), file units."""
    op = gr.load_optic(path, gr.scan(path))[0]
    z1 = gr.fl(op.surfaces[1].geometry.cs.z)
    cs = op.surfaces[-1].geometry.cs
    return gr.fl(cs.x), gr.fl(cs.y), gr.fl(cs.z) - z1


class Checks:
    def __init__(self):
        self.items = []

    def add(self, what, written, want, ok, diff, **note):
        num = lambda v: float(v) if isinstance(v, float) else v  # numpy floats -> float
        written, want = num(written), num(want)
        self.items.append({"quantity": what, "written": written, "reference": want,
                           "diff": diff, "ok": bool(ok), **note})

    def rel(self, what, written, want, tol=1e-9):
        d = rel(written, want) if (written is not None and want is not None) else math.inf
        self.add(what, written, want, d <= tol, {"rel": d})

    def absol(self, what, written, want, tol, **note):
        d = abs(written - want) if (written is not None and want is not None) else math.inf
        self.add(what, written, want, d <= tol, {"abs": d, "tol": tol}, **note)

    def exact(self, what, written, want):
        self.add(what, written, want, written == want, {"abs": None if written == want else
                                                         (written - want if isinstance(written, int) and isinstance(want, int) else "differs")})

    def bad(self):
        return [c for c in self.items if not c["ok"]]


def glass_list(entry):
    return [(g["surface"], g["glas_name"], g["n"]) for g in entry.get("glass_indices", [])
            if not g["catalog_fallback_to_abbe_model"]]


def compare(ref, got, u_ref, u_got, fr_ref, fr_got):
    c = Checks()
    c.rel("wavelength_nm", got["wavelength_nm"], ref["wavelength_nm"])
    dz = fr_ref[2] * u_ref - fr_got[2] * u_got
    if ref["efl_mm"] is None:
        # optiland has no paraxial model of the original (gen_reference.py patch 8): it must
        # have none of the written file either; the rays are compared below.
        c.exact("no paraxial model", got["efl_mm"] is None, True)
    else:
        if isinstance(ref["efl_mm"], str):
            # An afocal lens: gen_reference.py records optiland's infinite f2 and BFD as "inf" /
            # "-inf"; the written file must be afocal too (the sign follows the mirrors).
            afocal = isinstance(got["efl_mm"], str) or not math.isfinite(got["efl_mm"])
            c.exact("EFL (afocal)", afocal, True)
        else:
            c.rel("EFL", got["efl_mm"] * u_got, ref["efl_mm"] * u_ref)
        if not isinstance(ref["bfd_mm"], str):
            c.rel("BFD", got["bfd_mm"] * u_got, ref["bfd_mm"] * u_ref)
        c.rel("EPD", got["epd_mm"] * u_got, ref["epd_mm"] * u_ref)
        want_ep = ref["ep_z_mm"] * u_ref - dz
        c.absol("EP z", got["ep_z_mm"] * u_got, want_ep, 1e-9 * (1.0 + abs(want_ep)),
                note="reference = reference.json ep_z (original's frame) - dz",
                reference_original_frame=ref["ep_z_mm"] * u_ref, dz_mm=dz)
    g_ref, g_got = glass_list(ref), glass_list(got)
    if len(g_ref) != len(g_got):
        c.add("glass count", len(g_got), len(g_ref), False, {"abs": len(g_got) - len(g_ref)})
    else:
        for (sr, nr, n_ref), (sg, ng, n_got) in zip(g_ref, g_got):
            c.rel(f"n after SURF {sr} ({nr}; written SURF {sg} {ng})", n_got, n_ref)
    c.exact("field kind", got["field_kind"], ref["field_kind"])
    scale_f = 1.0 if ref["field_kind"] == "angle" else None
    c.rel("field max", got["field_max"] * (scale_f or u_got), ref["field_max"] * (scale_f or u_ref))
    for fw, fo in zip(got["fields"], ref["fields"]):
        fr = fo["frac"]
        c.exact(f"field {fr}: rays launched", fw["n_rays_launched"], fo["n_rays_launched"])
        c.exact(f"field {fr}: rays at image", fw["n_rays"], fo["n_rays"])
        if fo["n_rays"] == 0 or fw["n_rays"] == 0:
            continue
        want = fo["rms_um"] * u_ref
        c.absol(f"field {fr}: RMS spot um", fw["rms_um"] * u_got, want, 1e-9 * want + 1e-6)
        # global x, y: image-local centroid + image vertex position
        cw = [fw["centroid_mm"][k] * u_got + fr_got[k] * u_got for k in (0, 1)]
        co = [fo["centroid_mm"][k] * u_ref + fr_ref[k] * u_ref for k in (0, 1)]
        tol = 1e-9 * (1.0 + abs(fo["centroid_mm"][1] * u_ref))
        for k, ax in enumerate("xy"):
            c.absol(f"field {fr}: centroid {ax} mm", cw[k], co[k], tol)
    if len(got["fields"]) != len(ref["fields"]):
        c.add("field count", len(got["fields"]), len(ref["fields"]), False, {})
    return c, dz


def describe(bad):
    out = []
    for b in bad:
        d = b["diff"]
        if "rel" in d:
            out.append(f"{b['quantity']} rel {d['rel']:.3g} ({b['written']!r} vs {b['reference']!r})")
        elif d.get("abs") not in (None, "differs") and isinstance(d.get("abs"), float):
            out.append(f"{b['quantity']} by {d['abs']:.3g} ({b['written']!r} vs {b['reference']!r})")
        else:
            out.append(f"{b['quantity']}: {b['written']!r} vs {b['reference']!r}")
    return "; ".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tolray", default=os.path.join(REPO, "target", "release", "tolray"))
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--keep", help="keep the written .zmx files in this directory")
    ap.add_argument("--only", action="append", help="corpus path (source/name.zmx); repeatable")
    ap.add_argument("--via-json", action="store_true",
                    help="write IN.zmx -> OUT.json -> OUT.zmx (two `tolray convert` calls) instead of "
                         "IN.zmx -> OUT.zmx")
    args = ap.parse_args()
    tolray = os.path.abspath(args.tolray)
    refs = {e["path"]: e for e in json.load(open(os.path.join(gr.CORPUS, "reference.json")))}
    outdir = os.path.abspath(args.keep) if args.keep else tempfile.mkdtemp(prefix="zmx-roundtrip-")
    os.makedirs(outdir, exist_ok=True)
    json_path = os.path.abspath(args.json) if args.json else None
    os.chdir(tempfile.mkdtemp(prefix="zmx-roundtrip-cwd-"))

    results = []
    for source, path, relp in gr.corpus():
        if args.only and relp not in args.only:
            continue
        written = os.path.join(outdir, relp.replace("/", "__").rsplit(".", 1)[0] + ".zmx")
        r = {"path": relp, "written_file": os.path.basename(written)}
        if args.via_json:
            via = written[:-4] + ".json"
            p = subprocess.run([tolray, "convert", path, via], capture_output=True, text=True)
            if p.returncode == 0:
                p = subprocess.run([tolray, "convert", via, written], capture_output=True, text=True)
        else:
            p = subprocess.run([tolray, "convert", path, written], capture_output=True, text=True)
        if p.returncode != 0:
            r["status"] = "not opened by tolray"
            r["detail"] = (p.stderr.strip().splitlines() or [""])[0].replace(path + ": ", "")
            results.append(r)
            continue
        ref = refs.get(relp)
        if ref is None or "efl_mm" not in ref:
            r["status"] = "no optiland reference for the original"
            r["detail"] = (ref or {}).get("refused", "missing from reference.json")
            results.append(r)
            continue
        try:
            feat_w = gr.scan(written)
            got = gr.optiland_reference(written, feat_w)
            fr_got = frame(written)
            fr_ref = frame(path)
        except Exception as e:  # optiland cannot read the written file
            r["status"] = "optiland cannot read the written file"
            r["detail"] = f"{type(e).__name__}: {e}"[:400]
            results.append(r)
            continue
        checks, dz = compare(ref, got, unit_mm(ref["features"]), unit_mm(feat_w), fr_ref, fr_got)
        bad = checks.bad()
        r["status"] = "agree" if not bad else "differs"
        r["detail"] = describe(bad)
        r["frame_dz_mm"] = dz
        r["optiland_patches_written"] = got.get("optiland_patches", [])
        r["checks"] = checks.items
        results.append(r)
        print(f"{relp:60s} {r['status']}", file=sys.stderr, flush=True)

    w = max(len(r["path"]) for r in results) if results else 10
    print(f"{'file':{w}s}  status")
    for r in results:
        line = f"{r['path']:{w}s}  {r['status']}"
        if r.get("detail"):
            line += ": " + r["detail"]
        print(line)
    count = {}
    for r in results:
        count[r["status"]] = count.get(r["status"], 0) + 1
    opened = sum(v for k, v in count.items() if k != "not opened by tolray")
    print(f"\nopened by tolray and written: {opened}; " +
          "; ".join(f"{k}: {v}" for k, v in sorted(count.items())))

    if json_path:
        import importlib.metadata as md
        commit = subprocess.run(["git", "-C", REPO, "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True).stdout.strip()
        version = subprocess.run([tolray, "-V"], capture_output=True, text=True).stdout.strip()
        header = {
            "tolray_commit": commit,
            "tolray_binary": f"{tolray} ({version})",
            "optiland_version": md.version("optiland"),
            "command": " ".join(shlex.quote(a) for a in [sys.executable] + sys.argv),
            "what": "each corpus file tolray opens, written by " + (
                "`tolray convert IN.zmx OUT.json` then `tolray convert OUT.json OUT.zmx`, "
                if args.via_json else "`tolray convert IN.zmx OUT.zmx`, ") +
                    "loaded and evaluated by gen_reference.optiland_reference, compared with the "
                    "original's reference.json entry (see roundtrip_check.py for tolerances)",
            "summary": count,
        }

        with open(json_path, "w") as fh:
            json.dump(gr.json_finite({"header": header, "files": results}), fh, indent=1, default=repr,
                      allow_nan=False)
            fh.write("\n")


if __name__ == "__main__":
    main()
