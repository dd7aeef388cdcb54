#!/usr/bin/env python3
"""Generates src/lens/catalog_agf.rs: the built-in catalogs that OpticStudio ships and .zmx files
name in their GCAT lines but that the refractiveindex.info vendor pages (catalog_data.rs) do not
cover: INFRARED, MISC, LIGHTPATH, RPO, and the glasses of Hoya's 2013 catalog that Hoya's current
one has dropped (legacy names such as FD10 that older files still use).

Run once, by hand, when these catalogs are to be refreshed; nothing reads this at build or run
time. The AGF files are read from the nzhagen/zemaxglass repository (MIT; its AGF_files/ folder
holds the catalogs as Zemax and the vendors published them):

    git clone https://github.com/nzhagen/zemaxglass /tmp/zemaxglass
    git -C /tmp/zemaxglass checkout bb2486d0367dc97886627493096ad74dd6a32aa4
    python3 scripts/glass/generate_agf_catalogs.py /tmp/zemaxglass/AGF_files > new.rs
    mv new.rs src/lens/catalog_agf.rs

Each glass keeps the AGF's formula id (mapped to tolray's `Dispersion` exactly as
`lens::agf::dispersion_from_agf` maps it), coefficients, nominal n_d / V_d and wavelength range,
and its vendor; its source line (`GC`) is kept as a comment. Nothing is refitted. Left out, and
listed on stderr: names the built-in tables already hold for that vendor (catalog_data.rs and
catalog_extra.rs win), a second entry of one name in one file (the first wins, as OpticStudio
reads it), names that would read as something else in a lens file (air, vacuum, a number, n/V),
and glasses whose index is below 1 at d (MISC's VACUUM, which tolray writes as air). The Rust
test `catalog_glasses_reproduce_their_nominal_nd_vd` checks every glass whose range covers the
F, d and C lines against its nominal n_d and V_d.
"""
import os
import re
import sys

COMMIT = "bb2486d0367dc97886627493096ad74dd6a32aa4"
# (file in AGF_files/, vendor as tolray prints it, encoding, what the file is)
FILES = [
    ("infrared.agf", "Infrared", "latin-1", "Zemax INFRARED catalog (as shipped with OpticStudio 2013)"),
    ("misc.agf", "Misc", "latin-1", "Zemax MISC catalog (as shipped with OpticStudio 2013)"),
    ("lightpath.agf", "LightPath", "latin-1", "LightPath/Geltech moulded-glass catalog"),
    ("rpo.agf", "RPO", "latin-1", "Rochester Precision Optics moulded-glass catalog (updated 2009-02-25)"),
    ("hoya.agf", "Hoya", "utf-16", "HOYA optical glass catalog 2013 (legacy names only)"),
]
# Zemax formula id -> (tolray variant, field layout): 'a' = coefficients in order (count), 'bc' =
# Sellmeier pairs (count), as lens::agf::dispersion_from_agf.
FORMULAS = {
    1: ("Schott", "a", 6), 2: ("Sellmeier3", "bc", 3), 3: ("Herzberger", "a", 6),
    4: ("ZemaxSellmeier2", "a", 5), 5: ("Conrady", "a", 3), 6: ("Sellmeier4", "bc", 4),
    7: ("Handbook1", "a", 4), 8: ("Handbook2", "a", 4), 9: ("ZemaxSellmeier4", "a", 5),
    10: ("ExtendedSchott", "a", 8), 11: ("Sellmeier5", "bc", 5), 12: ("Extended2", "a", 8),
    13: ("Extended", "a", 9),
}


def fnum(x):
    r = repr(float(x))
    return r if ("." in r or "e" in r or "inf" in r or "nan" in r) else r + ".0"


def arr(xs):
    return "[" + ", ".join(fnum(x) for x in xs) + "]"


def rust_dispersion(fid, c):
    kind, layout, n = FORMULAS[fid]
    c = list(c) + [0.0] * 20
    if layout == "a":
        return f"Dispersion::{kind} {{ a: {arr(c[:n])} }}"
    return f"Dispersion::{kind} {{ b: {arr(c[0:2 * n:2])}, c: {arr(c[1:2 * n:2])} }}"


def unnameable(name):
    low = name.strip().lower()
    if low in ("air", "vacuum", "occluder") or "/" in low or (low.endswith(")") and " (" in low):
        return True
    try:
        float(low)
        return True
    except ValueError:
        return False


