#!/bin/sh
# The layout's include rules, checked over every #include line under ROOT (the repository, or
# a crafted tree in tests/data/include_rules that breaks each rule once). Prints every include
# that crosses a rule as FILE:LINE and exits 1; exits 0 when there is none. With EXPECTED (the
# crafted tree's test), exits 0 only when exactly that many includes cross a rule.
#
#   tests/services/include_rules.sh ROOT [EXPECTED]
#
# Includes only point down:
#   core/                 nothing of formats/, services/ or config/
#   formats/              nothing of services/ or config/
#   services/bake/, render/, util/, api/
#                         none of the farm's rooms
#   services/farm/        the farm's model, client, wire mapping, TLS and file transfer: none
#                         of the job store, coordinator, worker, command line or local farm
#   services/job_store/   of the farm's rooms, only farm/
#   services/coordinator/ (dashboard/ included) not the worker, the command line or the local
#                         farm
#   services/worker/, services/cli/
#                         not the coordinator or the job store (they speak to it through farm/)
#   services/local_farm/  not the command line or the worker (it starts workers as processes)
set -eu
root=$1
expected=${2:-}
status=0
crossings=0
# check DIR PATTERN WHY: no #include "PATTERN..." in the sources under ROOT/DIR.
check() {
  [ -d "$root/$1" ] || return 0
  found=$(grep -rnE --include='*.h' --include='*.cpp' "^[[:space:]]*#[[:space:]]*include[[:space:]]+\"($2)" \
          "$root/$1" || true)
  if [ -n "$found" ]; then
    echo "$found" | sed "s#^$root/##; s#\$#   <- $1 $3#"
    crossings=$((crossings + $(echo "$found" | wc -l)))
    status=1
  fi
}
farm_rooms='services/(farm|job_store|coordinator|worker|cli|local_farm)/'
check core 'formats/|services/|config/' 'must not include formats/, services/ or config/'
check formats 'services/|config/' 'must not include services/ or config/'
for dir in services/bake services/render services/util services/api; do
  check "$dir" "$farm_rooms" "must not include the farm's rooms"
done
check services/farm 'services/(job_store|coordinator|worker|cli|local_farm)/' \
  'includes only the farm model and what lies below it'
check services/job_store 'services/(coordinator|worker|cli|local_farm)/' \
  'includes only services/farm/ of the farm'
check services/coordinator 'services/(worker|cli|local_farm)/' \
  'must not include the worker, the command line or the local farm'
check services/worker 'services/(coordinator|job_store|cli|local_farm)/' \
  'speaks to the coordinator through services/farm/ only'
check services/cli 'services/(coordinator|job_store|worker)/' \
  'speaks to the coordinator through services/farm/ (or services/local_farm/) only'
check services/local_farm 'services/(cli|worker)/' 'must not include the command line or the worker'
if [ -n "$expected" ]; then
  echo "$crossings include(s) cross a rule under $root; expected $expected"
  [ "$crossings" = "$expected" ]
  exit
fi
[ "$status" = 0 ] && echo "include rules hold under $root"
exit "$status"
