#!/usr/bin/env bash
# Runs one night on Kubernetes: the Indexed Job of shards, then — once every
# shard completed — the aggregate Job. Not tested here (no cluster in CI);
# the same flow is tested on Slurm by deploy/slurm/smoke.sh.
#   deploy/k8s/run-nightly.sh [namespace]
set -euo pipefail
ns=${1:-default}
here=$(cd "$(dirname "$0")" && pwd)
# Wait for a Job to complete, and stop at once when it failed (waiting only
# for "complete" would sit out the whole timeout on a failed shard).
wait_job() { # JOB TIMEOUT_S
    local job=$1 deadline=$(($(date +%s) + $2))
    while :; do
        if kubectl -n "$ns" wait --for=condition=complete --timeout=15s "job/$job" >/dev/null 2>&1; then
            return 0
        fi
        if kubectl -n "$ns" wait --for=condition=failed --timeout=1s "job/$job" >/dev/null 2>&1; then
            echo "job $job failed; the night is not published:" >&2
            kubectl -n "$ns" describe "job/$job" | tail -n 20 >&2
            return 1
        fi
        if [ "$(date +%s)" -ge "$deadline" ]; then
            echo "job $job did not finish within $2 s" >&2
            return 1
        fi
    done
}
kubectl -n "$ns" delete job sparkout-shards sparkout-aggregate --ignore-not-found
kubectl -n "$ns" apply -f "$here/shards-job.yaml"
wait_job sparkout-shards $((12 * 3600))
kubectl -n "$ns" apply -f "$here/aggregate-job.yaml"
wait_job sparkout-aggregate $((2 * 3600))
echo "night published to \$BUCKET/out (see BUCKET in the two Job manifests)"
