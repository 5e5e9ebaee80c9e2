#!/usr/bin/env bash
# Creates or completes .venv-bench with the peers of bench/sot: pink (+ daqp) and TSID 1.10.0.
# TSID: libtsid has no cp311 wheel, so it is compiled from its sdist (~17 min on one core, once);
# the benchmark links the C++ library (bench/sot_peers/CMakeLists.txt), TSID's Python bindings
# are not needed. cmeel builds against the venv's cmeel prefix, which is why eiquadprog is
# installed first.
# Idempotent: does nothing when everything is there. Shared with other benchmarks (HPP): only
# adds packages, with the product's pin version.
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV=${MARIONETTE_BENCH_VENV:-$PWD/.venv-bench}
PY=${PYTHON:-python3}
say() { printf '\033[1m[bench venv]\033[0m %s\n' "$*" >&2; }
[ -x "$VENV/bin/python" ] || { say "creating $VENV"; "$PY" -m venv "$VENV"; }
pip=("$VENV/bin/python" -m pip install -q --disable-pip-version-check)
# (a compiler cache, when there is one, makes a rebuild of the sdists cheap: CMake reads these)
if command -v ccache >/dev/null; then
  export CMAKE_CXX_COMPILER_LAUNCHER=ccache CMAKE_C_COMPILER_LAUNCHER=ccache
fi
if ! "$VENV/bin/python" -c "import pink, daqp" 2>/dev/null; then
  say "installing pink + daqp"
  "${pip[@]}" -r bench/sot_peers/requirements.txt
fi
# The sdist is built without build isolation, against the build requirements installed here
# from PyPI: an isolated build lacks jrl-cmakemodules and clones it from its repository, which a
# machine reaching only the package registries cannot; found in the venv's cmeel prefix, it is
# used as is ("JRL cmakemodules found on system").
if [ ! -f "$VENV/lib/python3.11/site-packages/cmeel.prefix/lib/cmake/tsid/tsidConfig.cmake" ]; then
  say "installing the build requirements of libtsid (cmeel, jrl-cmakemodules) from PyPI"
  "${pip[@]}" -r bench/sot_peers/build-requirements.txt
  say "compiling libtsid 1.10.0 from its PyPI sdist (several minutes, once)"
  CMEEL_JOBS=${JOBS:-1} "${pip[@]}" --no-build-isolation --no-binary libtsid "libtsid==1.10.0" \
    -c bench/sot_peers/requirements.txt
fi