def read_agf(path, encoding):
    text = open(path, "rb").read().decode(encoding)
    glasses, cur = [], None
    for line in text.splitlines():
        t = line.split()
        if not t:
            continue
        if t[0] == "NM" and len(t) >= 6:
            cur = {"name": t[1], "formula": int(float(t[2])), "nd": float(t[4]), "vd": float(t[5]),
                   "cd": [], "ld": (0.0, float("inf")), "gc": ""}
            glasses.append(cur)
        elif cur is not None and t[0] == "CD":
            cur["cd"] = [float(x) for x in t[1:]]
        elif cur is not None and t[0] == "LD" and len(t) >= 3:
            cur["ld"] = (float(t[1]), float(t[2]))
        elif cur is not None and t[0] == "GC":
            cur["gc"] = line[2:].strip()
    return glasses


def builtin_names(here):
    names = set()
    for f in ("catalog_data.rs", "catalog_extra.rs"):
        src = open(os.path.join(here, "..", "..", "src", "lens", f)).read()
        names |= {(v, n.upper()) for n, v in re.findall(r'name: "([^"]+)",\s*vendor: "([^"]+)"', src)}
    return names


def main():
    root = sys.argv[1]
    here = os.path.dirname(os.path.abspath(__file__))
    have = builtin_names(here)
    entries, skipped, counts = [], [], {}
    for fname, vendor, enc, _ in FILES:
        seen = set()
        for g in read_agf(os.path.join(root, fname), enc):
            key = g["name"].upper()
            why = None
            if (vendor, key) in have:
                why = "already built in"
            elif key in seen:
                why = "second entry of this name in the file"
            elif unnameable(g["name"]):
                why = "name reads as something else in a lens file"
            elif g["formula"] not in FORMULAS:
                why = f"formula {g['formula']} unknown"
            elif g["nd"] < 1.0 and g["vd"] != 0.0:
                why = "index below 1 (tolray writes vacuum as air)"
            seen.add(key)
            if why:
                skipped.append(f"{fname}: {g['name']}: {why}")
                continue
            entries.append((vendor, g, fname))
            counts[vendor] = counts.get(vendor, 0) + 1
    out = [HEADER.format(n=len(entries), commit=COMMIT, files="".join(
        f"//! - **{v}** ({counts.get(v, 0)}): `{f}`, {what}.\n" for f, v, _, what in FILES))]
    for vendor, g, fname in sorted(entries, key=lambda e: (e[0].upper(), e[1]["name"].upper())):
        lo, hi = g["ld"]
        src = f"  // {g['gc']}" if g["gc"] else ""
        out.append(
            f'    CatalogGlass {{ name: "{g["name"]}", vendor: "{vendor}", '
            f'dispersion: {rust_dispersion(g["formula"], g["cd"])}, nd: {fnum(g["nd"])}, '
            f'vd: {fnum(g["vd"])}, range_um: ({fnum(lo)}, {fnum(hi)}) }},{src}\n'
        )
    out.append("];\n")
    sys.stdout.write("".join(out))
    for s in skipped:
        print("skipped", s, file=sys.stderr)
    print(f"{len(entries)} generated ({counts}), {len(skipped)} skipped", file=sys.stderr)


HEADER = """//! The built-in catalogs read from Zemax AGF files ({n} glasses): OpticStudio's INFRARED and
//! MISC catalogs, LightPath's and RPO's moulded glasses, and the legacy names of Hoya's 2013
//! catalog, which .zmx files name in their `GCAT` lines and the vendor pages behind
//! `catalog_data.rs` do not cover.
//!
//! Generated by `scripts/glass/generate_agf_catalogs.py` (do not edit by hand) from the AGF files
//! in the nzhagen/zemaxglass repository (MIT), `AGF_files/` at commit {commit}:
//!
{files}//!
//! Each entry is the AGF's own: formula (mapped as `agf::dispersion_from_agf` maps it),
//! coefficients, nominal n_d / V_d and wavelength range; the comment after it is the file's `GC`
//! source line (the literature each INFRARED and MISC material comes from). Names the other
//! tables hold for the same vendor are left out (they win), as are a second entry of one name
//! (the first wins, as in OpticStudio) and MISC's VACUUM. Infrared materials whose range misses
//! the visible carry the AGF's nominal n_d / V_d as the file gives them (often 1 and 0); the test
//! `catalog_glasses_reproduce_their_nominal_nd_vd` checks every glass whose range covers F, d, C.
use super::material::{{CatalogGlass, Dispersion}};

/// Catalog glasses read from AGF files, sorted by vendor then name, one a line.
#[rustfmt::skip]
pub(crate) const AGF: &[CatalogGlass] = &[
"""

if __name__ == "__main__":
    main()
