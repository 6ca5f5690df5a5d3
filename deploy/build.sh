#!/bin/sh
# Installs what is missing (deploy/setup-debian.sh), then configures and builds the release
# preset into build/. Safe to run again: nothing is reinstalled, the build is incremental.
set -eu
cd "$(dirname "$0")/.."
sh deploy/setup-debian.sh
cmake --preset release >/dev/null
cmake --build --preset release
