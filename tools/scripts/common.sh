# Shared set-up for the demo and test commands: install packages, configure, build, fetch data.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
build="${SVO_BUILD_DIR:-$root/build}"
jobs="${SVO_JOBS:-$(nproc)}"

bash "$root/tools/scripts/install-deps.sh"
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build "$build" -j "$jobs"
bash "$root/tools/scripts/fetch-data.sh" "$build/data" >/dev/null
export SVO_BUNNY="$build/data/bunny.ply"
