#!/usr/bin/env bash
# The main job on the embedded default scene: build an octree from the Stanford bunny and render it.
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
out="$root/out"
mkdir -p "$out"
"$build/tools/svo" build "$SVO_BUNNY" -o "$out/bunny.svo" --levels 10
"$build/tools/svo" render "$out/bunny.svo" -o "$out/bunny.png"
echo "image: $out/bunny.png"
