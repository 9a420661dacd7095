#!/usr/bin/env bash
# The GPU check: does the wgpu engine work on this machine's GPU, and how fast is it?
#
#   scripts/gpu-check.sh [--demo]           build (needs cargo) and run on this machine's GPU;
#                                           --demo also trains the demo on the GPU at `best`
#                                           and at `full` (needs the whole toolchain of
#                                           scripts/setup.sh, and minutes more)
#   scripts/gpu-check.sh --bundle DIR       build here and write what the check runs into DIR
#                                           (about 30 MB): stripped, xz-compressed test and
#                                           benchmark binaries that need only libc and a
#                                           Vulkan loader (no OpenCV, FFmpeg or COLMAP), the
#                                           LPIPS weights; copy DIR to a GPU machine that has
#                                           no cargo
#   scripts/gpu-check.sh --bundle-demo DIR  build here and write the demo's part into DIR
#                                           (about 50 MB): the engine-only `pipeline` and the
#                                           demo capture prepared up to `init`
#   scripts/gpu-check.sh --from DIR         run a bundle (from the repository's root): the
#                                           tests and benchmarks of --bundle, the demo of
#                                           --bundle-demo, or both where DIR holds both
#
# What it runs, in this order, and prints as one table at the end:
#   1. the adapter and driver (nvidia-smi where there is one, and the adapter wgpu picks);
#   2. every GPU test of the engine on that adapter (`gpu_*`: parity with the CPU engine
#      and its f64 reference, gradients, loss, Adam, training, the decay, LPIPS), with
#      the ones too slow for lavapipe;
#   3. benchmarks at 1352×1014: forward of 1M Gaussians, forward + backward through the
#      host, one whole resident training iteration (render, loss, backward, Adam) at 100k
#      and 1M, alone and with a pseudo view (`…_pseudo_view`), Adam alone at 1M, the loss, and LPIPS on the GPU (one pair at 640×360 and
#      at 1352×1014, a batch of four);
#   4. where one training iteration's device time goes, kernel by kernel, at 100k and 1M
#      (timestamp queries; profile.md);
#   5. peak GPU memory while the benchmarks ran (nvidia-smi, sampled every 200 ms);
#   6. the demo (--demo, or a bundle from --bundle-demo): the demo capture prepared up to
#      `init` trained with `--backend gpu` at `best` and at `full`, held-out PSNR / SSIM /
#      LPIPS and the train stage's wall time, and peak GPU memory while it trained;
#   7. only when asked (GPU_CHECK_PARTS=scale): a long, large capture's training time, the
#      demo's training views stretched to 4 × 300 frames at 1352×1014 (`pipeline bench
#      tradeoff --stretch 300:1352x1014`) trained with `full`'s budget for
#      GPU_CHECK_SCALE_STEPS steps (default 30 000, the paper's schedule; fewer give a
#      projection).
# Steps 1–6 take a few minutes on a data-centre GPU, step 7 about as long again: to fit a
# short slot run them as two commands, GPU_CHECK_PARTS="engine demo" (the default) and then
# GPU_CHECK_PARTS=scale. Logs and the table go to $GPU_CHECK_OUT (default
# target/gpu-check/). SPLAT4D_GPU_SOFTWARE=1 runs it on a software adapter (lavapipe) at
# the small sizes only, to try the script without a GPU (the demo then trains on the CPU
# at `preview`, the scale part on the CPU for 20 steps at 8 frames of 160×120).
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

# Sample the GPU's used memory (MiB) into $1 every 200 ms in the background; `sampler`
# is its process id (empty without nvidia-smi).
sample_memory() {
  sampler=""
  if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 200 >"$1" &
    sampler=$!
  fi
}

# The engine's GPU tests and benchmarks with the executables in $bin; $1 is 1 on a
# software adapter. Returns the tests' exit status.
engine() {
  local software="$1" tests_rc=0
  echo "gpu-check: the engine's GPU tests"
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

  local sampler
  sample_memory "$out/memory.log"
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
  return "$tests_rc"
}

