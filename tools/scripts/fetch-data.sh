#!/usr/bin/env bash
# Fetches the test data that comes from npm (the Stanford bunny) and writes it as OUT_DIR/bunny.ply.
# Usage: tools/scripts/fetch-data.sh [OUT_DIR]   (default: build/data in the repository, where the unit tests
# look). Idempotent; prints the PLY's path on stdout and nothing else there.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
out="${1:-$root/build/data}"
case "$out" in /*) ;; *) out="$PWD/$out" ;; esac

if [ -f "$out/bunny.ply" ]; then
  echo "$out/bunny.ply"
  exit 0
fi
cd "$root"
if [ ! -f node_modules/bunny/package.json ]; then
  # npm's progress and notices go to stderr so that stdout carries only the path.
  if [ -f package-lock.json ]; then
    npm ci --no-audit --no-fund --loglevel=error >&2
  else
    npm install --no-audit --no-fund --loglevel=error >&2
  fi
fi
node tools/scripts/bunny-to-ply.js "$out"
