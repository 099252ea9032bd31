#!/usr/bin/env bash
# Every experiment of docs/experiments.md, one after another (one heavy job at a time),
# results in bench/results/experiments/<name>/. Pass names to run only some of them:
#   bash bench/run_experiments.sh failure_modes sensitivity
set -u
PY=${PY:-.venv/bin/python}
OUT=${OUT:-bench/results/experiments}
ALL="table3_default failure_modes sensitivity scale table3_paper_dqn table3_paper_ppo media"
for name in ${@:-$ALL}; do
  echo "=== $name $(date +%T) load $(cut -d' ' -f1-3 /proc/loadavg)"
  start=$(date +%s)
  case $name in
    table3_default)   $PY -m wrl_jax.experiments.table3 --presets default --seeds 32 --first-seed 1000 --out $OUT/table3_default_32seeds ;;
    table3_paper_dqn) $PY -m wrl_jax.experiments.table3 --presets paper --algos dqn --seeds 8 --eval-points 25 --out $OUT/table3_paper_dqn ;;
    table3_paper_ppo) $PY -m wrl_jax.experiments.table3 --presets paper --algos ppo --seeds 8 --eval-points 25 --out $OUT/table3_paper_ppo ;;
    failure_modes)    $PY -m wrl_jax.experiments.failure_modes --seeds 8 --out $OUT/failure_modes ;;
    sensitivity)      $PY -m wrl_jax.experiments.sensitivity --seeds 4 --out $OUT/sensitivity ;;
    scale)            $PY -m wrl_jax.experiments.scale --presets default --seeds 8 --out $OUT/scale ;;
    media)            $PY -m wrl_jax.experiments.media --out docs/media ;;
    *) echo "unknown experiment $name"; exit 2 ;;
  esac
  echo "=== $name exit $? wall $(( $(date +%s) - start )) s"
done
