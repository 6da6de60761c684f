#!/usr/bin/env bash
# Optional: CHOLMOD (SuiteSparse) through scikit-sparse, the fastest sparse Cholesky measured here.
# Needs Debian's libsuitesparse-dev; every failure is tolerated (sc_fem falls back to scipy/cholespy).
PY=${1:-python3}
"$PY" -c "import sksparse.cholmod" 2>/dev/null && exit 0
if ! ls /usr/include/suitesparse/cholmod.h >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libsuitesparse-dev) >/dev/null 2>&1 \
      || { echo "note: libsuitesparse-dev not installed; using the fallback Cholesky backend"; exit 0; }
  else
    echo "note: no root/apt; skipping CHOLMOD (fallback backend is used)"; exit 0
  fi
fi
"$PY" -m pip install -q "scikit-sparse==0.4.16" >/dev/null 2>&1 \
  || "$PY" -m pip install -q scikit-sparse >/dev/null 2>&1 \
  || echo "note: scikit-sparse did not build; using the fallback Cholesky backend"
exit 0
