#!/usr/bin/env bash
# The main job: set up, then a short SILI training run on Circle (3 Goals) that prints its result.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/sili rollout circle-3 --policy stabilizing --interactions 50 "$@"
