#!/usr/bin/env bash
# Status of a fake-cluster job (cluster/submit.sh): prints exactly running, success or failed.
# Unknown ids print "failed": Snakemake persists external job ids and resumes them after a crash; answering
# "running" for an id that no longer exists makes it wait forever.
set -uo pipefail
id="${1:-}"
dir="${SELFSENSE_FAKECLUSTER_DIR:-.fakecluster}"
if [ -z "$id" ] || [ ! -e "$dir/$id.args" ]; then echo failed; exit 0; fi
if [ -f "$dir/$id.rc" ]; then
    [ "$(cat "$dir/$id.rc")" = "0" ] && echo success || echo failed
    exit 0
fi
pid="$(cat "$dir/$id.pid" 2>/dev/null || true)"
if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then echo running; exit 0; fi
# process gone: give the .rc rename a moment, then decide
sleep 0.2
if [ -f "$dir/$id.rc" ] && [ "$(cat "$dir/$id.rc")" = "0" ]; then echo success; else echo failed; fi
