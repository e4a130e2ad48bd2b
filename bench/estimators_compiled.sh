#!/bin/sh
# Samples/s of the general (numpy wavefront) path against the compiled fast path, per estimator,
# on two talk stages: bench/results/estimators/compiled.md. Run from the repository root with the
# project's Python as $PY (default .venv/bin/python). Alternates the two paths run by run.
PY=${PY:-.venv/bin/python}
OUT=${OUT:-/tmp/illum_est_bench}
mkdir -p "$OUT"
for stage in penumbra dome; do
  for est in "controlVariate" "ratio" "auto" "mis --light-samples 4"; do
    for path in --no-fast-path --fast-path; do
      tag=$(echo "$stage $est $path" | tr ' ' '_' | tr -d '-')
      # shellcheck disable=SC2086
      $PY -m renderer.cli render "stages/talk/$stage.usda" -o "$OUT/$tag.exr" --res 128 128 --spp 16 --threads 1 \
          --estimator "*=${est%% *}" $(echo "$est" | grep -o -- '--light-samples [0-9]*') $path \
          --stats "$OUT/$tag.json" --quiet
      $PY -c "import json,sys; d=json.load(open(sys.argv[1])); print(sys.argv[2], sys.argv[3], sys.argv[4], round(d['samples_per_second']), d['fast_path'])" \
          "$OUT/$tag.json" "$stage" "${est%% *}" "$path"
    done
  done
done
