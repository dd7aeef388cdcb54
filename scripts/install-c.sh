#!/usr/bin/env bash
# Installs tolray for C and C++ users under PREFIX:
#   PREFIX/include/tolray.h
#   PREFIX/lib/libtolray.so.3 (SONAME libtolray.so.3, the ABI version), the link
#   PREFIX/lib/libtolray.so -> libtolray.so.3 for the linker, PREFIX/lib/libtolray.a
#   PREFIX/lib/pkgconfig/tolray.pc (shared) and tolray-static.pc (static)
#   PREFIX/lib/cmake/tolray/ (find_package(tolray) -> tolray::tolray, tolray::tolray_static)
#
# The installed libraries are stripped of debug information (TOLRAY_KEEP_DEBUG=1 keeps it).
#
# Usage: scripts/install-c.sh PREFIX [LIBDIR]
#   LIBDIR: a directory that already holds libtolray.so and libtolray.a; by default the library
#   is built with `cargo build --release --lib` and taken from target/release.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
prefix="${1:?usage: scripts/install-c.sh PREFIX [LIBDIR]}"
libdir="${2:-}"
if [ -z "$libdir" ]; then
    (cd "$root" && cargo build --release --lib)
    libdir="${CARGO_TARGET_DIR:-$root/target}/release"
fi
for f in libtolray.so libtolray.a; do
    [ -f "$libdir/$f" ] || { echo "install-c.sh: $libdir/$f not found" >&2; exit 1; }
done
version="$(sed -n 's/^version = "\(.*\)"/\1/p' "$root/Cargo.toml" | head -n1)"
mkdir -p "$prefix"
prefix="$(cd "$prefix" && pwd)"
mkdir -p "$prefix/include" "$prefix/lib/pkgconfig" "$prefix/lib/cmake/tolray"
install -m 644 "$root/include/tolray.h" "$prefix/include/"
# The shared library is installed under its SONAME (the ABI version, set by build.rs), with the
# unversioned name as a link for `-ltolray`.
abi="$(sed -n 's/^#define TOLRAY_ABI_VERSION \([0-9]*\)$/\1/p' "$root/include/tolray.h")"
[ -n "$abi" ] || { echo "install-c.sh: TOLRAY_ABI_VERSION not found in include/tolray.h" >&2; exit 1; }
soname="libtolray.so.$abi"
rm -f "$prefix/lib/libtolray.so" "$prefix/lib/$soname"
install -m 755 "$libdir/libtolray.so" "$prefix/lib/$soname"
ln -s "$soname" "$prefix/lib/libtolray.so"
install -m 644 "$libdir/libtolray.a" "$prefix/lib/"
# The installed libraries carry no debug information (measured: libtolray.a 113 MB -> 37 MB,
# libtolray.so 40 MB -> 4.8 MB); TOLRAY_KEEP_DEBUG=1 keeps it. Symbols stay: C users link by them.
if [ -z "${TOLRAY_KEEP_DEBUG:-}" ]; then
    if command -v strip >/dev/null 2>&1; then
        strip --strip-debug "$prefix/lib/$soname" "$prefix/lib/libtolray.a"
    else
        echo "install-c.sh: strip not found; the libraries keep their debug information" >&2
    fi
fi
# The system libraries a Rust staticlib needs (rustc --print native-static-libs on Linux).
static_libs="-lgcc_s -lutil -lrt -lpthread -lm -ldl -lc"

# pkg-config splits flags at whitespace: spaces in the prefix are escaped with a backslash.
pc_prefix="${prefix// /\\ }"
cat > "$prefix/lib/pkgconfig/tolray.pc" <<PC
prefix=$pc_prefix
libdir=\${prefix}/lib
includedir=\${prefix}/include

Name: tolray
Description: Tolerance-aware lens design: exact, differentiable ray tracing with tolerances
Version: $version
Cflags: -I\${includedir}
Libs: -L\${libdir} -ltolray -Wl,-rpath,\${libdir} -lm
PC
cat > "$prefix/lib/pkgconfig/tolray-static.pc" <<PC
prefix=$pc_prefix
libdir=\${prefix}/lib
includedir=\${prefix}/include

Name: tolray-static
Description: tolray, linked statically
Version: $version
Cflags: -I\${includedir}
Libs: \${libdir}/libtolray.a $static_libs
PC

cat > "$prefix/lib/cmake/tolray/tolrayConfig.cmake" <<CMAKE
# tolray's CMake package: find_package(tolray) defines tolray::tolray (shared library) and
# tolray::tolray_static (static library), both carrying the include directory.
get_filename_component(_tolray_prefix "\${CMAKE_CURRENT_LIST_DIR}/../../.." ABSOLUTE)
if(NOT TARGET tolray::tolray)
  add_library(tolray::tolray SHARED IMPORTED)
  set_target_properties(tolray::tolray PROPERTIES
    IMPORTED_LOCATION "\${_tolray_prefix}/lib/$soname"
    IMPORTED_SONAME "$soname"
    INTERFACE_INCLUDE_DIRECTORIES "\${_tolray_prefix}/include")
  add_library(tolray::tolray_static STATIC IMPORTED)
  set_target_properties(tolray::tolray_static PROPERTIES
    IMPORTED_LOCATION "\${_tolray_prefix}/lib/libtolray.a"
    INTERFACE_INCLUDE_DIRECTORIES "\${_tolray_prefix}/include"
    INTERFACE_LINK_LIBRARIES "gcc_s;util;rt;pthread;m;dl")
endif()
unset(_tolray_prefix)
CMAKE
cat > "$prefix/lib/cmake/tolray/tolrayConfigVersion.cmake" <<CMAKE
# Compatible when the major (and, before 1.0, the minor) version matches and the installed
# version is not older than the one asked for.
set(PACKAGE_VERSION "$version")
set(PACKAGE_VERSION_COMPATIBLE FALSE)
if(NOT PACKAGE_FIND_VERSION VERSION_GREATER PACKAGE_VERSION)
  string(REPLACE "." ";" _have "\${PACKAGE_VERSION}")
  list(GET _have 0 _major)
  list(GET _have 1 _minor)
  if(PACKAGE_FIND_VERSION_MAJOR EQUAL _major AND
     (NOT _major EQUAL 0 OR PACKAGE_FIND_VERSION_MINOR EQUAL _minor))
    set(PACKAGE_VERSION_COMPATIBLE TRUE)
  endif()
endif()
if(PACKAGE_FIND_VERSION STREQUAL PACKAGE_VERSION)
  set(PACKAGE_VERSION_EXACT TRUE)
endif()
CMAKE
echo "installed tolray $version under $prefix"
