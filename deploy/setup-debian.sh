#!/bin/sh
# Installs every Debian 12 package pbgi needs to build, test and run; only what is missing.
# Idempotent: a second run installs nothing and takes about a second. postgresql-15 is the
# server the PostgreSQL job store's tests start a throwaway cluster of (initdb, pg_ctl);
# slurm-wlm and munge the one-node Slurm cluster the worker-array test starts (deploy/slurm);
# iproute2 the `ip netns` of the network-hosts test; chromium (and node, npm) the dashboard's
# headless browser test; systemd the `systemd-analyze verify` of deploy/systemd's units (a
# container need not run it).
set -eu

PACKAGES="
build-essential cmake ninja-build git ccache pkg-config clang libclang-rt-14-dev
libembree-dev libopenexr-dev libimath-dev libopenimageio-dev libopenvdb-dev
libboost-iostreams-dev libopencolorio-dev libtbb-dev
libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc libabsl-dev
libsqlite3-dev libpqxx-dev postgresql-15 libassimp-dev libtomlplusplus-dev libcli11-dev
libspdlog-dev libfmt-dev libzstd-dev libgtest-dev libgmock-dev libbenchmark-dev
libcpp-httplib-dev libxxhash-dev nlohmann-json3-dev slurm-wlm munge iproute2 chromium systemd
"
# The dashboard's browser test drives chromium with playwright-core, which npm installs from
# tests/browser/package-lock.json. Debian's node and npm, unless a Node.js is already there (a
# nodesource package, which brings its own npm and conflicts with Debian's).
command -v node >/dev/null 2>&1 || PACKAGES="$PACKAGES nodejs"
command -v npm >/dev/null 2>&1 || PACKAGES="$PACKAGES npm"

missing=""
for p in $PACKAGES; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing="$missing $p"
  fi
done

if [ -z "$missing" ]; then
  exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
  echo "setup-debian.sh: these packages are missing and installing them needs root:$missing" >&2
  exit 1
fi

echo "setup-debian.sh: installing:$missing"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q
# shellcheck disable=SC2086
apt-get install -y -q --no-install-recommends $missing
