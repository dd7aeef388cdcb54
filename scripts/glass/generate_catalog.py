#!/usr/bin/env python3
"""Generates src/lens/catalog_data.rs, tolray's built-in glass catalog, from the vendor glass
pages of the refractiveindex.info database (public domain, CC0 1.0), which transcribe the
vendors' own Zemax AGF downloads (each page names its source catalog and date).

Run once, by hand, when the catalog is to be refreshed; nothing reads this at build or run time:

    pip download --no-deps optiland==0.6.3        # bundles the database (optiland/database)
    unzip -q optiland-0.6.3-py3-none-any.whl 'optiland/database/data-nk/glass/*' -d db
    python3 scripts/glass/generate_catalog.py db/optiland/database/data-nk/glass > new.rs
    mv new.rs src/lens/catalog_data.rs

It writes one glass a line (the table is data: `#[rustfmt::skip]` keeps it so). Glasses the
database does not have (Zemax MISC plastics and crystals) are kept by hand
in src/lens/catalog_extra.rs, which this script neither reads nor writes; a name in both is
left out here, so the built-in catalog never holds a glass twice. Every generated entry is
checked: its formula must reproduce the
page's n_d to 5e-5 and V_d to 0.1 (or to the page's own rounding, when coarser), or the glass
is left out and listed on stderr with the reason.
"""
import glob
import os
import re
import sys

import yaml

VENDORS = {  # database folder -> vendor name as tolray prints it (Zemax GCAT names upper-cased)
    "schott": "Schott",
    "ohara": "Ohara",
    "cdgm": "CDGM",
    "hikari": "Hikari",
    "hoya": "Hoya",
    "sumita": "Sumita",
}
LD, LF, LC = 0.5875618, 0.4861327, 0.6562725


def sellmeier(b, c):
    return lambda l: (1 + sum(bi * l * l / (l * l - ci) for bi, ci in zip(b, c))) ** 0.5


def poly(a0, terms):
    return lambda l: (a0 + sum(c * l ** e for c, e in terms)) ** 0.5


def decimals(v):
    t = str(v)
    return len(t.split(".")[1]) if "." in t and "e" not in t.lower() else 0


def fnum(x):
    r = repr(float(x))
    return r if ("." in r or "e" in r or "inf" in r or "nan" in r) else r + ".0"


def arr(xs):
    return "[" + ", ".join(fnum(x) for x in xs) + "]"


def tabulated(pts):
    """n(λ) of (λ, n) points: linear between them, the end values beyond (as tolray and optiland)."""
    def n(l):
        if l <= pts[0][0]:
            return pts[0][1]
        if l >= pts[-1][0]:
            return pts[-1][1]
        k = next(i for i, p in enumerate(pts) if p[0] > l)
        (xa, ya), (xb, yb) = pts[k - 1], pts[k]
        return ya + (yb - ya) * (l - xa) / (xb - xa)
    return n


def convert(d):
    """(rust dispersion expression, python n(λ)) or None for a formula tolray lacks."""
    for e in d.get("DATA", []):
        t = e["type"].strip()
        if t == "tabulated n":
            # A page with measured indices only (Schott B 270, BOROFLOAT 33): kept as the table.
            pts = [tuple(float(x) for x in line.split()) for line in str(e["data"]).split("\n")
                   if line.strip()]
            rust = "Dispersion::Tabulated { points: &[" + ", ".join(
                f"({fnum(l)}, {fnum(n)})" for l, n in pts) + "] }"
            return rust, tabulated(pts), [pts[0][0], pts[-1][0]]
        if not t.startswith("formula"):
            continue
        c = [float(x) for x in str(e["coefficients"]).split()]
        rng = [float(x) for x in str(e["wavelength_range"]).split()]
        if t == "formula 2" and c[0] == 0 and len(c) in (7, 9, 11):
            b, cc = c[1::2], c[2::2]
            kind = {3: "Sellmeier3", 4: "Sellmeier4", 5: "Sellmeier5"}[len(b)]
            return f"Dispersion::{kind} {{ b: {arr(b)}, c: {arr(cc)} }}", sellmeier(b, cc), rng
        if t in ("formula 1", "formula 2") and len(c) == 5:
            sq = (lambda x: x * x) if t == "formula 1" else (lambda x: x)
            a = [1 + c[0], c[1], sq(c[2]), c[3], sq(c[4])]
            f = lambda l, a=a: (a[0] + a[1] * l * l / (l * l - a[2]) + a[3] * l * l / (l * l - a[4])) ** 0.5
            return f"Dispersion::ZemaxSellmeier4 {{ a: {arr(a)} }}", f, rng
        if t == "formula 3":
            a0, terms = c[0], list(zip(c[1::2], c[2::2]))
            ex = [e for _, e in terms]
            by = {e: k for k, e in terms}
            if ex == [2, -2, -4, -6, -8]:
                a = [a0] + [by[e] for e in (2, -2, -4, -6, -8)]
                return f"Dispersion::Schott {{ a: {arr(a)} }}", poly(a0, terms), rng
            if set(ex) <= {2, 4, -2, -4, -6, -8, -10, -12} and len(set(ex)) == len(ex):
                a = [a0] + [by.get(e, 0.0) for e in (2, 4, -2, -4, -6, -8, -10, -12)]
                return f"Dispersion::Extended {{ a: {arr(a)} }}", poly(a0, terms), rng
        return None
    return None


