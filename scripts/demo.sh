#!/usr/bin/env bash
# Install what the build needs, build the `pipeline` command, and run the demo: simulate
# a 4-camera capture of a built-in scene and run every stage on it.
# Usage: scripts/demo.sh [OUT_DIR]   (default: ./4c4d-demo)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo build --release -p pipeline
exec target/release/pipeline demo "${1:-4c4d-demo}"
