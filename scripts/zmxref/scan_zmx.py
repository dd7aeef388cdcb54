"""Feature scanner for Zemax .zmx files (pure python, no optiland needed).

scan(path) -> dict describing encoding and the features a .zmx reader must handle.
"""
from __future__ import annotations

import codecs
import re

APERTURE_KEYS = ["DIAM", "CLAP", "SQAP", "ELAP", "OBSC", "OBDC", "FLAP", "SPID", "UDAD", "FLOA"]
SURFACE_KEYS = {"TYPE", "CURV", "DISZ", "GLAS", "STOP", "CONI", "PARM", "XDAT", "HIDE", "MIRR",
                "SLAB", "COMM", "FIMP", "MEMA", "OEMA", "COAT", "MAZH", "PZUP", "PKUP", "CHZN",
                "DECX", "DECY", "TILTX", "TILTY", "SCBD", "TEZI", "SSID", "POPS", "FLWR", "IGNR"} | set(APERTURE_KEYS) - {"FLOA"}
VIGNETTE_KEYS = ["VDXN", "VDYN", "VCXN", "VCYN", "VANN"]
FTYP_NAMES = {0: "angle", 1: "object_height", 2: "paraxial_image_height",
              3: "real_image_height", 4: "theodolite_angle"}


def read_text(path):
    raw = open(path, "rb").read()
    if raw.startswith(codecs.BOM_UTF16_LE) or raw.startswith(codecs.BOM_UTF16_BE):
        return raw.decode("utf-16"), "utf-16" + ("le" if raw.startswith(codecs.BOM_UTF16_LE) else "be") + "-bom"
    if raw.startswith(codecs.BOM_UTF8):
        return raw[3:].decode("utf-8"), "utf-8-bom"
    if len(raw) > 1 and raw[1:2] == b"\x00":
        return raw.decode("utf-16-le"), "utf-16le-nobom"
    try:
        txt = raw.decode("ascii")
        return txt, "ascii"
    except UnicodeDecodeError:
        pass
    try:
        return raw.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return raw.decode("latin-1"), "iso-8859-1"


def _f(tok):
    try:
        return float(tok)
    except ValueError:
        if tok.upper() == "INFINITY":
            return float("inf")
        return tok


