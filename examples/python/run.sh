#!/usr/bin/env bash
# Sets up the Python example client (a venv with the pinned packages from PyPI, then the
# gRPC code generated from crates/client/proto/ with grpcio-tools) and runs it with the given arguments:
#
#   examples/python/run.sh --server 127.0.0.1:50051 --filter taa
#
# The venv and the generated code go under examples/python/.venv and
# examples/python/generated (both ignored by git); a second run reuses them.
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
stamp="$venv/.requirements"
if ! cmp -s "$here/requirements.txt" "$stamp"; then
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements.txt"
  cp "$here/requirements.txt" "$stamp"
fi

out="$here/generated"
mkdir -p "$out"
"$venv/bin/python" -m grpc_tools.protoc -I "$root/crates/client/proto" \
  --python_out="$out" --grpc_python_out="$out" \
  "$root/crates/client/proto/afterimage/v1/afterimage.proto"

exec "$venv/bin/python" "$here/client.py" "$@"
