#!/usr/bin/env bash
# Create (or refresh) .venv with the CPU torch wheel first, then this package, with the optional
# dependency groups named as arguments (`bash scripts/setup.sh dev` adds the test tools).
# Idempotent: nothing to do when pyproject.toml and the torch pin are unchanged and the groups
# are installed. SILI_VENV: another environment folder; PYTHON: the interpreter to make it with
# (an environment on another Python version is made anew with it).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${SILI_VENV:-.venv}
PY=${PYTHON:-python3}
TORCH=2.13.0
TORCH_CPU_INDEX=https://download.pytorch.org/whl/cpu
SUPPORTED='import sys; sys.exit(sys.version_info < (3, 10))'  # pyproject's requires-python

version() { "$1" -c 'import sys; print(*sys.version_info[:2], sep=".")' 2>/dev/null; }

usable() {  # an environment with pip, on a supported Python (PYTHON's version, when given)
    "$VENV/bin/python" -c "$SUPPORTED" 2>/dev/null || return 1
    if [ -n "${PYTHON:-}" ]; then
        [ "$(version "$VENV/bin/python")" = "$(version "$PY")" ] || return 1
    fi
    "$VENV/bin/python" -m pip --version >/dev/null 2>&1 ||
        "$VENV/bin/python" -m ensurepip -q >/dev/null 2>&1
}

if ! usable; then
    # missing, broken (its interpreter gone with an upgrade) or on another Python: anew, if it
    # is an environment
    if [ -n "$(ls -A "$VENV" 2>/dev/null)" ] && [ ! -f "$VENV/pyvenv.cfg" ]; then
        echo "setup: $VENV is a folder, not a virtual environment; give SILI_VENV another" >&2
        exit 2
    fi
    if ! "$PY" -c "$SUPPORTED" 2>/dev/null; then
        echo "setup: sili-robots needs Python >= 3.10; $PY is $(version "$PY" || echo "not a" \
            "Python"); give PYTHON=python3.11 (or another >= 3.10)" >&2
        exit 2
    fi
    "$PY" -m venv --clear "$VENV"
fi
hash=$({ cat pyproject.toml; echo "torch==$TORCH"; } | sha256sum | cut -d' ' -f1)
stamp="$VENV/.sili-installed"  # the hash, then the groups installed with it
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
    pip=("$VENV/bin/python" -m pip install -q)
    "${pip[@]}" --upgrade pip
    # torch first, so no dependency range pulls another build. On Linux x86-64 PyPI's is the CUDA
    # build (several GB): the CPU build where pip finds it already (a wheel on disk, a configured
    # index), else from PyTorch's CPU index; elsewhere PyPI's is the CPU build.
    if [ "$(uname -s)-$(uname -m)" != Linux-x86_64 ]; then
        "${pip[@]}" "torch==$TORCH"
    elif ! "${pip[@]}" "torch==$TORCH+cpu" 2>/dev/null &&
        ! "${pip[@]}" "torch==$TORCH+cpu" --extra-index-url "$TORCH_CPU_INDEX"; then
        echo "setup: could not install torch $TORCH's CPU build (pip's error above); install it" \
            "into $VENV first (e.g. from a wheel file), then run this again" >&2
        exit 1
    fi
    spec="."
    [ -n "$groups" ] && spec=".[${groups// /,}]"
    "${pip[@]}" -e "$spec"
    echo "$hash${groups:+ $groups}" > "$stamp"
fi
