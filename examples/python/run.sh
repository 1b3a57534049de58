#!/usr/bin/env bash
# Sets up the Python example client (a venv with the afterimage-client package from
# clients/python, its dependencies pinned by requirements.txt) and runs it with the given
# arguments:
#
#   examples/python/run.sh --server 127.0.0.1:50051 --filter taa
#
# The venv goes under examples/python/.venv (ignored by git); a second run reuses it and
# reinstalls the package only when clients/python, the proto its build generates the gRPC
# modules from, or requirements.txt changed.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
venv="$here/.venv"
py="${PYTHON:-python3}"

if [ ! -x "$venv/bin/python" ]; then
  if ! "$py" -m venv "$venv" 2>/dev/null; then
    # Debian's system Python keeps venv in a separate package.
    echo "python3 -m venv failed; installing python3-venv" >&2
    rm -rf "$venv"
    (apt-get update -qq && apt-get install -y -qq python3-venv) >&2
    "$py" -m venv "$venv"
  fi
fi
stamp="$venv/.afterimage-client"
pkg="$root/clients/python"
if [ ! -f "$stamp" ] || ! cmp -s "$here/requirements.txt" "$stamp" \
  || [ -n "$(find "$pkg/pyproject.toml" "$pkg/setup.py" "$pkg/src" "$pkg/proto/" -newer "$stamp" -print -quit)" ]; then
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -c "$here/requirements.txt" "$pkg"
  cp "$here/requirements.txt" "$stamp"
fi

exec "$venv/bin/python" "$here/client.py" "$@"
