#!/bin/sh
# Runs one headless-Chromium test of the dashboard (ctest calls it: tests/CMakeLists.txt).
#
#   tests/browser/run.sh BUILD_DIR TEST.mjs      (TEST.mjs: a path)
#
# playwright-core is installed from the committed lockfile into BUILD_DIR/browser-tests
# (npm ci, once; it downloads no browser) and drives Debian's /usr/bin/chromium. Without node,
# npm or chromium the test skips (exit 77) and says which is missing, unless
# PBGI_REQUIRE_BROWSER=1 (CI), where that is a failure.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
build=$(cd "$1" && pwd)
test=$2
missing=""
for tool in node npm; do command -v "$tool" >/dev/null 2>&1 || missing="$missing $tool"; done
[ -x "${PBGI_CHROMIUM:-/usr/bin/chromium}" ] || missing="$missing ${PBGI_CHROMIUM:-/usr/bin/chromium}"
if [ -n "$missing" ]; then
  echo "browser test $test: missing:$missing (deploy/setup-debian.sh installs them)"
  [ "${PBGI_REQUIRE_BROWSER:-0}" = 1 ] && exit 1
  exit 77
fi
modules="$build/browser-tests"
mkdir -p "$modules"
# npm ci again only when the lockfile changed.
if ! cmp -s "$here/package-lock.json" "$modules/package-lock.json" ||
   [ ! -d "$modules/node_modules/playwright-core" ]; then
  cp "$here/package.json" "$here/package-lock.json" "$modules/"
  (cd "$modules" && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund --loglevel=error)
fi
export PBGI_BROWSER_MODULES="$modules/node_modules"
export PBGI_BIN_DIR="$build/bin"
export PBGI_SOURCE_DIR="$(cd "$here/../.." && pwd)"
exec node "$test"