# The training time of a long, large capture: the demo capture's training views stretched
# to 4 × 300 frames at 1352×1014, trained on the GPU with `full`'s budget for
# $GPU_CHECK_SCALE_STEPS steps (its schedule scaled to them); $1 is 1 on a software adapter,
# where 20 steps of 8 frames at 160×120 train on the CPU instead (to try the script).
scale() {
  local software="$1" backend=gpu steps="${GPU_CHECK_SCALE_STEPS:-30000}" stretch=300:1352x1014
  if [ "$software" = 1 ]; then
    backend=cpu
    steps=20
    stretch=8:160x120
  fi
  local sampler
  sample_memory "$out/scale-memory.log"
  echo "gpu-check: the demo stretched to $stretch, $steps steps"
  local folder="tradeoff-${stretch/:/x}"
  rm -rf "$demo_capture/work/bench/$folder"
  # --as-prepared: the bundle's capture lacks the COLMAP workspace and the point maps that
  # poses and init read, and this build could not rerun them.
  if "$pipeline_bin" bench tradeoff "$demo_capture" --as-prepared --iterations "$steps" \
    --resolution 1 --max-gaussians 200000 --backend "$backend" --stretch "$stretch" \
    >"$out/scale.log" 2>&1; then
    row "the demo's cameras × ${stretch%%:*} frames at ${stretch#*:} on $backend, $steps steps, \`full\`'s budget (train wall time, Gaussians, held-out PSNR)" "$(python3 - "$demo_capture/work/bench/$folder/tradeoff.csv" "$steps" <<'PY'
import csv, sys
row = list(csv.DictReader(open(sys.argv[1])))[-1]
steps, seconds = int(sys.argv[2]), float(row["seconds"])
text = f"{seconds:.0f} s ({steps / seconds:.1f} steps/s), {row['gaussians']} Gaussians, {float(row['psnr']):.2f} dB"
if steps != 30000:
    text += f"; 30 000 steps ≈ {seconds * 30000 / steps / 60:.1f} min"
print(text)
PY
)"
  else
    row "the demo's cameras × ${stretch%%:*} frames at ${stretch#*:} on $backend" "failed (see scale.log)"
  fi
  if [ -n "$sampler" ]; then
    kill "$sampler" 2>/dev/null || true
    row "peak GPU memory while the stretched demo trained" "$(sort -n "$out/scale-memory.log" | tail -1) MiB"
  fi
}

# Train the demo capture $demo_capture (prepared up to `init`) with $pipeline_bin at
# `best` and at `full` on the GPU; $1 is 1 on a software adapter, where it trains on the
# CPU at `preview` instead (to try the script).
demo() {
  local software="$1" backend=gpu presets=(best full)
  if [ "$software" = 1 ]; then
    backend=cpu
    presets=(preview)
  fi
  local sampler
  sample_memory "$out/demo-memory.log"
  local preset
  for preset in "${presets[@]}"; do
    echo "gpu-check: the demo at $preset"
    local log="$out/demo-$preset.log"
    : >"$log"
    local stage
    for stage in train eval; do
      "$pipeline_bin" run "$demo_capture" --only "$stage" --backend "$backend" --preset "$preset" >>"$log" 2>&1 || break
    done
    local trained_on
    trained_on="$(grep -m1 -o 'training backend: .*' "$log" | sed 's/^training backend: //' || true)"
    if grep -q '✓ eval: done' "$log"; then
      row "demo at \`$preset\` on ${trained_on:-$backend} (held-out PSNR / SSIM / LPIPS, moving region, train wall time)" "$(python3 - "$demo_capture/work" <<'PY'
import json, sys
work = sys.argv[1]
held = json.load(open(f"{work}/eval/metrics.json"))["heldout"]
m = held["mean"]
seconds = json.load(open(f"{work}/train/stage.json"))["duration_s"]
lpips = m.get("lpips")
lpips = f"{lpips:.3f}" if isinstance(lpips, float) else "–"
moving = held.get("moving", {}).get("mean", {}).get("psnr")
moving = f"{moving:.2f} dB" if isinstance(moving, float) else "–"
print(f"{m['psnr']:.2f} dB / {m['ssim']:.3f} / {lpips}, moving {moving}, {seconds:.0f} s")
PY
)"
    else
      row "demo at \`$preset\` on $backend" "failed (see demo-$preset.log)"
    fi
  done
  if [ -n "$sampler" ]; then
    kill "$sampler" 2>/dev/null || true
    row "peak GPU memory while the demo trained" "$(sort -n "$out/demo-memory.log" | tail -1) MiB"
  fi
}

