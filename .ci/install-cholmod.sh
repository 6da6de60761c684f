#!/usr/bin/env bash
# Optional: CHOLMOD (SuiteSparse) through scikit-sparse, the fastest sparse Cholesky measured here.
# Needs Debian's libsuitesparse-dev; every failure is tolerated (sc_fem falls back to scipy/cholespy).
PY=${1:-python3}
# CHOLMOD's dense kernels run on the system BLAS: Debian's reference BLAS factorizes 5x slower and
# solves 5-6x slower than OpenBLAS (measured: a 56k-DOF bunny, 16.3 s -> 3.0 s, 64 solves 2.8 s -> 0.5 s).
# The serial OpenBLAS takes the libblas.so.3 alternative and never competes with numpy's own threads.
openblas() {
  ls /usr/lib/x86_64-linux-gnu/openblas-serial/libblas.so.3 /usr/lib/aarch64-linux-gnu/openblas-serial/libblas.so.3 \
    >/dev/null 2>&1 && return 0
  command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ] || return 0
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libopenblas0-serial >/dev/null 2>&1 \
    || echo "note: libopenblas0-serial not installed; CHOLMOD runs on the reference BLAS (slower)"
}
if "$PY" -c "import sksparse.cholmod" 2>/dev/null; then openblas; exit 0; fi
if ! ls /usr/include/suitesparse/cholmod.h >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libsuitesparse-dev) >/dev/null 2>&1 \
      || { echo "note: libsuitesparse-dev not installed; using the fallback Cholesky backend"; exit 0; }
  else
    echo "note: no root/apt; skipping CHOLMOD (fallback backend is used)"; exit 0
  fi
fi
openblas
"$PY" -m pip install -q "scikit-sparse==0.4.16" >/dev/null 2>&1 \
  || "$PY" -m pip install -q scikit-sparse >/dev/null 2>&1 \
  || echo "note: scikit-sparse did not build; using the fallback Cholesky backend"
exit 0
