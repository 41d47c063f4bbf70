#!/usr/bin/env bash
# Refresh constraints.txt: the exact versions of every dependency of `.[all,dev]`, as pip
# resolves them today into a fresh virtual environment. The image and .ci/run install with
# `pip install -c constraints.txt ...`, so two builds a month apart get the same packages
# until this is run again (and the change committed).
#
#   docker/refresh-constraints.sh            # uses python3; PYTHON=python3.11 to choose
#
# Resolve with the Python the image uses (3.11): some pins (numpy >= 2.3) need >= 3.11.
set -euo pipefail
cd "$(dirname "$0")/.."
python="${PYTHON:-python3}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"$python" -m venv "$tmp/venv"
"$tmp/venv/bin/python" -m pip install --quiet --upgrade pip
"$tmp/venv/bin/python" -m pip install --quiet '.[all,dev]'
version="$("$tmp/venv/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
{
    echo "# Exact versions for \`pip install -c constraints.txt '.[all,dev]'\` (and any subset)."
    echo "# Resolved on Python $version by docker/refresh-constraints.sh; do not edit by hand."
    "$tmp/venv/bin/python" -m pip freeze --exclude flocklab
} >constraints.txt.partial
mv constraints.txt.partial constraints.txt
echo "constraints.txt: $(grep -vc '^#' constraints.txt) pins (Python $version)"
