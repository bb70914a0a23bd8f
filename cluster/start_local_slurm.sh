#!/usr/bin/env bash
# Start a single-node SLURM cluster (slurmctld + slurmd + munge) on this machine, from Debian packages.
# Idempotent: a second call with the daemons already up only re-checks that the node is idle.
#
#   sudo cluster/start_local_slurm.sh          # needs root (apt-get, /etc/slurm, munged)
#   cluster/stop_local_slurm.sh                # stops exactly the daemons this script started (by PID)
#
# State (PID files, logs, spool) lives in $SELFSENSE_SLURM_STATE (default /tmp/selfsense-slurm).
# The partition is called "debug" (default), so workflow/profiles/slurm-local works unchanged.
# Exit codes: 0 node idle; 2 not root; 3 packages unavailable; 4 daemons did not come up.
set -uo pipefail

STATE="${SELFSENSE_SLURM_STATE:-/tmp/selfsense-slurm}"
CONF=/etc/slurm/slurm.conf
MARK="# written by selfsense cluster/start_local_slurm.sh"
WAIT_S="${SELFSENSE_SLURM_WAIT:-60}"

log() { echo "[start_local_slurm] $*" >&2; }

if [ "$(id -u)" -ne 0 ]; then
    log "must run as root (installs packages, writes $CONF, starts munged/slurmctld/slurmd)"; exit 2
fi

alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

node_state() { sinfo -h -N -o '%T' 2>/dev/null | head -n1; }

# 0. Already running (started by us)? Then only make sure the node is idle.
if alive "$STATE/slurmctld.pid" && alive "$STATE/slurmd.pid" && [ "$(node_state)" = "idle" ]; then
    log "already running (slurmctld $(cat "$STATE/slurmctld.pid"), slurmd $(cat "$STATE/slurmd.pid")), node idle"
    exit 0
fi

# 1. Packages.
need=()
for b in slurmctld slurmd sinfo munged; do command -v "$b" >/dev/null 2>&1 || need+=("$b"); done
if [ "${#need[@]}" -gt 0 ]; then
    log "installing slurmctld slurmd slurm-client munge (missing: ${need[*]})"
    export DEBIAN_FRONTEND=noninteractive
    if ! command -v apt-get >/dev/null 2>&1; then log "apt-get not available"; exit 3; fi
    # policy-rc.d 101: the packages' maintainer scripts must not start daemons; we start them below by hand.
    made_policy=0
    if [ ! -e /usr/sbin/policy-rc.d ]; then printf '#!/bin/sh\nexit 101\n' > /usr/sbin/policy-rc.d; chmod +x /usr/sbin/policy-rc.d; made_policy=1; fi
    apt-get update -qq >&2 || log "apt-get update failed (trying install anyway)"
    apt-get install -y -qq --no-install-recommends slurmctld slurmd slurm-client munge >&2
    rc=$?
    [ "$made_policy" = 1 ] && rm -f /usr/sbin/policy-rc.d
    if [ $rc -ne 0 ]; then log "apt-get install failed (rc=$rc)"; exit 3; fi
fi

mkdir -p "$STATE"/{log,spool/ctld,spool/d} /etc/slurm /run/munge /var/log/munge /var/lib/munge
HOST="$(hostname -s)"
# --all: GNU nproc honours OMP_NUM_THREADS, which a test process may have set to 1 (one BLAS thread); the node
# must declare the machine's real CPUs or group jobs asking for 2 stay pending (PartitionConfig) for ever
CPUS="$(nproc --all)"
MEM_MB="$(awk '/MemTotal/ {print int($2/1024*0.9)}' /proc/meminfo)"

# 2. slurm.conf (never overwrite a configuration that someone else wrote).
if [ -f "$CONF" ] && ! grep -qF "$MARK" "$CONF"; then
    log "$CONF exists and was not written by this script; refusing to overwrite it"; exit 4
fi
cat > "$CONF" <<CONF
$MARK
ClusterName=selfsense
SlurmctldHost=${HOST}(127.0.0.1)
AuthType=auth/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$STATE/spool/ctld
SlurmdSpoolDir=$STATE/spool/d
SlurmctldPidFile=$STATE/slurmctld.pid
SlurmdPidFile=$STATE/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
MinJobAge=600
MailProg=/bin/true
SlurmctldTimeout=30
SlurmdTimeout=30
NodeName=${HOST} NodeAddr=127.0.0.1 CPUs=${CPUS} RealMemory=${MEM_MB} State=UNKNOWN
PartitionName=debug Nodes=${HOST} Default=YES MaxTime=INFINITE State=UP
CONF
log "wrote $CONF (NodeName=$HOST CPUs=$CPUS RealMemory=$MEM_MB)"

# 3. munge.
if [ ! -s /etc/munge/munge.key ]; then
    mkdir -p /etc/munge
    if command -v mungekey >/dev/null 2>&1; then mungekey --create --force >&2; else
        dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null; fi
fi
chown -R munge:munge /etc/munge /run/munge /var/log/munge /var/lib/munge 2>/dev/null || true
chmod 0400 /etc/munge/munge.key 2>/dev/null || true
if alive "$STATE/munged.pid"; then
    log "munged already running (pid $(cat "$STATE/munged.pid"))"
else
    munged --force --pid-file="$STATE/munged.pid" >&2 || { log "munged failed to start"; exit 4; }
    for _ in $(seq 50); do alive "$STATE/munged.pid" && break; sleep 0.1; done
    alive "$STATE/munged.pid" || { log "munged did not write $STATE/munged.pid"; exit 4; }
    log "munged pid $(cat "$STATE/munged.pid")"
fi

# 4. slurmctld, slurmd (they daemonise and write the PID files named in slurm.conf).
if ! alive "$STATE/slurmctld.pid"; then
    slurmctld >&2 || { log "slurmctld failed to start; see $STATE/log/slurmctld.log"; exit 4; }
fi
if ! alive "$STATE/slurmd.pid"; then
    slurmd >&2 || { log "slurmd failed to start; see $STATE/log/slurmd.log"; exit 4; }
fi

# 5. Wait for the node to be idle.
deadline=$(( $(date +%s) + WAIT_S ))
while :; do
    st="$(node_state)"
    [ "$st" = "idle" ] && break
    case "$st" in down*|drain*) scontrol update nodename="$HOST" state=resume >/dev/null 2>&1 ;; esac
    if [ "$(date +%s)" -ge "$deadline" ]; then
        log "node not idle after ${WAIT_S}s (state '${st}'); logs in $STATE/log"; tail -n 20 "$STATE"/log/*.log >&2; exit 4
    fi
    sleep 0.5
done
log "cluster up: munged $(cat "$STATE/munged.pid"), slurmctld $(cat "$STATE/slurmctld.pid"), slurmd $(cat "$STATE/slurmd.pid")"
sinfo >&2
exit 0
