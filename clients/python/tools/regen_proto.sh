#!/usr/bin/env bash
# Regenerates the committed gRPC modules in src/afterimage_client/proto/ from
# crates/client/proto/afterimage/v1/afterimage.proto (the repository's contract), with a pinned
# grpcio-tools so the output is the same on every machine.
#
#   clients/python/tools/regen_proto.sh           # rewrite the modules
#   clients/python/tools/regen_proto.sh --check   # exit 1 if the committed ones are stale
#
# Why committed: `pip install ./clients/python` then needs neither grpcio-tools nor the
# repository's proto/ directory (a build from an sdist or a copied folder has no ../../proto),
# and every install gets the same code. The pinned generator decides the lower bounds in
# pyproject.toml: its code asks for protobuf >= the version it names and grpcio >= its own
# version (see GENCODE_* below); raise those bounds together with GRPCIO_TOOLS.
#
# The venv with the generator goes to $AFTERIMAGE_PROTOC_VENV (default
# ~/.cache/afterimage-grpcio-tools-$GRPCIO_TOOLS) and is reused.
set -euo pipefail
GRPCIO_TOOLS=1.66.2
here="$(cd "$(dirname "$0")/.." && pwd)"
root="$(cd "$here/../.." && pwd)"
dest="$here/src/afterimage_client/proto"
venv="${AFTERIMAGE_PROTOC_VENV:-$HOME/.cache/afterimage-grpcio-tools-$GRPCIO_TOOLS}"
check=0
[ "${1:-}" = "--check" ] && check=1

if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import grpc_tools" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check "grpcio-tools==$GRPCIO_TOOLS"
fi

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"$venv/bin/python" -m grpc_tools.protoc -I "$root/crates/client/proto" \
  --python_out="$tmp" --pyi_out="$tmp" --grpc_python_out="$tmp" \
  "$root/crates/client/proto/afterimage/v1/afterimage.proto"
mkdir -p "$tmp/out"
for f in afterimage_pb2.py afterimage_pb2.pyi afterimage_pb2_grpc.py; do
  # The generated stub imports the messages as a top-level package `afterimage.v1`; inside
  # this package they are a sibling module.
  sed -e 's/^from afterimage\.v1 import afterimage_pb2 as /from . import afterimage_pb2 as /' \
    "$tmp/afterimage/v1/$f" >"$tmp/out/$f"
done

if [ $check = 1 ]; then
  stale=0
  for f in afterimage_pb2.py afterimage_pb2.pyi afterimage_pb2_grpc.py; do
    if ! cmp -s "$tmp/out/$f" "$dest/$f"; then
      echo "stale: $dest/$f differs from what grpcio-tools $GRPCIO_TOOLS generates from crates/client/proto/afterimage/v1/afterimage.proto; run clients/python/tools/regen_proto.sh" >&2
      stale=1
    fi
  done
  [ $stale = 0 ] && echo "generated gRPC modules are current (grpcio-tools $GRPCIO_TOOLS)"
  exit $stale
fi
mkdir -p "$dest"
cp "$tmp/out/"* "$dest/"
echo "wrote $dest/{afterimage_pb2.py,afterimage_pb2.pyi,afterimage_pb2_grpc.py} with grpcio-tools $GRPCIO_TOOLS"
