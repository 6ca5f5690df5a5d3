#!/bin/sh
# Builds pbgi's libFuzzer targets with clang++ (libFuzzer, AddressSanitizer, UBSan) and runs each
# for a number of seconds over its seed corpus:
#   page_file    the .pbgi container                   tests/data/pbgi/fuzz_corpus
#   tree_page    tree page payloads                    tests/data/pbgi_tree/fuzz_corpus
#   shot         shot files (TOML text)                tests/data/shots/fuzz_corpus
#   surfel_vdb   surfel point clouds (OpenVDB files)   tests/data/vdb/fuzz_corpus
#   coordinator  sequences of farm RPCs, in-process    tests/data/coordinator/fuzz_corpus
#
#   tests/fuzz/run_fuzz.sh [seconds] [libFuzzer flags...]      (default: 60 seconds)
#
# Builds the targets through CMake in build-fuzz/ ($PBGI_FUZZ_BUILD_DIR), configured with
# PBGI_FUZZ=ON and $PBGI_FUZZ_CXX (default clang++), which instruments every library (ccache
# keeps rebuilds short). $PBGI_FUZZ_TARGETS picks targets (default: all five, in that order);
# with $PBGI_FUZZ_BIN_DIR set it skips the build and runs pbgi_<target>_fuzz from that folder.
# Inputs the fuzzer finds interesting go to build-fuzz/new_corpus_<target>, never into the
# committed corpus; a crash leaves its input in the repository root as crash-<sha1>, which is
# what to add to tests/data/ with a test once fixed. LeakSanitizer leaves out the leaks that
# tests/fuzz/lsan_suppressions.txt explains (OpenVDB's). surfel_vdb stops at the file's content
# hash unless PBGI_VDB_FUZZ_REHASH=1 (tests/fuzz/surfel_vdb_fuzz_input.h says why).
# Needs clang with libFuzzer's runtime (Debian 12: clang-14, which pulls in libclang-rt-14-dev).
set -eu
cd "$(dirname "$0")/../.."
seconds=${1:-60}
[ $# -gt 0 ] && shift
out=${PBGI_FUZZ_BUILD_DIR:-build-fuzz}
targets=${PBGI_FUZZ_TARGETS:-page_file tree_page shot surfel_vdb coordinator}
bin=${PBGI_FUZZ_BIN_DIR:-}

corpus_of() {
  case $1 in
    page_file) echo tests/data/pbgi/fuzz_corpus ;;
    tree_page) echo tests/data/pbgi_tree/fuzz_corpus ;;
    shot) echo tests/data/shots/fuzz_corpus ;;
    surfel_vdb) echo tests/data/vdb/fuzz_corpus ;;
    coordinator) echo tests/data/coordinator/fuzz_corpus ;;
    *) echo "run_fuzz.sh: unknown target '$1'" >&2; exit 2 ;;
  esac
}

if [ -z "$bin" ]; then
  # -O1 and line tables: readable stack traces at near full speed. No NDEBUG: asserts stay on.
  cmake -S . -B "$out" -G Ninja -DPBGI_FUZZ=ON -DPBGI_BUILD_TESTS=OFF -DPBGI_BUILD_BENCH=OFF \
    -DCMAKE_CXX_COMPILER="${PBGI_FUZZ_CXX:-clang++}" -DCMAKE_BUILD_TYPE= \
    -DCMAKE_CXX_FLAGS="-O1 -gline-tables-only" >/dev/null
  names=""
  for t in $targets; do names="$names pbgi_${t}_fuzz"; done
  # shellcheck disable=SC2086  # one argument per target
  cmake --build "$out" --target $names
  bin="$out/bin"
fi

# Leaks that are not pbgi's (each explained in the file).
LSAN_OPTIONS="suppressions=$(pwd)/tests/fuzz/lsan_suppressions.txt:print_suppressions=0${LSAN_OPTIONS:+:$LSAN_OPTIONS}"
export LSAN_OPTIONS
for t in $targets; do
  corpus=$(corpus_of "$t")
  mkdir -p "$out/new_corpus_$t"
  # -rss_limit_mb: a hostile size that slipped past the checks shows up as an allocation.
  "$bin/pbgi_${t}_fuzz" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=1024 \
    -malloc_limit_mb=64 -print_final_stats=1 "$@" "$out/new_corpus_$t" "$corpus"
done
