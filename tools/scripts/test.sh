#!/usr/bin/env bash
# Set-up as for the demo, then the whole test suite (unit, end-to-end, bad input under AddressSanitizer).
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
# The AddressSanitizer build of the command runs the bad-input tests; no peers needed there, nor MPI (the
# MPI tests run the optimized build under mpirun).
cmake -S "$root" -B "$build-asan" -G Ninja -DCMAKE_BUILD_TYPE=Debug -DSVO_SANITIZE=ON -DSVO_BENCH_PEERS=OFF \
  -DSVO_MPI=OFF -DBUILD_TESTING=OFF >/dev/null
cmake --build "$build-asan" --target svo -j "$jobs"
export SVO_ASAN_BINARY="$build-asan/tools/svo"
# The libFuzzer targets over the store reader, the PLY reader, the point-cloud readers, the server's request
# parsers and the view stream's messages (clang); the test suite runs them for a bounded number of inputs.
CC=clang CXX=clang++ cmake -S "$root" -B "$build-fuzz" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSVO_FUZZ=ON -DSVO_MPI=OFF \
  >/dev/null
cmake --build "$build-fuzz" -j "$jobs"
export SVO_FUZZ_STORE="$build-fuzz/tests/fuzz/svo_fuzz_store"
export SVO_FUZZ_PLY="$build-fuzz/tests/fuzz/svo_fuzz_ply"
export SVO_FUZZ_POINTS="$build-fuzz/tests/fuzz/svo_fuzz_points"
export SVO_FUZZ_REQUEST="$build-fuzz/tests/fuzz/svo_fuzz_request"
export SVO_FUZZ_VIEW="$build-fuzz/tests/fuzz/svo_fuzz_view"
cd "$build"
ctest --output-on-failure -j "$jobs"
