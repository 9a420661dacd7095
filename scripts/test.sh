#!/usr/bin/env bash
# Install what the build needs, then build and run every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# The tests run under cargo-nextest (one process per test); install it where it is missing.
cargo nextest --version >/dev/null 2>&1 || cargo install --locked cargo-nextest
status=0
# A whole run (no arguments) checks the formatting and the lints: `-D warnings` makes any
# warning, clippy's and the workspace's `[workspace.lints]` included, a failure.
if [ $# -eq 0 ]; then
  cargo fmt --all --check || { echo "cargo fmt --check: run 'cargo fmt --all'" >&2; status=1; }
fi
if [ "${CI:-}" = true ]; then
  # A one-off CI build gains nothing from incremental artefacts; they only take disk. Its
  # builds lint as they compile: clippy-driver compiles the workspace's crates (cargo runs
  # `cargo clippy` so too), which spares a separate check of every dependency (18 minutes
  # on 2 cores). The benches, which no test builds, are compiled below.
  export CARGO_INCREMENTAL=0 RUSTFLAGS="${RUSTFLAGS:-} -D warnings"
  RUSTC_WORKSPACE_WRAPPER="$(dirname "$(rustup which cargo 2>/dev/null || command -v cargo)")/clippy-driver"
  export RUSTC_WORKSPACE_WRAPPER
elif [ $# -eq 0 ]; then
  cargo clippy --workspace --all-targets -- -D warnings || status=$?
fi
# The engine-only binary (no FFmpeg, SQLite built in: what GPU nodes run, docs/cluster.md),
# kept apart from the full build's target/debug/pipeline; the `engine_only` test runs it.
target="$(realpath -m "${CARGO_TARGET_DIR:-target}")"
cargo build -p pipeline --no-default-features --features bundled-sqlite || status=$?
mkdir -p "$target/engine-only"
cp "$target/debug/pipeline" "$target/engine-only/pipeline" || status=$?
export PIPELINE_ENGINE_ONLY="$target/engine-only/pipeline"
cargo nextest run --workspace --no-fail-fast "$@" || status=$?
if [ "${CI:-}" = true ] && [ $# -eq 0 ]; then
  cargo test --workspace --benches --no-run || status=$?
fi
# Live capture through nokhwa is a feature (`--features nokhwa`): compile it and run the
# tests that change with it (rig's unit tests, the recorder, `pipeline record`). The same
# workspace-wide build, so only rig, pipeline and nokhwa compile again.
if [ $# -eq 0 ]; then
  cargo nextest run --workspace --features pipeline/nokhwa --no-fail-fast \
    -E 'package(rig) & (kind(lib) | test(/^record_live::/)) | package(pipeline) & test(/^cli::record/)' ||
    status=$?
fi
exit "$status"
