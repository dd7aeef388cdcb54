#!/usr/bin/env bash
# Copies the Embree 4 and oneTBB libraries a `tolray` binary built with `--features embree` was
# linked against into DEST, so that the binary (or the library) keeps working after the build
# directory is gone: its rpath searches its own directory and ../lib first.
#
# Usage: scripts/bundle-embree.sh BINARY DEST
#   e.g. after `cargo install --path cli --features embree`:
#        scripts/bundle-embree.sh ~/.cargo/bin/tolray ~/.cargo/lib
# The libraries are found in the binary's absolute rpath entries (the build directory's copy of
# the pinned PyPI wheel, or EMBREE_DIR). A system Embree (/usr/lib) needs no bundling.
set -euo pipefail
bin="${1:?usage: scripts/bundle-embree.sh BINARY DEST}"
dest="${2:?usage: scripts/bundle-embree.sh BINARY DEST}"
[ -f "$bin" ] || { echo "bundle-embree.sh: $bin not found" >&2; exit 1; }
runpath="$(readelf -d "$bin" | sed -n 's/.*(RUNPATH).*\[\(.*\)\]/\1/p; s/.*(RPATH).*\[\(.*\)\]/\1/p' | head -n1)"
src=""
IFS=':' read -r -a dirs <<< "$runpath"
for d in "${dirs[@]}"; do
    case "$d" in /*) [ -e "$d/libembree4.so" ] && { src="$d"; break; } ;; esac
done
if [ -z "$src" ]; then
    echo "bundle-embree.sh: no rpath entry of $bin holds libembree4.so (rpath: ${runpath:-none});" \
         "was it built with --features embree against a non-system Embree?" >&2
    exit 1
fi
mkdir -p "$dest"
n=0
for f in "$src"/libembree4*.so* "$src"/libtbb*.so*; do
    [ -e "$f" ] || continue
    cp -P "$f" "$dest/"
    n=$((n + 1))
done
[ -f "$src/LICENSE" ] && cp "$src/LICENSE" "$dest/embree4-LICENSE"
echo "copied $n Embree/oneTBB files from $src to $dest"
