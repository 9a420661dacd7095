#!/usr/bin/env bash
# The GPU check: does the wgpu engine work on this machine's GPU, and how fast is it?
#
#   scripts/gpu-check.sh [--demo]      build (needs cargo) and run on this machine's GPU;
#                                      --demo also trains the demo on the GPU at `best` and
#                                      at `full` (needs the whole toolchain of
#                                      scripts/setup.sh, and minutes more)
#   scripts/gpu-check.sh --bundle DIR  build here and write what the check runs into DIR
#                                      (about 30 MB): stripped, xz-compressed test and
#                                      benchmark binaries that need only libc and a Vulkan
#                                      loader (no OpenCV, FFmpeg or COLMAP), the LPIPS
#                                      weights; copy DIR to a GPU machine that has no cargo
#   scripts/gpu-check.sh --from DIR    run a bundle (from the repository's root)
#
# What it runs, in this order, and prints as one table at the end:
#   1. the adapter and driver (nvidia-smi where there is one, and the adapter wgpu picks);
#   2. every GPU test of the engine on that adapter (`gpu_*`: parity with the CPU engine
#      and its f64 reference, gradients, loss, Adam, training, the decay, LPIPS), with
#      the ones too slow for lavapipe;
#   3. benchmarks at 1352×1014: forward of 1M Gaussians, forward + backward through the
#      host, one whole resident training iteration (render, loss, backward, Adam) at 100k
#      and 1M, Adam alone at 1M, the loss, and LPIPS on the GPU (one pair at 640×360 and
#      at 1352×1014, a batch of four);
#   4. where one training iteration's device time goes, kernel by kernel, at 100k and 1M
#      (timestamp queries; profile.md);
#   5. peak GPU memory while the benchmarks ran (nvidia-smi, sampled every 200 ms);
#   6. with --demo: `pipeline demo --backend gpu` at `best` and `full`, held-out PSNR /
#      SSIM / LPIPS and the train stage's wall time.
# It takes a few minutes on a data-centre GPU. Logs and the table go to $GPU_CHECK_OUT
# (default target/gpu-check/). SPLAT4D_GPU_SOFTWARE=1 runs it on a software adapter
# (lavapipe) at the small sizes only, to try the script without a GPU.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${GPU_CHECK_OUT:-$root/target/gpu-check}"

# The paths of the built test and benchmark executables, one per line: integration,
# render_gpu, lpips (cargo's progress and errors go to stderr).
build() {
  cd "$root"
  {
    cargo test -p splat4d --test integration --no-run --message-format=json
    cargo bench -p splat4d --bench render_gpu --bench lpips --no-run --message-format=json
  } | python3 -c '
import json, sys
found = {}
for line in sys.stdin:
    try:
        m = json.loads(line)
    except ValueError:
        continue
    if m.get("reason") == "compiler-artifact" and m.get("executable"):
        found[m["target"]["name"]] = m["executable"]
for name in ("integration", "render_gpu", "lpips"):
    if name not in found:
        sys.exit(f"gpu-check: cargo built no {name} executable")
    print(found[name])
'
}

