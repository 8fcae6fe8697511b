#!/usr/bin/env bash
# Runs one night on Kubernetes: the Indexed Job of shards, then — once every
# shard completed — the aggregate Job. The one place the night is set up:
#   BUCKET=s3://fleet-data IMAGE=registry.example.com/sparkout:1.2 \
#   SHARDS=4 NIGHT=2026-11-27 deploy/k8s/run-nightly.sh [namespace]
# SHARDS defaults to 4, NIGHT to today's UTC date; outputs go to
# $BUCKET/nights/$NIGHT/{shards/<i>,out}, so nights never overwrite each other.
#   deploy/k8s/run-nightly.sh --render DIR   writes the filled manifests to DIR
#                                            and applies nothing (used by the
#                                            tests; `kubectl apply -f DIR` works)
# Not run against a cluster here (none in CI); the manifests are rendered and
# checked by tests/e2e/deploy_recipes.rs, and the same flow is tested on Slurm
# by deploy/slurm/smoke.sh.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
render_only=""
if [ "${1:-}" = "--render" ]; then
    render_only=${2:?--render needs a directory}
    shift 2
fi
ns=${1:-default}
: "${BUCKET:?set BUCKET to the bucket URL holding runs/ (e.g. s3://fleet-data)}"
: "${IMAGE:?set IMAGE to the sparkout image (built from deploy/docker/Dockerfile)}"
SHARDS=${SHARDS:-4}
NIGHT=${NIGHT:-$(date -u +%Y-%m-%d)}
case "$SHARDS" in
    '' | *[!0-9]* | 0*) echo "SHARDS must be a whole number ≥ 1, not '$SHARDS'" >&2; exit 2 ;;
esac
# A typo (40000 for 4) would start that many pods.
if [ "$SHARDS" -gt 1000 ]; then
    echo "SHARDS must be at most 1000, not $SHARDS (a pod per shard; a night needs a few to a few dozen)" >&2
    exit 2
fi
# The pods share nothing but the bucket: a path without a scheme would be
# each pod's own disk (outputs lost, aggregate failing after every shard
# ran); a space would split the shard list the aggregate pod builds.
case "$BUCKET" in
    *[[:space:]]*) echo "BUCKET must not contain spaces: '$BUCKET'" >&2; exit 2 ;;
    s3://?* | gs://?* | az://?*) ;;
    *) echo "BUCKET must be an object-store URL (s3://, gs:// or az://), not '$BUCKET'" >&2; exit 2 ;;
esac
case "$NIGHT" in
    [0-9][0-9][0-9][0-9]-[0-9][0-9]-[0-9][0-9]) ;;
    *) echo "NIGHT must be YYYY-MM-DD, not '$NIGHT'" >&2; exit 2 ;;
esac
BUCKET=${BUCKET%/}
export BUCKET IMAGE SHARDS NIGHT

# Per-index retries need Kubernetes ≥ 1.29 (beta, on by default; GA in 1.33).
# On an older cluster they become one Job-wide retry budget.
per_index=yes
if [ -z "$render_only" ]; then
    minor=$(kubectl version -o json 2>/dev/null |
        python3 -c 'import json,sys; print(int("".join(c for c in json.load(sys.stdin)["serverVersion"]["minor"] if c.isdigit())))' 2>/dev/null || echo 0)
    [ "$minor" -ge 29 ] || per_index=no
fi
render() { # TEMPLATE → stdout; only our four variables are filled (the pod
    # scripts' own $i, $? and $JOB_COMPLETION_INDEX stay as they are).
    envsubst '${BUCKET} ${IMAGE} ${SHARDS} ${NIGHT}' <"$1" |
        if [ "$per_index" = yes ]; then cat; else
            sed -e 's/^  backoffLimitPerIndex: .*/  backoffLimit: '"$((2 * SHARDS))"'/' -e '/^  maxFailedIndexes:/d'
        fi
}
if [ -n "$render_only" ]; then
    dir=$render_only
else
    # The rendered manifests live as long as the night's script.
    dir=$(mktemp -d)
    trap 'rm -rf "$dir"' EXIT
fi
mkdir -p "$dir"
render "$here/shards-job.yaml" >"$dir/shards-job.yaml"
render "$here/aggregate-job.yaml" >"$dir/aggregate-job.yaml"
if [ -n "$render_only" ]; then
    echo "rendered $dir/shards-job.yaml and $dir/aggregate-job.yaml ($SHARDS shards, night $NIGHT)"
    exit 0
fi

# Wait for a Job to complete, and stop at once when it failed (waiting only
# for "complete" would sit out the whole timeout on a failed shard).
wait_job() { # JOB TIMEOUT_S
    local job=$1 deadline=$(($(date +%s) + $2))
    while :; do
        if kubectl -n "$ns" wait --for=condition=complete --timeout=15s "job/$job" >/dev/null 2>&1; then
            return 0
        fi
        if kubectl -n "$ns" wait --for=condition=failed --timeout=1s "job/$job" >/dev/null 2>&1; then
            echo "job $job failed; the night $NIGHT is not published:" >&2
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
kubectl -n "$ns" apply -f "$dir/shards-job.yaml"
wait_job sparkout-shards $((12 * 3600))
kubectl -n "$ns" apply -f "$dir/aggregate-job.yaml"
wait_job sparkout-aggregate $((2 * 3600))
echo "night $NIGHT published to $BUCKET/nights/$NIGHT/out"
