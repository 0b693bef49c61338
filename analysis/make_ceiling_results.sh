#!/usr/bin/env bash
# The Bayes ceiling beside every policy (docs/explanation/results.md, "What can be won"), under the score and both target
# objectives (target-p: each turn's success probability near R; target-rate: the session's success rate near R).
# Then `PYTHONPATH=. python analysis/results_page.py` writes the page's generated tables and prose from these outputs.
# DATASET_ROOT: the published sessions, extracted from ../shared/data/sequence-learning/clean_data_bands.tar.xz
# OBJECTIVES: which objectives to run (default all three); they can run in parallel.
set -euo pipefail
ROOT=${DATASET_ROOT:?set DATASET_ROOT to the extracted clean_data folder}
cd "$(dirname "$0")/.."
NT=${NT:-.venv/bin/nao-trainer}
for OBJ in ${OBJECTIVES:-score target-p:0.75 target-rate:0.75}; do
  TAG=${OBJ/:/-}
  # own rates (each held-out session's own success per level, shrunk by 2 pseudo-turns); 1, 2, 5, 10 sessions
  $NT evaluate --personalise --users sessions --data "$ROOT" --session-prior 2 --assessment 0 --objective "$OBJ" \
      --loo-bayes --questplus-fitted --multi-session 2,5,10 --out "docs/results/ceiling-own-rates-$TAG"
  # data prior (the default per-session users)
  $NT evaluate --personalise --users sessions --data "$ROOT" --assessment 0 --objective "$OBJ" --loo-bayes \
      --questplus-fitted --multi-session 5 --out "docs/results/ceiling-data-prior-$TAG"
  # the cluster users (level-only variants of the shipped clusters)
  $NT evaluate --users level-only --seeds 3 --objective "$OBJ" --out "docs/results/ceiling-level-only-$TAG"
done
# which user model predicts held-out turns best (per level, clusters, pooled psychometric)
$NT evaluate --user-models --users sessions --data "$ROOT" --out docs/results/user-models
# the live bayes policy (shipped psychometric prior) valued on the same held-out users as bayes-psychometric
PYTHONPATH=. "${PYTHON:-.venv/bin/python}" analysis/live_bayes.py --data "$ROOT" docs/results/ceiling-{own-rates,data-prior}-{target-p-0.75,target-rate-0.75,score} \
    > docs/results/live_bayes.txt
PYTHONPATH=. "${PYTHON:-.venv/bin/python}" analysis/results_page.py   # the generated blocks of docs/explanation/results.md
