#!/usr/bin/env bash
# Install what the build needs, then build and run every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# A one-off CI build gains nothing from incremental artefacts; they only take disk.
if [ "${CI:-}" = true ]; then export CARGO_INCREMENTAL=0; fi
status=0
# A whole run (no arguments) checks the formatting and the lints first: `-D warnings`
# makes any clippy warning, the workspace's `[workspace.lints]` included, a failure.
if [ $# -eq 0 ]; then
  cargo fmt --all --check || { echo "cargo fmt --check: run 'cargo fmt --all'" >&2; status=1; }
  cargo clippy --workspace --all-targets -- -D warnings || status=$?
fi
# The engine-only binary (no FFmpeg: what GPU nodes run, docs/cluster.md), kept apart from
# the full build's target/debug/pipeline; the `engine_only` test runs it.
target="$(realpath -m "${CARGO_TARGET_DIR:-target}")"
cargo build -p pipeline --no-default-features || status=$?
mkdir -p "$target/engine-only"
cp "$target/debug/pipeline" "$target/engine-only/pipeline" || status=$?
export PIPELINE_ENGINE_ONLY="$target/engine-only/pipeline"
if cargo nextest --version >/dev/null 2>&1; then
  cargo nextest run --workspace --no-fail-fast "$@" || status=$?
else
  cargo test --workspace --no-fail-fast "$@" || status=$?
fi
# Live capture through nokhwa is a feature (`--features nokhwa`): compile it and run the
# tests that change with it (its format/error mapping, the recorder, `pipeline record`).
if [ $# -eq 0 ]; then
  cargo test -p rig --features nokhwa --lib --no-fail-fast || status=$?
  cargo test -p rig --features nokhwa --test integration --no-fail-fast record_live:: || status=$?
  cargo test -p pipeline --features nokhwa --test integration --no-fail-fast cli::record || status=$?
fi
exit "$status"
