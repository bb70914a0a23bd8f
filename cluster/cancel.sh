#!/usr/bin/env bash
# Cancel fake-cluster jobs (cluster/submit.sh) by id: kills the recorded wrapper PID and its children.
set -uo pipefail
dir="${SELFSENSE_FAKECLUSTER_DIR:-.fakecluster}"
for id in "$@"; do
    pid="$(cat "$dir/$id.pid" 2>/dev/null || true)"
    [ -n "$pid" ] || continue
    pkill -TERM -P "$pid" 2>/dev/null || true   # children of this one wrapper PID only
    kill -TERM "$pid" 2>/dev/null || true
    echo 143 > "$dir/$id.rc"
done
exit 0