# The demo's part of a bundle in $1: the engine-only `pipeline` (no FFmpeg, OpenCV or
# COLMAP: what a GPU node runs, docs/cluster.md) and the demo capture prepared up to
# `init` by the whole build, with what training and eval read. Leaves the engine-only
# build in target/release (the next `cargo build --release -p pipeline` rebuilds it).
bundle_demo() {
  local dir="$1" target="${CARGO_TARGET_DIR:-$root/target}"
  mkdir -p "$dir"
  local prep="$target/gpu-check-demo"
  (cd "$root" && cargo build --release -p pipeline)
  rm -rf "$prep"
  "$target/release/pipeline" --quiet demo "$prep/demo" --to init
  (cd "$root" && cargo build --release -p pipeline --no-default-features --features bundled-sqlite)
  strip -o "$dir/pipeline" "$target/release/pipeline"
  xz -9 -T0 -f "$dir/pipeline"
  # Not the COLMAP workspace and the point maps (read by poses and init, which have run)
  # nor the simulator's depth and clean held-out renders (eval scores the filmed ones).
  tar -C "$prep" -cf - --exclude demo/work/poses/colmap --exclude demo/pointmaps \
    --exclude demo/groundtruth/depth --exclude demo/groundtruth/heldout demo |
    xz -9 -T0 >"$dir/demo.tar.xz"
  if [ -f "$root/weights/lpips-alex-v0.1.safetensors" ]; then
    cp "$root/weights/lpips-alex-v0.1.safetensors" "$dir/"
  fi
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

  local tests_rc=0
  local software=0
  case "${SPLAT4D_GPU_SOFTWARE:-}" in 1 | true) software=1 ;; esac
  local parts=" ${GPU_CHECK_PARTS:-engine demo} "
  if [ -x "$bin/integration" ] && [[ "$parts" == *" engine "* ]]; then
    engine "$software" || tests_rc=$?
  fi
  if [ -n "${pipeline_bin:-}" ] && [[ "$parts" == *" demo "* ]]; then
    demo "$software"
  fi
  if [ -n "${pipeline_bin:-}" ] && [[ "$parts" == *" scale "* ]]; then
    scale "$software"
  fi

  echo
  echo "| check | result |"
  echo "|---|---|"
  cat "$out/table.md"
  if [ -f "$out/profile.md" ]; then
    echo
    cat "$out/profile.md"
  fi
  return "$tests_rc"
}

case "${1:-}" in
--bundle)
  [ $# -eq 2 ] || { echo "usage: $0 --bundle DIR" >&2; exit 2; }
  bundle "$2"
  ;;
--bundle-demo)
  [ $# -eq 2 ] || { echo "usage: $0 --bundle-demo DIR" >&2; exit 2; }
  bundle_demo "$2"
  ;;
--from)
  [ $# -eq 2 ] || { echo "usage: $0 --from DIR" >&2; exit 2; }
  dir="$(cd "$2" && pwd)"
  bin="${TMPDIR:-/tmp}/gpu-check-bin"
  mkdir -p "$bin" "$out"
  if [ ! -f "$dir/bin/integration.xz" ] && [ ! -f "$dir/pipeline.xz" ]; then
    echo "gpu-check: $dir holds no bundle; make one with --bundle and/or --bundle-demo" >&2
    exit 2
  fi
  if [ -f "$dir/bin/integration.xz" ]; then
    for f in integration render_gpu lpips; do
      [ -f "$dir/bin/$f.xz" ] || { echo "gpu-check: $dir/bin/$f.xz is missing; make the bundle again with --bundle" >&2; exit 2; }
      xz -dc "$dir/bin/$f.xz" >"$bin/$f"
      chmod +x "$bin/$f"
    done
  fi
  if [ -f "$dir/pipeline.xz" ]; then
    [ -f "$dir/demo.tar.xz" ] || { echo "gpu-check: $dir/demo.tar.xz is missing; make the bundle again with --bundle-demo" >&2; exit 2; }
    pipeline_bin="$bin/pipeline"
    xz -dc "$dir/pipeline.xz" >"$pipeline_bin"
    chmod +x "$pipeline_bin"
    rm -rf "$out/demo"
    xz -dc "$dir/demo.tar.xz" | tar -C "$out" -xf -
    demo_capture="$out/demo"
  fi
  weights="$dir/lpips-alex-v0.1.safetensors"
  source_root="$root"
  [ -f "$dir/source-root" ] && source_root="$(cat "$dir/source-root")"
  check "$source_root"
  ;;
"" | --demo)
  if [ "${1:-}" = --demo ]; then
    (cd "$root" && cargo build --release -p pipeline)
    pipeline_bin="${CARGO_TARGET_DIR:-$root/target}/release/pipeline"
    demo_capture="$out/demo"
    rm -rf "$demo_capture"
    "$pipeline_bin" --quiet demo "$demo_capture" --to init
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
  sed -n '2,46p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
  ;;
esac