def scan(path):
    text, enc = read_text(path)
    lines = text.splitlines()
    feat = {
        "encoding": enc,
        "line_endings": "CRLF" if "\r\n" in text else ("CR" if "\r" in text else "LF"),
        "vers": None, "mode": None, "unit": None, "name": None,
        "system_aperture": None,
        "ftyp_raw": None, "field_type": None, "xfln": None, "yfln": None,
        "wavelengths_um": {}, "pwav": None,
        "gcat": [], "glass_names": [],
        "raim": None,
        "vignetting": {},
        "surface_types": {},
        "num_surfaces": 0,
        "stop_surface": None,
        "mirror_surfaces": [],
        "negative_thickness_surfaces": [],
        "apertures": {},
        "surfaces_with_conic": [],
        "object_distance": None,
        "coordbrk_surfaces": [],
        "surface_tilt_decenter_keys": [],
        "has_pickups_or_solves": False,
        "other_top_level_keys": [],
    }
    cur = None
    surfs = {}
    seen_top = set()
    for ln in lines:
        if not ln.strip():
            continue
        tok = ln.split()
        indented = (ln[:1] in (" ", "\t")) or (cur is not None and tok[0] in SURFACE_KEYS)
        key = tok[0]
        if key == "SURF":
            cur = int(tok[1])
            surfs[cur] = {"type": "STANDARD"}
            continue
        if not indented:
            cur = None
            if key == "VERS":
                feat["vers"] = " ".join(tok[1:])
            elif key == "MODE":
                feat["mode"] = tok[1] if len(tok) > 1 else ""
            elif key == "UNIT":
                feat["unit"] = " ".join(tok[1:])
            elif key == "NAME":
                feat["name"] = ln[5:].strip()
            elif key in ("ENPD", "FNUM", "OBNA", "FLOA", "EFFL"):
                if key != "EFFL":
                    feat["system_aperture"] = {"type": key, "values": [_f(t) for t in tok[1:]]}
            elif key == "FTYP":
                feat["ftyp_raw"] = " ".join(tok[1:])
                try:
                    feat["field_type"] = FTYP_NAMES.get(int(tok[1]), "unknown_" + tok[1])
                except (IndexError, ValueError):
                    feat["field_type"] = None
            elif key in ("XFLN", "XFLD"):
                feat["xfln"] = [float(t) for t in tok[1:]]
            elif key in ("YFLN", "YFLD"):
                feat["yfln"] = [float(t) for t in tok[1:]]
            elif key == "WAVM":
                feat["wavelengths_um"][int(tok[1])] = float(tok[2])
            elif key == "WAVL":
                for i, t in enumerate(tok[1:]):
                    feat["wavelengths_um"][i + 1] = float(t)
            elif key == "PWAV":
                feat["pwav"] = int(tok[1])
            elif key == "GCAT":
                feat["gcat"] = tok[1:]
            elif key == "RAIM":
                feat["raim"] = " ".join(tok[1:])
            elif key in VIGNETTE_KEYS:
                vals = [float(t) for t in tok[1:]]
                feat["vignetting"][key] = vals
            elif key == "FLOA":
                feat["system_aperture"] = {"type": "FLOA", "values": []}
            else:
                seen_top.add(key)
            continue
        if cur is None:
            continue
        s = surfs[cur]
        if key == "TYPE":
            s["type"] = tok[1]
        elif key == "STOP":
            s["stop"] = True
        elif key == "GLAS":
            s["glass"] = tok[1]
        elif key == "DISZ":
            s["disz"] = _f(tok[1])
        elif key == "CONI":
            if float(tok[1]) != 0.0:
                s["conic"] = float(tok[1])
        elif key in APERTURE_KEYS:
            s.setdefault("apertures", {})[key] = [_f(t) for t in tok[1:4] if t != '""']
        elif key in ("DECX", "DECY", "TILTX", "TILTY", "SCBD", "TEZI"):
            s.setdefault("tilt_decenter", []).append(key)
        elif key in ("PZUP", "SLAB", "PKUP", "CHZN"):
            feat["has_pickups_or_solves"] = True
    for k in ("ENPD", "FNUM", "OBNA"):
        pass
    if "FLOA" in seen_top:
        feat["system_aperture"] = {"type": "FLOA", "values": []}
        seen_top.discard("FLOA")
    feat["other_top_level_keys"] = sorted(seen_top)
    feat["num_surfaces"] = len(surfs)
    glasses = []
    for i in sorted(surfs):
        s = surfs[i]
        feat["surface_types"][s["type"]] = feat["surface_types"].get(s["type"], 0) + 1
        if s.get("stop"):
            feat["stop_surface"] = i
        g = s.get("glass")
        if g is not None:
            if g.upper() == "MIRROR":
                feat["mirror_surfaces"].append(i)
            elif g not in glasses:
                glasses.append(g)
        d = s.get("disz")
        if isinstance(d, float) and d < 0:
            feat["negative_thickness_surfaces"].append(i)
        for a, v in s.get("apertures", {}).items():
            feat["apertures"].setdefault(a, []).append(i)
        if "conic" in s:
            feat["surfaces_with_conic"].append(i)
        if s["type"] == "COORDBRK":
            feat["coordbrk_surfaces"].append(i)
        if s.get("tilt_decenter"):
            feat["surface_tilt_decenter_keys"].append([i, sorted(set(s["tilt_decenter"]))])
    feat["glass_names"] = glasses
    if 0 in surfs:
        d = surfs[0].get("disz")
        feat["object_distance"] = "INFINITY" if d == float("inf") else d
    # drop zero-only vignetting columns but keep record that they exist
    feat["vignetting_nonzero"] = sorted(k for k, v in feat["vignetting"].items() if any(x != 0 for x in v))
    feat["wavelengths_um"] = {str(k): v for k, v in sorted(feat["wavelengths_um"].items())}
    return feat


if __name__ == "__main__":
    import json
    import sys
    for p in sys.argv[1:]:
        print(p)
        print(json.dumps(scan(p), indent=1))
