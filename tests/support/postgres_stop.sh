#!/bin/sh
# Stops the PostgreSQL cluster the services tests share (tests/support/postgres_cluster.h,
# PBGI_POSTGRES_SHARED_DIR) and removes its folder: ctest's cleanup fixture after the last
# test that needed it. Nothing to do when no test started one.
set -eu
dir=$1
[ -f "$dir/data/postmaster.pid" ] || { rm -rf "$dir"; exit 0; }
bin=${PBGI_POSTGRES_BIN:-$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1)}
if [ "$(id -u)" -eq 0 ]; then
  runuser -u postgres -- "$bin/pg_ctl" -D "$dir/data" -m immediate -w stop >/dev/null
else
  "$bin/pg_ctl" -D "$dir/data" -m immediate -w stop >/dev/null
fi
rm -rf "$dir"
