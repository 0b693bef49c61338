#!/usr/bin/env bash
# Regenerates every number and figure of docs/explanation/results.md (about 6 minutes on a 2-core machine).
# DATASET_ROOT: the published sessions, extracted from ../shared/data/sequence-learning/clean_data_bands.tar.xz
set -euo pipefail
ROOT=${DATASET_ROOT:?set DATASET_ROOT to the extracted clean_data folder}
cd "$(dirname "$0")/.."
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
# Personalising for a new participant (docs/explanation/personalisation.md): held-out sessions, assessment lengths 0-12
$NT evaluate --personalise --users sessions --data "$ROOT" --out docs/results/personalise
USERS=$(mktemp -d)
$NT evaluate --personalise --users sessions --data "$ROOT" --session-prior 2 --out docs/results/personalise-own-rates \
    --export-users "$USERS"
# the demo's two simulated participants: one whose best level is 2, one whose best is 4 (own rates)
mkdir -p sim/participants
cp "$USERS/user_17_session_1.json" sim/participants/level2.json
cp "$USERS/user_8_session_1.json" sim/participants/level4.json
rm -r "$USERS"
