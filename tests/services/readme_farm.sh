#!/bin/sh
# Runs the README's farm walkthrough (the sh block after "<!-- farm walkthrough -->") as it
# stands, from the repository root, and checks that the frame was written.
#
#   tests/services/readme_farm.sh SOURCE_DIR BUILD_DIR
set -eu
source_dir=$1
build_dir=$2
block=$(mktemp)
log=$(mktemp)
trap 'rm -f "$block" "$log"' EXIT
awk '/<!-- farm walkthrough -->/ { found = 1; next }
     found && /^```sh/ { inside = 1; next }
     inside && /^```/ { exit }
     inside { print }' "$source_dir/README.md" > "$block"
if [ ! -s "$block" ]; then
  echo "README.md has no farm walkthrough block" >&2
  exit 1
fi
# The README runs from the repository root with the build in build/.
if [ "$(cd "$build_dir" && pwd)" != "$(cd "$source_dir/build" 2>/dev/null && pwd)" ]; then
  echo "the walkthrough runs build/bin from the repository root; this build is $build_dir" >&2
  exit 77
fi
cd "$source_dir"
status=0
timeout 300 sh -eu "$block" > "$log" 2>&1 || status=$?
cat "$log"
if [ "$status" -ne 0 ]; then
  echo "FAIL: the README's farm walkthrough exited $status" >&2
  # What the block started and did not stop.
  pkill -f "pbgi-worker --coordinator 127.0.0.1:7411 --token-file" 2>/dev/null || true
  pkill -f "pbgi-coordinator --state /tmp/tmp" 2>/dev/null || true
  exit 1
fi
grep -q "job 1 done" "$log" || { echo "FAIL: logs --follow did not end with the job done" >&2; exit 1; }
grep -q "cornell.0001.exr" "$log" || { echo "FAIL: the frame is not in the output folder" >&2; exit 1; }
echo "PASS: the README's farm walkthrough"
