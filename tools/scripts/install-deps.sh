#!/usr/bin/env bash
# Installs every Debian 12 package svostream needs; safe to run again (apt skips what is present).
set -euo pipefail
packages=(
  build-essential cmake ninja-build pkg-config git
  libopenvdb-dev libopenvdb-tools libnanovdb-dev libboost-iostreams-dev libtbb-dev
  libdraco-dev libassimp-dev assimp-testmodels
  libopenimageio-dev openimageio-tools libglm-dev libzstd-dev libxxhash-dev
  libgtest-dev libgmock-dev libbenchmark-dev libcli11-dev nlohmann-json3-dev libspdlog-dev libfmt-dev
  libembree-dev libnanoflann-dev libeigen3-dev
  libcurl4-openssl-dev prometheus-cpp-dev nginx-light wrk nghttp2-client openssl
  gnuplot-nox
  libglfw3-dev libimgui-dev libgl1-mesa-dri xvfb imagemagick
  libegl-dev libopengl-dev libegl-mesa0
  clang libclang-rt-14-dev
  libopenmpi-dev openmpi-bin
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# node and npm may come from outside Debian (npm 11 here); only install them when absent.
command -v npm >/dev/null || missing+=(nodejs npm)
if ((${#missing[@]})); then
  echo "installing: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
