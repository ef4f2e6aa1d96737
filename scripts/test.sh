#!/usr/bin/env bash
# Set up, then lint and run the whole test suite (slow learning tests included).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh dev
if ! command -v chromium >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    # Headless visual checks of the previews need Debian's chromium.
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium \
        fonts-dejavu-core >/dev/null) || echo "warning: could not install chromium" >&2
fi
VENV=${SILI_VENV:-.venv}  # the environment setup.sh made
"$VENV/bin/ruff" check .
"$VENV/bin/ruff" format --check .
# Two pytest workers (pytest-xdist): on a 2-core Zen 3 the suite took 9 min against 15 in one process.
# Give -n 0 after the command for one process (e.g. to debug a test).
exec "$VENV/bin/python" -m pytest -m "slow or not slow" -n 2 "$@"
