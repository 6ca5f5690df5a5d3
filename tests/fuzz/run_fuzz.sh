#!/bin/sh
# Builds the .pbgi fuzz targets with clang++ (libFuzzer, AddressSanitizer, UBSan) and runs each
# for a number of seconds over its seed corpus: the container (tests/data/pbgi/fuzz_corpus)
# and tree page payloads (tests/data/pbgi_tree/fuzz_corpus).
#
#   tests/fuzz/run_fuzz.sh [seconds] [libFuzzer flags...]      (default: 60 seconds)
#
# Builds into build-fuzz/ ($PBGI_FUZZ_BUILD_DIR) with $PBGI_FUZZ_CXX (default clang++), or
# skips the builds and runs $PBGI_FUZZ_BINARY and $PBGI_TREE_FUZZ_BINARY when they are set. Inputs the fuzzer finds
# interesting go to build-fuzz/new_corpus_<target>, never into the committed corpus; a crash leaves its
# input in the current folder as crash-<sha1>, which is what to add to the corpus once fixed.
# Needs clang with libFuzzer's runtime (Debian 12: clang-14, which pulls in libclang-rt-14-dev).
set -eu
cd "$(dirname "$0")/../.."
seconds=${1:-60}
[ $# -gt 0 ] && shift
out=${PBGI_FUZZ_BUILD_DIR:-build-fuzz}

# Each target: name, sources, seed corpus.
run_target() {
  name=$1 sources=$2 corpus=$3 binary=$4
  mkdir -p "$out/new_corpus_$name"
  if [ -z "$binary" ]; then
    binary="$out/pbgi_${name}_fuzz"
    packages="absl_status absl_statusor absl_strings fmt Imath libzstd libxxhash"
    # shellcheck disable=SC2046,SC2086  # pkg-config's flags and the source list are meant to split
    ${PBGI_FUZZ_CXX:-clang++} -std=c++20 -O1 -g -fno-omit-frame-pointer \
      -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
      -I. $(pkg-config --cflags $packages) $sources \
      -o "$binary" $(pkg-config --libs $packages)
  fi
  # -rss_limit_mb: a hostile size that slipped past the checks shows up as an allocation.
  "$binary" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=1024 \
    -malloc_limit_mb=64 -print_final_stats=1 $extra \
    "$out/new_corpus_$name" "$corpus"
}

extra="$*"
run_target page_file "tests/fuzz/page_file_fuzz.cpp formats/pbgi/page_file_decode.cpp" \
  tests/data/pbgi/fuzz_corpus "${PBGI_FUZZ_BINARY:-}"
run_target tree_page "tests/fuzz/tree_page_fuzz.cpp core/pbgi/tree_page.cpp core/pbgi/tree.cpp core/pbgi/sh.cpp core/pbgi/wavelet.cpp core/pbgi/microbuffer.cpp" \
  tests/data/pbgi_tree/fuzz_corpus "${PBGI_TREE_FUZZ_BINARY:-}"
