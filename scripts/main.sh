#!/usr/bin/env bash
# The main job: set up, then a short SILI training on Circle (3 Goals) that ends with a one-line
# verdict (did it hold the opponent over its last 50 interactions, and what it earned next to
# standing still and the scripted stabilizing policy), then a greedy evaluation.
# A small agent (2 x 64 networks) so it finishes in minutes on 2 CPU cores; b = 0 for the first
# 150 interactions (the latent model learns from a policy that pursues the task), then 0.5; 20
# latent-model updates per interaction (the default 5 let seed 0 go at this budget:
# benchmarks/RESULTS.md, "The main job"); float32 products on every machine (with bfloat16,
# chosen by default on CPUs with bfloat16 units, seed 0 did not hold at this budget).
# When it does not hold (seed 0 without AVX-512), it names a longer recipe that held there (3 of 3).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT=${SILI_MAIN_OUT:-runs/main}
.venv/bin/sili train --task circle-3 --method sili --seed 0 \
    --interactions "${SILI_MAIN_INTERACTIONS:-600}" --set hidden=64 \
    --set model.updates_per_interaction=20 --set sac.precision=float32 --beta-anneal 0 0.5 50 150 \
    --out "$OUT" --overwrite "$@"
if ! .venv/bin/python -c "import sys; from sili_robots.verdict import held; sys.exit(not held(sys.argv[1]))" "$OUT"; then
    echo "At 600 interactions of this small agent holding depends on how the processor rounds (seed 0 did not" \
        "hold with AVX2 alone, emulated). The delayed-b recipe with the default agent held in 3 of 3 seeds on a Zen 5" \
        "and with AVX2 alone (12-15 min): .venv/bin/sili train --task circle-3-v0 --method sili" \
        "--beta-schedule 250:0,300:0.5 --interactions 1000 --out runs/recipe (benchmarks/RESULTS.md, \"The main job\"" \
        "and \"Fewer updates per interaction: the learning check\")." >&2
fi
.venv/bin/sili eval "$OUT" --interactions 20
