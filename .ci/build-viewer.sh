#!/usr/bin/env bash
# The web viewer's JavaScript: three.js and esbuild from the npm registry (pinned), bundled with
# src/sc_fem/io/_viewer/main.js into src/sc_fem/io/_viewer/viewer.js. Also installs the Khronos glTF
# validator used by the tests. Without node/npm: a note, and `sc-fem view` says what is missing.
set -u
cd "$(dirname "$0")/.."
OUT=src/sc_fem/io/_viewer/viewer.js
if ! command -v npm >/dev/null 2>&1; then
  echo "note: npm not found; the web viewer (sc-fem view) is not built"; exit 0
fi
mkdir -p build/npm
if [ ! -x build/npm/node_modules/.bin/esbuild ] || [ ! -d build/npm/node_modules/gltf-validator ]; then
  (cd build/npm && [ -f package.json ] || npm init -y >/dev/null 2>&1
   npm install --no-audit --no-fund --silent three@0.170.0 esbuild@0.24.0 gltf-validator@2.0.0-dev.3.10) \
    || { echo "note: npm install failed; the web viewer is not built"; exit 0; }
fi
NODE_PATH=build/npm/node_modules build/npm/node_modules/.bin/esbuild src/sc_fem/io/_viewer/main.js \
  --bundle --minify --format=iife --target=es2020 --log-level=warning --outfile="$OUT.tmp" \
  && mv "$OUT.tmp" "$OUT" || { rm -f "$OUT.tmp"; echo "note: esbuild failed; the web viewer is not built"; }
exit 0
