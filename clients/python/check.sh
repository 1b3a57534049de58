#!/usr/bin/env bash
# Checks the afterimage-client package end to end (what CI runs):
#
#   clients/python/check.sh target/release/afterimage
#
# 1. `pip install ./clients/python[test]` into a fresh venv (a temporary directory, removed
#    afterwards) builds the package, its gRPC modules generated from
#    crates/client/proto/afterimage/v1/afterimage.proto (setup.py), and installs it,
#    importable from the venv's site-packages, with its `python -m afterimage_client` command;
# 2. the sdist carries the proto, and the wheel built from the sdist (not the checkout) has
#    the generated modules;
# 3. the tests in clients/python/tests run against the given server binary: the EXR
#    mapping and error unit tests, and, against a real `afterimage serve` on loopback
#    ports, `python -m afterimage_client filter` on the committed Blender frames for taa
#    and phlm compared with `afterimage filter` on the same frames (bit for bit), and the
#    Blender example (examples/blender_stream.py) when `blender` is installed.
#
# PYTHON picks the interpreter (default python3); AFTERIMAGE_PY_CONSTRAINTS, a pip
# constraints file, pins the dependencies (default: none, the newest that fit, as a user
# installing the package gets).
set -euo pipefail
if [ $# -ne 1 ]; then
  echo "usage: $0 PATH/TO/afterimage   (the server binary the tests start)" >&2
  exit 2
fi
bin="$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"
if [ ! -x "$bin" ]; then
  echo "$0: $1 is not an executable afterimage binary" >&2
  exit 2
fi
here="$(cd "$(dirname "$0")" && pwd)"
py="${PYTHON:-python3}"

echo "== pip install ./clients/python into a fresh venv"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
if ! "$py" -m venv "$tmp/venv" 2>/dev/null; then
  # Debian's system Python keeps venv in a separate package.
  rm -rf "$tmp/venv"
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv) >&2
  "$py" -m venv "$tmp/venv"
fi
constraints=()
[ -n "${AFTERIMAGE_PY_CONSTRAINTS:-}" ] && constraints=(-c "$AFTERIMAGE_PY_CONSTRAINTS")
"$tmp/venv/bin/python" -m pip install --quiet --disable-pip-version-check "${constraints[@]}" "$here[test]"
"$tmp/venv/bin/python" -m pip list --disable-pip-version-check 2>/dev/null | grep -iE '^(afterimage-client|grpcio|protobuf|numpy|openexr|pytest) '
# Run from elsewhere, so the import can only come from the installed package.
(cd "$tmp" && "$tmp/venv/bin/python" - <<'PY'
import afterimage_client, sys
where = afterimage_client.__file__
assert "site-packages" in where, f"afterimage_client imported from {where}, not the venv's site-packages"
print(f"afterimage_client {afterimage_client.__version__} from {where}")
PY
)
(cd "$tmp" && "$tmp/venv/bin/python" -m afterimage_client filter --help >/dev/null)

echo "== the sdist carries the proto; the wheel built from it has the generated gRPC modules"
# A build away from the checkout (an sdist) has no ../../crates: it must bring its own proto.
"$tmp/venv/bin/python" -m pip install --quiet --disable-pip-version-check build
"$tmp/venv/bin/python" -m build --outdir "$tmp/dist" "$here" >"$tmp/build.log" 2>&1 || { cat "$tmp/build.log" >&2; exit 1; }
"$tmp/venv/bin/python" - "$tmp/dist" <<'PY'
import glob, sys, tarfile, zipfile
(sdist,), (wheel,) = glob.glob(f"{sys.argv[1]}/*.tar.gz"), glob.glob(f"{sys.argv[1]}/*.whl")
names = tarfile.open(sdist).getnames()
assert any(n.endswith("/proto/afterimage/v1/afterimage.proto") for n in names), f"{sdist} has no proto: {names}"
assert not any("afterimage_pb2" in n for n in names), f"{sdist} carries generated modules"
missing = {f"afterimage_client/proto/afterimage_pb2{m}" for m in (".py", ".pyi", "_grpc.py")} - set(zipfile.ZipFile(wheel).namelist())
assert not missing, f"{wheel} lacks {sorted(missing)}"
print(f"{sdist.rsplit('/', 1)[1]} carries the proto; {wheel.rsplit('/', 1)[1]}, built from it, the generated modules")
PY

echo "== tests against $bin"
cd "$tmp"
# -s: the agreement tests print their max |client - afterimage filter| per filter and shot.
# tests/test_blender_example.py runs examples/blender_stream.py in `blender` when it is on
# PATH (AFTERIMAGE_REQUIRE_BLENDER=1 makes its absence a failure).
AFTERIMAGE_BIN="$bin" AFTERIMAGE_REQUIRE_SERVER=1 \
  "$tmp/venv/bin/python" -m pytest -q -s -p no:cacheprovider "$here/tests"

echo "== the EXR and server tests again with the built-in EXR reader and writer (the one Blender uses)"
AFTERIMAGE_BIN="$bin" AFTERIMAGE_REQUIRE_SERVER=1 AFTERIMAGE_CLIENT_EXR=builtin \
  "$tmp/venv/bin/python" -m pytest -q -p no:cacheprovider "$here/tests/test_exr.py" "$here/tests/test_server.py"
echo "== clients/python: all passed"
