#!/usr/bin/env bash
# Stop the single-node SLURM cluster started by cluster/start_local_slurm.sh: cancels its jobs, then stops
# slurmd, slurmctld and munged by the PIDs recorded in $SELFSENSE_SLURM_STATE (default /tmp/selfsense-slurm).
# Never kills by process name. Safe to call when nothing is running.
set -uo pipefail
STATE="${SELFSENSE_SLURM_STATE:-/tmp/selfsense-slurm}"
log() { echo "[stop_local_slurm] $*" >&2; }

if [ -s "$STATE/slurmctld.pid" ] && kill -0 "$(cat "$STATE/slurmctld.pid")" 2>/dev/null; then
    ids="$(squeue -h -o '%i' 2>/dev/null | tr '\n' ' ')"
    if [ -n "${ids// /}" ]; then log "cancelling jobs $ids"; scancel $ids 2>/dev/null || true; sleep 1; fi
fi

stop_pid() {  # name pidfile
    local name="$1" f="$2" pid
    [ -s "$f" ] || { log "$name: no PID file"; return 0; }
    pid="$(cat "$f")"
    if ! kill -0 "$pid" 2>/dev/null; then log "$name: pid $pid not running"; rm -f "$f"; return 0; fi
    kill -TERM "$pid" 2>/dev/null
    for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    if kill -0 "$pid" 2>/dev/null; then log "$name: pid $pid ignored SIGTERM, sending SIGKILL"; kill -KILL "$pid" 2>/dev/null; fi
    rm -f "$f"
    log "$name: stopped pid $pid"
}
stop_pid slurmd "$STATE/slurmd.pid"
stop_pid slurmctld "$STATE/slurmctld.pid"
stop_pid munged "$STATE/munged.pid"
exit 0