def main():
    root = sys.argv[1]
    here = os.path.dirname(os.path.abspath(__file__))
    extra = open(os.path.join(here, "..", "..", "src", "lens", "catalog_extra.rs")).read()
    kept = {
        (v, n.upper())
        for n, v in re.findall(r'name: "([^"]+)",\s*vendor: "([^"]+)"', extra)
    }
    entries, skipped, names = [], [], {}
    for folder, vendor in VENDORS.items():
        for path in sorted(glob.glob(os.path.join(root, folder, "**", "*.yml"), recursive=True)):
            rel = os.path.relpath(path, root)
            name = os.path.splitext(os.path.basename(path))[0]
            d = yaml.safe_load(open(path))
            specs = d.get("SPECS") or {}
            conv = convert(d)
            if conv is None:
                skipped.append(f"{rel}: formula not supported")
                continue
            rust, n, rng = conv
            # (Tables end at the C line rounded, 656.27 nm: 2.5e-6 µm short of it is its end.)
            if not (rng[0] <= LF and LC <= rng[1] + 1e-5):
                skipped.append(f"{rel}: the formula's range {rng} µm misses the d, F, C lines")
                continue
            try:
                nd_f = n(LD)
                vd_f = (nd_f - 1) / (n(LF) - n(LC))
            except (ZeroDivisionError, ValueError, TypeError):
                skipped.append(f"{rel}: formula has no real index at d, F or C")
                continue
            if isinstance(nd_f, complex) or isinstance(vd_f, complex):
                skipped.append(f"{rel}: formula has no real index at d, F or C")
                continue
            if "nd" in specs and "Vd" in specs:
                # The page's nominal values, as precise as the page writes them (some round).
                nd, vd = float(specs["nd"]), float(specs["Vd"])
                tol = lambda v, floor: max(floor, 0.5 * 10 ** -decimals(v))
                if abs(nd_f - nd) > tol(specs["nd"], 5e-5) or abs(vd_f - vd) > tol(specs["Vd"], 0.1):
                    skipped.append(f"{rel}: formula gives n_d {nd_f}, V_d {vd_f}; page says {nd}, {vd}")
                    continue
            else:
                # No nominal values on the page (B270, BOROFLOAT33, LF7): the formula's own.
                nd, vd = round(nd_f, 6), round(vd_f, 4)
            key = name.upper()
            if key in names and names[key][0] == vendor:
                skipped.append(f"{rel}: duplicate of {names[key][1]}")
                continue
            names.setdefault(key, (vendor, rel))
            entries.append((vendor, name, rust, nd, vd, rng, rel))
    entries = [e for e in entries if (e[0], e[1].upper()) not in kept]
    out = [HEADER.format(n=len(entries))]
    for vendor, name, rust, nd, vd, rng, rel in sorted(
        entries, key=lambda e: (e[0].upper(), e[1].upper())
    ):
        out.append(
            f'    CatalogGlass {{ name: "{name}", vendor: "{vendor}", dispersion: {rust}, '
            f"nd: {fnum(nd)}, vd: {fnum(vd)}, range_um: ({fnum(rng[0])}, {fnum(rng[1])}) }},\n"
        )
    out.append("];\n")
    sys.stdout.write("".join(out))
    for s in skipped:
        print("skipped", s, file=sys.stderr)
    print(f"{len(entries)} generated, {len(kept)} kept by hand, {len(skipped)} skipped", file=sys.stderr)


HEADER = """//! The generated part of the built-in glass catalog ({n} glasses): dispersion data of the
//! public vendor catalogs.
//!
//! Generated by `scripts/glass/generate_catalog.py` (do not edit by hand) from the vendor glass
//! pages of the refractiveindex.info database (public domain, CC0 1.0; as bundled in the
//! optiland 0.6.3 wheel on PyPI, `optiland/database/data-nk/glass/<vendor>/*.yml`). Each page
//! transcribes the vendor's own Zemax AGF download and names it:
//!
//! - **Schott**: SCHOTT Zemax catalog 2017-01-20b (schott.com), with `obsolete/`, `misc/`
//!   (B270, BOROFLOAT33, ...) and `infrared/` pages.
//! - **Ohara**: OHARA Zemax catalog 2017-11-30 (ohara-inc.co.jp).
//! - **CDGM**: CDGM Zemax catalog 2022-06 (cdgmgd.com).
//! - **Hikari**: Nikon/Hikari Zemax catalog 2017-11.
//! - **Hoya**: HOYA Zemax catalog (hoya-opticalworld.com), as the database's pages name it.
//! - **Sumita**: SUMITA Zemax catalog (sumita-opt.co.jp), likewise.
//!
//! Glasses the database lacks are kept by hand in `catalog_extra.rs`; `material::catalog()` is
//! the two together.
//!
//! Coefficients are the pages' own, in the formula the catalog uses (Sellmeier; the Schott
//! formula; Hikari's extended formula), never refitted. `nd`/`vd` are the catalog's nominal
//! values and `range_um` the formula's stated range. The generator keeps a glass only when its
//! formula reproduces the catalog n_d to 5e-5 and V_d to 0.1 at the d, F and C lines, or to the
//! page's rounding when coarser (the test `catalog_glasses_reproduce_their_nominal_nd_vd` checks
//! it again); pages without catalog values (LF7) take the formula's.
use super::material::{{CatalogGlass, Dispersion}};

/// Generated catalog glasses, sorted by vendor then name, one a line.
#[rustfmt::skip]
pub(crate) const CATALOG: &[CatalogGlass] = &[
"""

if __name__ == "__main__":
    main()
