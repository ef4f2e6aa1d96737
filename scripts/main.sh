#!/usr/bin/env bash
# The main job: set up, then a short SILI training on Circle (3 Goals) that ends with a one-line
# verdict (did it hold the opponent over its last 50 interactions, and what it earned next to
# standing still and the scripted stabilizing policy), then a greedy evaluation.
# The delayed-b recipe (b = 0 until interaction 250, the latent model learning from a policy
# that pursues the task; 0.5 from 300) on a small agent (2 x 64 networks) so 1,000 interactions
# fit in minutes on 2 CPU cores; float32 products on every machine. It held above standing
# still's reward in 9 of 12 seeds across two instruction sets (benchmarks/RESULTS.md, "The main
# job"). When a run did not hold, or held below that reward, it names the default agent's longer
# recipe.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT=${SILI_MAIN_OUT:-runs/main}
.venv/bin/sili train --task circle-3 --method sili --seed 0 \
    --interactions "${SILI_MAIN_INTERACTIONS:-1000}" --set hidden=64 --set sac.precision=float32 \
    --beta-schedule 250:0,300:0.5 --out "$OUT" --overwrite "$@"
if ! .venv/bin/python -c "import sys; from sili_robots.verdict import worked; sys.exit(not worked(sys.argv[1]))" "$OUT"; then
    echo "Whether this small agent holds well at 1,000 interactions depends on the sample (how the processor" \
        "rounds is part of it: 9 of 12 seeds held above standing still's reward). The delayed-b recipe with the" \
        "default agent held in 11 of 12 seeds (12-15 min): .venv/bin/sili train --task circle-3-v0 --method sili" \
        "--beta-schedule 250:0,300:0.5 --interactions 1000 --out runs/recipe (benchmarks/RESULTS.md, \"The main job\"" \
        "and \"Fewer updates per interaction: the learning check\")." >&2
fi
.venv/bin/sili eval "$OUT" --interactions 20
