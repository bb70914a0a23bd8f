#!/usr/bin/env bash
# Fake scheduler for Snakemake's cluster-generic executor: runs the jobscript (last argument) in the
# background on this machine and prints a job id. The other arguments (--mem=... --time=... --cpus=...
# --name=...) are recorded in .fakecluster/<id>.args so the templating can be checked.
# NOT `set -e`: with -e a failing job would never write its .rc and status.sh would say "running" forever.
set -uo pipefail
jobscript="${@: -1}"
dir="${SELFSENSE_FAKECLUSTER_DIR:-.fakecluster}"
mkdir -p "$dir"
id="fake$(date +%s%N)$$"
echo "$*" > "$dir/$id.args"
( rc=0; bash "$jobscript" > "$dir/$id.out" 2>&1 || rc=$?; echo "$rc" > "$dir/$id.rc.tmp"; mv "$dir/$id.rc.tmp" "$dir/$id.rc" ) \
    < /dev/null > /dev/null 2>&1 &
echo "$!" > "$dir/$id.pid"
echo "$id"
