#!/usr/bin/env bash
# nav2d on plain ROS 2: every node on its own timer at the spec's baseline rates
# (baseline.params.yaml), Linux's default scheduling, no catanc.
#
# Usage: bash plain.sh [CPUS]    CPUS: pin every process there (taskset -c), e.g. 0
# Ctrl-C (or SIGTERM) stops every process; plain.sh exits once they have.
set -euo pipefail
here=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
pin=()
[[ -z "${1-}" ]] || pin=(taskset -c "$1")
pids=()
stop() { kill -TERM "${pids[@]}" 2>/dev/null || true; }
trap stop INT TERM
for script in scan_shim nav_operator nav_mapper nav_navigator; do
  "${pin[@]}" python3 "$here/$script.py" --ros-args --params-file "$here/baseline.params.yaml" &
  pids+=("$!")
done
status=0
for pid in "${pids[@]}"; do
  while :; do
    code=0
    wait "$pid" || code=$?
    kill -0 "$pid" 2>/dev/null || break  # it ended (else a trapped signal cut the wait short)
  done
  (( code == 0 )) || status=$code
done
exit "$status"
