#!/usr/bin/env bash
# The main job: set up, then a short SILI training run on Circle (3 Goals) that prints its result
# (final task reward and true stability over its last interactions, then a greedy evaluation).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/sili train --task circle-3 --method sili --interactions "${SILI_MAIN_INTERACTIONS:-150}" \
    --seed 0 --out runs/main --overwrite "$@"
.venv/bin/sili eval runs/main --interactions 20
