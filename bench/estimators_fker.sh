#!/bin/sh
# Samples/s of the compiled path's per-light estimators before and after F moved into the vertex
# kernel (#23): BASE and NEW are two checkouts (BASE e.g. `git archive 94d3740`), each run with
# its own PYTHONPATH, alternated run by run. Writes one line per run:
#   stage estimator which repeat samples_per_second fast_path
# Run from anywhere with the project's Python as $PY (default /work/main/.venv/bin/python).
PY=${PY:-/work/main/.venv/bin/python}
BASE=${BASE:?checkout before}
NEW=${NEW:?checkout after}
OUT=${OUT:-/tmp/illum_fker_bench}
REPEATS=${REPEATS:-2}
mkdir -p "$OUT"
run() {  # which dir stage estimator extra... (sh has no locals: the names are run's own)
  r_which=$1; r_dir=$2; r_stage=$3; r_est=$4; shift 4
  tag=$(echo "$r_which $(basename "$r_stage" .usda) $r_est $*" | tr ' /*=' '____' | tr -d '-')
  (cd "$r_dir" && PYTHONPATH=$r_dir $PY -m renderer.cli render "$r_stage" -o "$OUT/$tag.exr" --res 128 96 --spp 8 \
      --threads 1 --max-depth 4 --estimator "*=$r_est" "$@" --stats "$OUT/$tag.json" --quiet) || return 1
  $PY -c "import json,sys; d=json.load(open(sys.argv[1])); print(*sys.argv[2:], round(d['samples_per_second']), d['fast_path'])" \
      "$OUT/$tag.json" "$(basename "$r_stage" .usda)" "$r_est${*:+ $*}" "$r_which" "$r"
}
for r in $(seq 1 "$REPEATS"); do
  for stage in penumbra dome disks large_rect sphere_occluder furnace; do
    for est in controlVariate ratio; do
      run base "$BASE" "stages/talk/$stage.usda" $est
      run new "$NEW" "stages/talk/$stage.usda" $est
    done
  done
  run base "$BASE" stages/many_lights/many_lights.usda controlVariate --light-sampler bvh
  run new "$NEW" stages/many_lights/many_lights.usda controlVariate --light-sampler bvh
done
