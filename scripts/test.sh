#!/usr/bin/env bash
# Install what the build needs, then build and run every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# A one-off CI build gains nothing from incremental artefacts; they only take disk.
if [ "${CI:-}" = true ]; then export CARGO_INCREMENTAL=0; fi
status=0
if cargo nextest --version >/dev/null 2>&1; then
  cargo nextest run --workspace --no-fail-fast "$@" || status=$?
else
  cargo test --workspace --no-fail-fast "$@" || status=$?
fi
# Live capture through nokhwa is a feature (`--features nokhwa`): compile it and run the
# tests that change with it (its format/error mapping, the recorder, `pipeline record`).
if [ $# -eq 0 ]; then
  cargo test -p rig --features nokhwa --lib --test record_live --no-fail-fast || status=$?
  cargo test -p pipeline --features nokhwa --test cli --no-fail-fast record || status=$?
fi
exit "$status"
