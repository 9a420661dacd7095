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
  # camera models / undistortion, pose solving
  libopencv-dev colmap
  # wgpu on machines without a GPU (lavapipe)
  mesa-vulkan-drivers libvulkan1
  # browser viewer test (tests/viewer_browser.rs): headless Chromium, WebGL on SwiftShader
  chromium
  # text of the plots `pipeline bench tradeoff` draws
  fonts-dejavu-core
)
# The viewer's web project (viewer/) needs Node.js and npm; use any already on PATH.
if ! command -v npm >/dev/null; then
  PACKAGES+=(nodejs npm)
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
     [ -n "$(find "$viewer/src" "$viewer/index.html" "$viewer/build.mjs" "$viewer/package-lock.json" -newer "$viewer/dist/index.html" 2>/dev/null)" ]; then
    echo "setup: building the viewer bundle (viewer/dist)"
    npm run --prefix "$viewer" --silent build >/dev/null
  fi
}

if [ ${#missing[@]} -eq 0 ]; then
  build_viewer
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
echo "setup: done"
