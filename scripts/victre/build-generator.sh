#!/usr/bin/env bash
# Build the FDA VICTRE breast phantom generator (DIDSR/breastPhantom) and,
# optionally, its FE compression tool (DIDSR/breastCompress) and FEBio 2.x
# from source on Debian 12 (bookworm). EVALUATION DATA ONLY (issue #48, point 5).
#
# Usage:
#   scripts/victre/build-generator.sh [WORKDIR]          # generator only
#   WITH_COMPRESS=1 scripts/victre/build-generator.sh    # + breastCompress
#   WITH_FEBIO=1    scripts/victre/build-generator.sh    # + FEBio 2 (slow; see README)
#
# WORKDIR defaults to /work/victre (outside the repository). Idempotent: a
# checkout already at the pinned commit is reused, a patch already applied is
# skipped, and cmake/make only rebuild what changed.
#
# Sources (public domain / CC0, FDA DIDSR):
#   https://github.com/DIDSR/breastPhantom   docs: https://breastphantom.readthedocs.io
#     (docs/installation.rst lists the Ubuntu 16.04 / VTK 6 packages; the
#      Debian 12 equivalents are below)
#   https://github.com/DIDSR/breastCompress  docs: https://breastcompress.readthedocs.io
#     (needs FEBio 2: it runs $FEBIO_PATH/bin/febio2.lnx64 and parses its
#      version-0x0005 .xplt plot file itself; libtet1.5-dev for TetGen)
#   https://github.com/febiosoftware/FEBio   (FEBio 2.x: last FEBio2 commit
#     4a6c891, 2018-08-24, built with its own build/Makefile "sky" target:
#     g++ and the built-in skyline solver, i.e. no Intel MKL/Pardiso)
#
# Git sources: by default the local mirrors made by the session `fetch` tool
# (/work/.mirror/...), else GitHub. Override with BREASTPHANTOM_GIT,
# BREASTCOMPRESS_GIT, FEBIO_GIT.
set -euo pipefail

WORKDIR=${1:-/work/victre}
JOBS=${JOBS:-2}
NICE=${NICE:-10}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
PATCHES="$HERE/patches"

# Pinned upstream commits (breastPhantom/breastCompress: newest on master when
# this was written; FEBio: the FEBio 2 code line, not the current FEBio 4).
BREASTPHANTOM_REV=370336f312074a8f90a37dfb51cee1a7e9bc517e   # 2019-03-28 "fix for voxel size greater than 200 micron"
BREASTCOMPRESS_REV=7f12214f33f60e8f3559ce4e8cffcfa61895c54b  # 2018-12-17 "add disclaimer"
FEBIO2_REV=4a6c891279cde2fc64e0a4093263cc4734107ffc          # 2018-08-24, last FEBio2 commit before the FEBio3 rename

