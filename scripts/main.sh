#!/usr/bin/env bash
# The main job: set up, then a short SILI training on Circle (3 Goals), two seeds at once (one per
# core), each ending with a one-line verdict (did it hold the opponent over its last 50
# interactions, and what it earned next to standing still and the scripted stabilizing policy),
# then one line across the seeds and a greedy evaluation of the best run (one that worked, if any).
# The delayed-b recipe (b = 0 until interaction 250, the latent model learning from a policy
# that pursues the task; 0.5 from 300) on a small agent (2 x 64 networks) so 900 interactions
# fit in 5 minutes on 2 CPU cores without AVX-512; float32 products on every machine. A run held
# above standing still's reward in 8 of 12 seeds across two instruction sets, the same seeds at
# 900 interactions as at 1,000 (benchmarks/RESULTS.md, "The main job"). When neither seed did, it
# names the default agent's longer recipe on the same task.
# SILI_MAIN_OUT: where the sweep goes (default runs/main-job; a rerun replaces it).
# Further arguments go to `sili sweep`; the output folder is SILI_MAIN_OUT's alone, as the verdict
# reads the runs there.
# SILI_VENV: the environment setup.sh makes and the job runs in (default .venv).
set -euo pipefail
dry_run=0
for arg in "$@"; do
    case $arg in
    --ou*)  # --out, or an abbreviation argparse would take for it
        echo "scripts/main.sh: error: give the output folder as SILI_MAIN_OUT=DIR, not $arg" >&2
        exit 2
        ;;
    --dr* | -h | --he*) dry_run=1 ;;  # --dry-run or --help (or abbreviations): nothing trained
    esac
done
cd "$(dirname "$0")/.."
bash scripts/setup.sh
VENV=${SILI_VENV:-.venv}
OUT=${SILI_MAIN_OUT:-runs/main-job}
"$VENV/bin/sili" sweep --tasks circle-3 --methods sili --seeds 0-1 --workers 2 \
    --interactions "${SILI_MAIN_INTERACTIONS:-900}" --set hidden=64 --set sac.precision=float32 \
    --beta-schedule 250:0,300:0.5 --out "$OUT" --overwrite --no-tensorboard "$@"
[ "$dry_run" = 1 ] && exit 0
status=0
RUN=$("$VENV/bin/python" -m sili_robots.verdict "$OUT"/runs/*/) || status=$?  # the runs --overwrite left
if [ "$status" = 3 ]; then  # no seed worked (sili_robots.verdict.NONE_WORKED)
    echo "Whether this small agent holds well at 900 interactions depends on the seed (how the processor" \
        "rounds is part of it: 8 of 12 seeds held above standing still's reward). The default agent (2 x 256) in float32" \
        "held on this task in 3 of 3 seeds of the paper grid at 2,000 interactions (-8.3 to -16.9; 23-27 min per run):" \
        "$VENV/bin/sili train --task circle-3 --method sili --interactions 2000 --set sac.precision=float32 --out runs/recipe" \
        "(benchmarks/RESULTS.md, \"The main job\" and \"The paper grid\")." >&2
elif [ "$status" != 0 ]; then
    exit "$status"
fi
"$VENV/bin/sili" eval "$RUN" --interactions 20
