#!/bin/sh
# Builds the .pbgi fuzz target with clang++ (libFuzzer, AddressSanitizer, UBSan) and runs it
# for a number of seconds over the seed corpus in tests/data/pbgi/fuzz_corpus.
#
#   tests/fuzz/run_fuzz.sh [seconds] [libFuzzer flags...]      (default: 60 seconds)
#
# Builds into build-fuzz/ ($PBGI_FUZZ_BUILD_DIR) with $PBGI_FUZZ_CXX (default clang++), or
# skips the build and runs $PBGI_FUZZ_BINARY when that is set. Inputs the fuzzer finds
# interesting go to build-fuzz/new_corpus, never into the committed corpus; a crash leaves its
# input in the current folder as crash-<sha1>, which is what to add to the corpus once fixed.
# Needs clang with libFuzzer's runtime (Debian 12: clang-14, which pulls in libclang-rt-14-dev).
set -eu
cd "$(dirname "$0")/../.."
seconds=${1:-60}
[ $# -gt 0 ] && shift
out=${PBGI_FUZZ_BUILD_DIR:-build-fuzz}
mkdir -p "$out/new_corpus"

binary=${PBGI_FUZZ_BINARY:-}
if [ -z "$binary" ]; then
  binary="$out/pbgi_page_file_fuzz"
  packages="absl_status absl_statusor absl_strings fmt Imath libzstd libxxhash"
  # shellcheck disable=SC2046  # pkg-config's flags are meant to split
  ${PBGI_FUZZ_CXX:-clang++} -std=c++20 -O1 -g -fno-omit-frame-pointer \
    -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
    -I. $(pkg-config --cflags $packages) \
    tests/fuzz/page_file_fuzz.cpp formats/pbgi/page_file_decode.cpp \
    -o "$binary" $(pkg-config --libs $packages)
fi

# -rss_limit_mb: a hostile size that slipped past the checks shows up as an allocation.
exec "$binary" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=1024 \
  -malloc_limit_mb=64 -print_final_stats=1 "$@" \
  "$out/new_corpus" tests/data/pbgi/fuzz_corpus
