#!/usr/bin/env bash
# Runs one night on Kubernetes: the Indexed Job of shards, then — once every
# shard completed — the aggregate Job. Not tested here (no cluster in CI);
# the same flow is tested on Slurm by deploy/slurm/smoke.sh.
#   deploy/k8s/run-nightly.sh [namespace]
set -euo pipefail
ns=${1:-default}
here=$(cd "$(dirname "$0")" && pwd)
kubectl -n "$ns" delete job sparkout-shards sparkout-aggregate --ignore-not-found
kubectl -n "$ns" apply -f "$here/shards-job.yaml"
kubectl -n "$ns" wait --for=condition=complete --timeout=12h job/sparkout-shards
kubectl -n "$ns" apply -f "$here/aggregate-job.yaml"
kubectl -n "$ns" wait --for=condition=complete --timeout=2h job/sparkout-aggregate
echo "night published to \$BUCKET/out (see BUCKET in the two Job manifests)"