# Stop unless the build gave all three executables.
built() {
  [ $# -eq 3 ] || { echo "gpu-check: the build failed (cargo's errors are above)" >&2; exit 1; }
}

bundle() {
  local dir="$1"
  mkdir -p "$dir/bin"
  mapfile -t exes < <(build)
  built "${exes[@]}"
  for exe in "${exes[@]}"; do
    local name
    name="$(basename "$exe" | sed 's/-[0-9a-f]*$//')"
    strip -o "$dir/bin/$name" "$exe"
    xz -9 -T0 -f "$dir/bin/$name"
  done
  if [ -f "$root/weights/lpips-alex-v0.1.safetensors" ]; then
    cp "$root/weights/lpips-alex-v0.1.safetensors" "$dir/"
  fi
  # The tests find their fixtures under the source tree they were built in.
  echo "$root" >"$dir/source-root"
  du -sh "$dir"
}

# Run the check with the executables in $bin; $1 is the source tree they were built in.
check() {
  local source_root="$1"
  mkdir -p "$out"
  : >"$out/table.md"
  row() { printf '| %s | %s |\n' "$1" "$2" >>"$out/table.md"; }
  echo "gpu-check: logs in $out"

  if command -v nvidia-smi >/dev/null; then
    row "GPU (nvidia-smi)" "$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | head -1)"
  fi
  if [ ! -d "$source_root" ] && [ "$source_root" != "$root" ]; then
    # A bundle built elsewhere: its tests look for fixtures under the tree it was built in.
    mkdir -p "$(dirname "$source_root")"
    ln -s "$root" "$source_root"
  fi
  export LPIPS_WEIGHTS="${LPIPS_WEIGHTS:-$weights}"

  echo "gpu-check: the engine's GPU tests"
  local tests_rc=0
  local software=0
  case "${SPLAT4D_GPU_SOFTWARE:-}" in 1 | true) software=1 ;; esac
  # On a real GPU also the tests too slow for lavapipe (a 300-iteration training against
  # the CPU's, the decay's device path against the host's, LPIPS timing).
  local ignored=(--include-ignored)
  [ "$software" = 1 ] && ignored=()
  (cd "$root" && "$bin/integration" gpu_ --test-threads 4 "${ignored[@]}") >"$out/tests.log" 2>&1 || tests_rc=$?
  row "GPU tests (\`gpu_*\`)" "$(grep -E '^test result' "$out/tests.log" | tail -1 | sed 's/^test result: //') (exit $tests_rc)"
  grep -E '^test .* FAILED$' "$out/tests.log" | sed 's/^/  /' || true

  local render_filter lpips_filter
  if [ "$software" = 1 ]; then
    render_filter='gpu_resident_step/128x96|gpu_loss/gpu/128x96'
    lpips_filter='' # a pair takes most of a minute on lavapipe
  else
    render_filter='gpu_render/forward_1352x1014|gpu_train_step/forward_backward_1352x1014|gpu_resident_step/1352x1014|gpu_adam/gpu_step/1000000|gpu_loss/gpu/1352x1014'
    lpips_filter='lpips_alex/gpu_'
  fi

  local sampler=""
  if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 200 >"$out/memory.log" &
    sampler=$!
  fi
  echo "gpu-check: benchmarks"
  local opts=(--warm-up-time 1 --measurement-time 2 --sample-size 10 --noplot --output-format bencher)
  # SPLAT4D_GPU_PROFILE=1: the benchmark first prints one training iteration's device
  # time kernel by kernel.
  (cd "$root" && SPLAT4D_GPU_PROFILE=1 "$bin/render_gpu" --bench "$render_filter" "${opts[@]}") >"$out/render_gpu.log" 2>&1 || true
  grep -E '^(profile:|\|)' "$out/render_gpu.log" >"$out/profile.md" || true
  : >"$out/lpips.log"
  if [ -n "$lpips_filter" ]; then
    (cd "$root" && "$bin/lpips" --bench "$lpips_filter" "${opts[@]}") >"$out/lpips.log" 2>&1 || true
  fi
  if [ -n "$sampler" ]; then
    kill "$sampler" 2>/dev/null || true
    local idle peak
    idle="$(head -1 "$out/memory.log")"
    peak="$(sort -n "$out/memory.log" | tail -1)"
    row "peak GPU memory in the benchmarks (largest: 1M Gaussians)" "$peak MiB ($((peak - idle)) MiB above idle)"
  fi
  local adapter
  adapter="$(grep -m1 '^adapter:' "$out/render_gpu.log" | sed 's/^adapter: //' || true)"
  row "adapter wgpu used" "${adapter:-none found (see render_gpu.log)}"
  # `test NAME ... bench: 12,345 ns/iter (+/- 678)` → milliseconds.
  grep -hE '^test .* bench:' "$out/render_gpu.log" "$out/lpips.log" | python3 -c '
import re, sys
for line in sys.stdin:
    m = re.match(r"test (\S+) \.\.\. bench:\s+([\d,]+) ns/iter \(\+/- ([\d,]+)\)", line)
    if m:
        ns, dev = (int(x.replace(",", "")) for x in m.group(2, 3))
        print(f"| {m.group(1)} | {ns / 1e6:.2f} ms (± {dev / 1e6:.2f}) |")
' >>"$out/table.md"

  if [ -n "${pipeline_bin:-}" ]; then
    for preset in best full; do
      echo "gpu-check: the demo at $preset"
      if "$pipeline_bin" --quiet demo "$out/demo" --backend gpu --preset "$preset" >"$out/demo-$preset.log" 2>&1; then
        row "demo at \`$preset\` (held-out PSNR / SSIM / LPIPS, train wall time)" "$(python3 - "$out/demo/work" <<'PY'
import json, sys
work = sys.argv[1]
m = json.load(open(f"{work}/eval/metrics.json"))["heldout"]["mean"]
s = json.load(open(f"{work}/train/stage.json"))["duration_s"]
lpips = m.get("lpips")
lpips = f"{lpips:.3f}" if isinstance(lpips, float) else "–"
print(f"{m['psnr']:.2f} dB / {m['ssim']:.3f} / {lpips}, {s:.0f} s")
PY
)"
      else
        row "demo at \`$preset\`" "failed (see demo-$preset.log)"
      fi
    done
  fi

  echo
  echo "| check | result |"
  echo "|---|---|"
  cat "$out/table.md"
  echo
  cat "$out/profile.md"
  return "$tests_rc"
}

case "${1:-}" in
--bundle)
  [ $# -eq 2 ] || { echo "usage: $0 --bundle DIR" >&2; exit 2; }
  bundle "$2"
  ;;
--from)
  [ $# -eq 2 ] || { echo "usage: $0 --from DIR" >&2; exit 2; }
  dir="$(cd "$2" && pwd)"
  bin="${TMPDIR:-/tmp}/gpu-check-bin"
  mkdir -p "$bin"
  for f in integration render_gpu lpips; do
    [ -f "$dir/bin/$f.xz" ] || { echo "gpu-check: $dir/bin/$f.xz is missing; make the bundle with --bundle" >&2; exit 2; }
    xz -dc "$dir/bin/$f.xz" >"$bin/$f"
    chmod +x "$bin/$f"
  done
  weights="$dir/lpips-alex-v0.1.safetensors"
  check "$(cat "$dir/source-root")"
  ;;
"" | --demo)
  if [ "${1:-}" = --demo ]; then
    (cd "$root" && cargo build --release -p pipeline)
    pipeline_bin="$root/target/release/pipeline"
  fi
  mapfile -t exes < <(build)
  built "${exes[@]}"
  bin="$out/bin"
  mkdir -p "$bin"
  for exe in "${exes[@]}"; do ln -sf "$exe" "$bin/$(basename "$exe" | sed 's/-[0-9a-f]*$//')"; done
  weights="$root/weights/lpips-alex-v0.1.safetensors"
  check "$root"
  ;;
*)
  sed -n '2,28p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
  ;;
esac