pick_src() { # $1 = mirror dir, $2 = GitHub URL
  if [ -d "$1" ]; then echo "$1"; else echo "$2"; fi
}
BREASTPHANTOM_GIT=${BREASTPHANTOM_GIT:-$(pick_src /work/.mirror/DIDSR+breastPhantom/repo https://github.com/DIDSR/breastPhantom)}
BREASTCOMPRESS_GIT=${BREASTCOMPRESS_GIT:-$(pick_src /work/.mirror/DIDSR+breastCompress/repo/.git https://github.com/DIDSR/breastCompress)}
FEBIO_GIT=${FEBIO_GIT:-$(pick_src /work/.mirror/febiosoftware+FEBio/repo https://github.com/febiosoftware/FEBio)}

SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO=sudo; fi

# --- 1. Debian build dependencies ------------------------------------------
# breastPhantom: VTK (9.1 in bookworm; upstream used VTK 6), BLAS/LAPACK,
# Boost program_options, zlib (CMakeLists.txt target_link_libraries line).
# breastCompress additionally links TetGen (libtet1.5-dev).
PKGS="cmake make g++ git libvtk9-dev libblas-dev liblapack-dev libboost-dev libboost-program-options-dev zlib1g-dev"
if [ "${WITH_COMPRESS:-0}" = 1 ]; then PKGS="$PKGS libtet1.5-dev"; fi
if [ "${WITH_FEBIO:-0}" = 1 ]; then PKGS="$PKGS patch"; fi
missing=""
for p in $PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing="$missing $p"
done
if [ -n "$missing" ]; then
  $SUDO apt-get update
  # --no-install-recommends keeps Qt out; the patched CMakeLists asks VTK only
  # for the modules the code uses, so VTK's Qt module is never looked up.
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends $missing
fi

mkdir -p "$WORKDIR"

checkout() { # $1 = git source, $2 = dir, $3 = commit
  if [ ! -d "$2/.git" ]; then
    git clone -q "$1" "$2"
  fi
  if [ "$(git -C "$2" rev-parse HEAD 2>/dev/null || true)" != "$3" ]; then
    git -C "$2" checkout -q "$3"
  fi
}

apply_patch() { # $1 = dir, $2 = patch file
  if git -C "$1" apply --reverse --check "$2" 2>/dev/null; then
    echo "patch already applied: $(basename "$2")"
  else
    git -C "$1" apply "$2"
  fi
}

cmake_build() { # $1 = source dir, $2 = build dir
  mkdir -p "$2"
  (cd "$2" && nice -n "$NICE" cmake -DCMAKE_BUILD_TYPE=Release "$1" >/dev/null && nice -n "$NICE" make -j"$JOBS")
}

# --- 2. breastPhantom --------------------------------------------------------
# The patch makes the 2019 code build against VTK 9.1 / g++ 12 without
# changing what it computes: find_package(VTK COMPONENTS ...), no
# VTK_USE_FILE, VTK include paths for the helper libraries, a forced
# vtkVersionMacros.h include (the VTK_MAJOR_VERSION <= 5 branches otherwise
# pick the VTK 5 API), and std::ifstream / <fstream>.
checkout "$BREASTPHANTOM_GIT" "$WORKDIR/breastPhantom" "$BREASTPHANTOM_REV"
apply_patch "$WORKDIR/breastPhantom" "$PATCHES/breastPhantom-debian12-vtk9.patch"
cmake_build "$WORKDIR/breastPhantom" "$WORKDIR/build"
echo "built: $WORKDIR/build/breastPhantom"

# --- 3. breastCompress (optional) --------------------------------------------
if [ "${WITH_COMPRESS:-0}" = 1 ]; then
  checkout "$BREASTCOMPRESS_GIT" "$WORKDIR/breastCompress" "$BREASTCOMPRESS_REV"
  apply_patch "$WORKDIR/breastCompress" "$PATCHES/breastCompress-debian12-vtk9.patch"
  cmake_build "$WORKDIR/breastCompress" "$WORKDIR/build-compress"
  echo "built: $WORKDIR/build-compress/breastCompress"
fi

# --- 4. FEBio 2 (optional, slow: ~550 C++ files) -----------------------------
# breastCompress expects $FEBIO_PATH/bin/febio2.lnx64 and parses FEBio 2's
# plot file (PLT_VERSION 0x0005 at this commit). FEBio's own 2018 Makefile is
# used with its "sky" platform (g++, built-in skyline solver, no Intel MKL /
# Pardiso, which VICTRE used). At this commit "sky" no longer built as shipped;
# patches/FEBio2-4a6c891-gcc12-nomkl.patch: -O2 -std=c++11 -fopenmp and forced
# standard headers for g++ 12, MKL-only code in NumCore/CSRMatrix.cpp (sparse
# mat-vec, replaced by a plain loop) and NumCore/Preconditioner.cpp (ILU
# preconditioners, disabled) put behind MKL_ISS, and bin/febio.xml switched to
# the skyline solver (the Makefile's own comment asks for that). The mirror
# lacks some large Documentation blobs, so only the source folders are
# exported with `git archive`.
if [ "${WITH_FEBIO:-0}" = 1 ]; then
  FEB="$WORKDIR/FEBio2"
  if [ ! -f "$FEB/build/Makefile" ]; then
    if [ ! -d "$FEBIO_GIT" ]; then   # a URL: make a local bare clone first
      [ -d "$WORKDIR/FEBio.git" ] || git clone -q --bare "$FEBIO_GIT" "$WORKDIR/FEBio.git"
      FEBIO_GIT="$WORKDIR/FEBio.git"
    fi
    mkdir -p "$FEB"
    git --git-dir="$FEBIO_GIT" archive "$FEBIO2_REV" build FEBio2 FEBioFluid FEBioLib FEBioMech \
      FEBioMix FEBioOpt FEBioPlot FEBioTest FEBioXML FECore NumCore | tar -x -C "$FEB"
  fi
  if patch -d "$FEB" -p1 --dry-run -R -s -f < "$PATCHES/FEBio2-4a6c891-gcc12-nomkl.patch" >/dev/null 2>&1; then
    echo "patch already applied: FEBio2-4a6c891-gcc12-nomkl.patch"
  else
    patch -d "$FEB" -p1 -s < "$PATCHES/FEBio2-4a6c891-gcc12-nomkl.patch"
  fi
  (cd "$FEB/build" && { [ -d sky ] || bash Mkdir.bash sky >/dev/null; } && mkdir -p lib bin \
    && nice -n "$NICE" make -j"$JOBS" sky)
  ln -sf febio2.sky "$FEB/build/bin/febio2.lnx64"
  echo "built: $FEB/build/bin/febio2.lnx64 (use FEBIO_PATH=$FEB/build)"
fi
