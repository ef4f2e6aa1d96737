#!/usr/bin/env bash
# Create (or refresh) .venv with the CPU torch wheel first, then this package, with the optional
# dependency groups named as arguments (`bash scripts/setup.sh dev` adds the test tools).
# Idempotent: nothing to do when pyproject.toml is unchanged and the groups are installed.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${SILI_VENV:-.venv}
PY=${PYTHON:-python3}
if ! "$VENV/bin/python" -m pip --version >/dev/null 2>&1 &&
    ! "$VENV/bin/python" -m ensurepip -q >/dev/null 2>&1; then
    # missing, or broken (its interpreter gone with an upgrade): anew, if it is an environment
    if [ -n "$(ls -A "$VENV" 2>/dev/null)" ] && [ ! -f "$VENV/pyvenv.cfg" ]; then
        echo "setup: $VENV is a folder, not a virtual environment; give SILI_VENV another" >&2
        exit 2
    fi
    "$PY" -m venv --clear "$VENV"
fi
hash=$(sha256sum pyproject.toml | cut -d' ' -f1)
stamp="$VENV/.sili-installed"  # the pyproject hash, then the groups installed with it
have=$(cat "$stamp" 2>/dev/null || true)
groups="" missing=1
if [ "${have%% *}" = "$hash" ]; then
    groups=$(echo "$have" | cut -s -d' ' -f2-) missing=0
fi
for g in "$@"; do
    case " $groups " in *" $g "*) ;; *) missing=1; groups="$groups $g" ;; esac
done
if [ "$missing" = 1 ]; then
    groups=$(echo $groups)  # trimmed, one space apart
    "$VENV/bin/python" -m pip install -q --upgrade pip
    # CPU build first so no dependency range pulls a CUDA build of torch.
    "$VENV/bin/python" -m pip install -q torch==2.13.0
    spec="."
    [ -n "$groups" ] && spec=".[${groups// /,}]"
    "$VENV/bin/python" -m pip install -q -e "$spec"
    echo "$hash${groups:+ $groups}" > "$stamp"
fi
