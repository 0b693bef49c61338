#!/usr/bin/env bash
# The power figures of docs/how-to/study.md and the README ("Running a study"). Needs the published dataset
# extracted (DATA=.../clean_data); about 2-4 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:?set DATA to the extracted clean_data folder of the published dataset}
nao-trainer study power config/protocols/example-3arm.yaml --users sessions --data "$DATA" \
  --n 12,24,48,96,192,384 --reps 400 --seed 1 --out docs/study/sessions
nao-trainer study power config/protocols/example-3arm.yaml --users clusters \
  --n 12,24,48,96,192,384 --reps 400 --seed 1 --out docs/study/clusters
