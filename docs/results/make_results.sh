#!/usr/bin/env bash
# Regenerates every number and figure of docs/results.md (about 6 minutes on a 2-core machine).
# DATASET_ROOT: the published sessions, extracted from ../shared/data/sequence-learning/clean_data_bands.tar.xz
set -euo pipefail
ROOT=${DATASET_ROOT:?set DATASET_ROOT to the extracted clean_data folder}
cd "$(dirname "$0")/../.."
NT=${NT:-.venv/bin/nao-trainer}
$NT fit "$ROOT" --out sim/models-tested --no-figures                          # the tested-effects default fit
$NT evaluate --users clusters --per-user --out docs/results/clusters
$NT evaluate --users clusters --mdp informed --per-user --out docs/results/clusters-informed
$NT evaluate --users level-only --per-user --out docs/results/level-only
$NT evaluate --users clusters --models sim/models-tested --per-user --out docs/results/clusters-tested
$NT evaluate --users sessions --data "$ROOT" --out docs/results/sessions
$NT evaluate --users sessions --data "$ROOT" --mdp informed --out docs/results/sessions-informed
$NT evaluate --users clusters --policy-files sim/policies \
    --policies fixed:2,best-fixed,usp:performance,usp:shaping,usp:qaug,usp-learning:qaug,oracle \
    --out docs/results/clusters-shipped
