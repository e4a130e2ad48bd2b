#!/bin/sh
# The estimator study of bench/README.md: every direct-lighting estimator of the talk on the
# talk's four stages, at equal render time, direct lighting only (max depth 1, where the talk's
# claims apply), 4 light samples per light (what alpha = average visibility needs).
# Writes bench/results/estimators/{results.csv,results.md,error_vs_time.png}; the MIS references
# (1024 spp) are cached in bench/results/estimators/references/ (not committed: *.exr are large
# and regenerate deterministically).
#
#   sh bench/estimators.sh            # from the repository root; ~25-40 min on a busy 2-core machine
#   BUDGETS=1,4 sh bench/estimators.sh
#   REPEATS=3 sh bench/estimators.sh  # 3 interleaved runs per (config, budget), medians (~3x as long)
set -eu
cd "$(dirname "$0")/.."
BUDGETS="${BUDGETS:-2,8}"
REPEATS="${REPEATS:-1}"
exec .venv/bin/python -m renderer.cli bench stages/talk/*.usda \
    --estimators mis,lightSampling,bsdfSampling,controlVariate:one,controlVariate:averageVisibility,controlVariate:averageVisibilityUnbiased,ratio,auto \
    --light-samples 4 --budgets "$BUDGETS" --repeats "$REPEATS" --res 100 75 --max-depth 1 --seed 0 \
    --reference-spp 1024 --out bench/results/estimators --raw-throughput "$@"
