#!/usr/bin/env bash
# Install what the build needs, then build and run every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# A one-off CI build gains nothing from incremental artefacts; they only take disk.
if [ "${CI:-}" = true ]; then export CARGO_INCREMENTAL=0; fi
if cargo nextest --version >/dev/null 2>&1; then
  exec cargo nextest run --workspace --no-fail-fast "$@"
else
  exec cargo test --workspace --no-fail-fast "$@"
fi
