#!/usr/bin/env bash
# Make a pipeline capture of CMU Panoptic's five HD views (../shared/data/panoptic-5view):
# raw/cam0..cam3 train (views 00_03, 00_06, 00_12, 00_13), raw/cam4 (00_23) is held out,
# each an image sequence of the five moments; calibration.json is the data set's
# camera_parameters.json; capture.toml is fixtures/panoptic-capture.toml.
#   scripts/panoptic-capture.sh [DATA_DIR] OUT_DIR   then   pipeline run OUT_DIR
# Images and calibration are linked, not copied.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ $# -eq 1 ]; then
  data="$here/../shared/data/panoptic-5view"; out="$1"
elif [ $# -eq 2 ]; then
  data="$1"; out="$2"
else
  echo "usage: $0 [DATA_DIR] OUT_DIR" >&2; exit 2
fi
data="$(cd "$data" 2>/dev/null && pwd)" || { echo "error: $data does not exist (the panoptic-5view data set)" >&2; exit 1; }
[ -f "$data/camera_parameters.json" ] || { echo "error: $data/camera_parameters.json is missing: is $data the panoptic-5view folder?" >&2; exit 1; }
if [ -e "$out" ] && [ -n "$(ls -A "$out" 2>/dev/null)" ]; then
  echo "error: $out exists and is not empty; choose a new folder" >&2; exit 1
fi
views=(00_03 00_06 00_12 00_13 00_23)
for i in "${!views[@]}"; do
  v="${views[$i]}"
  images=("$data/$v"/*.jpg)
  [ -f "${images[0]}" ] || { echo "error: no images in $data/$v" >&2; exit 1; }
  mkdir -p "$out/raw/cam$i"
  ln -s "${images[@]}" "$out/raw/cam$i/"
done
ln -s "$data/camera_parameters.json" "$out/calibration.json"
cp "$here/fixtures/panoptic-capture.toml" "$out/capture.toml"
echo "wrote $out: run \`pipeline run $out\`"
