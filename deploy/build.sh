#!/usr/bin/env bash
# Builds the server binary the way the image does, and puts it in OUT_DIR.
#
#   deploy/build.sh OUT_DIR           cargo build --locked --release --bin afterimage, then
#                                     OUT_DIR/afterimage (debug info stripped) and a
#                                     --version smoke run. deploy/Dockerfile's build stage
#                                     runs exactly this (deploy/build.sh /out).
#   deploy/build.sh --check OUT_DIR   What CI runs, without building again: the Dockerfile
#                                     runs this script and copies its output; the build
#                                     context of Dockerfile.dockerignore holds what cargo
#                                     needs (cargo reads the manifest and lock file there);
#                                     target/release/afterimage exists, is newer than every
#                                     input, and goes through the same install step.
#
# Why --check in CI: .ci/run's `cargo test --release` builds target/release/afterimage with
# the features dev-dependencies add (tokio's io-util, ...). A plain `cargo build --release`
# after it compiles afterimage again (measured on the 2-core machine: 2 min 45 s with every
# dependency already built for both feature sets; on a fresh clone the dependencies of the
# non-test feature set as well). The binary is the same program either way.
#
# STRIP=debug (default: symbols kept, so panics still name functions; 18 MB instead of
# 91 MB), STRIP=all (14 MB) or STRIP=none.
set -euo pipefail
cd "$(dirname "$0")/.."

check=0
if [ "${1:-}" = --check ]; then
  check=1
  shift
fi
if [ $# -ne 1 ]; then
  sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//' >&2
  exit 2
fi
out=$1
strip_mode=${STRIP:-debug}
bin=target/release/afterimage
# What the binary is built from (the context also has benches/, which Cargo.toml names).
inputs=(Cargo.toml Cargo.lock src crates)

if [ $check = 1 ]; then
  # 1. The Dockerfile's build stage runs this script into /out, and the runtime stage copies
  #    that file: the image is built by the steps checked here.
  grep -qxF '    deploy/build.sh /out' deploy/Dockerfile ||
    { echo "build.sh: deploy/Dockerfile does not run 'deploy/build.sh /out'" >&2; exit 1; }
  grep -qxF 'COPY --from=build /out/afterimage /usr/local/bin/afterimage' deploy/Dockerfile ||
    { echo "build.sh: deploy/Dockerfile does not copy /out/afterimage from the build stage" >&2; exit 1; }
  grep -qxF 'ENTRYPOINT ["afterimage", "serve"]' deploy/Dockerfile ||
    { echo "build.sh: deploy/Dockerfile's ENTRYPOINT is not afterimage serve" >&2; exit 1; }
  # 2. The build context: copy what Dockerfile.dockerignore lets in (docker's rules: the
  #    last matching pattern wins, a pattern matching a parent directory matches its files)
  #    and let cargo read the manifest, its targets and the lock file there: a file the
  #    build needs but the context leaves out fails here (cargo fetch --locked also fails
  #    when Cargo.lock is not up to date).
  ctx=$(mktemp -d)
  trap 'rm -rf "$ctx"' EXIT
  python3 - deploy/Dockerfile.dockerignore "$ctx" <<'PY'
import fnmatch, os, shutil, subprocess, sys
rules = []
for line in open(sys.argv[1]):
    line = line.strip()
    if line and not line.startswith('#'):
        neg = line.startswith('!')
        rules.append((neg, line.lstrip('!').strip('/')))
def excluded(path):
    parts = path.split('/')
    out = False
    for neg, pat in rules:
        for i in range(1, len(parts) + 1):
            if fnmatch.fnmatchcase('/'.join(parts[:i]), pat):
                out = not neg
                break
    return out
files = subprocess.run(['git', 'ls-files', '-co', '--exclude-standard', '-z'],
                       capture_output=True, text=True, check=True).stdout.split('\0')
n = 0
for f in filter(None, files):
    if os.path.isfile(f) and not excluded(f):
        os.makedirs(os.path.join(sys.argv[2], os.path.dirname(f)), exist_ok=True)
        shutil.copy2(f, os.path.join(sys.argv[2], f))
        n += 1
print(f'build.sh: the image build context: {n} files')
PY
  [ -x "$ctx/deploy/build.sh" ] || { echo "build.sh: the build context lacks deploy/build.sh" >&2; exit 1; }
  (cd "$ctx" && cargo fetch --locked --quiet) ||
    { echo "build.sh: cargo cannot read the image's build context (deploy/Dockerfile.dockerignore leaves out a file it needs?)" >&2; exit 1; }
  # 3. A binary built from the current inputs.
  [ -x "$bin" ] || { echo "build.sh: no $bin: build it first (cargo build --locked --release, or CI's release test step)" >&2; exit 1; }
  newer=$(find "${inputs[@]}" -type f -newer "$bin" 2>/dev/null | head -n 1)
  [ -z "$newer" ] || { echo "build.sh: $newer is newer than $bin: build again" >&2; exit 1; }
else
  cargo build --locked --release --bin afterimage
fi

mkdir -p "$out"
case $strip_mode in
  debug) strip --strip-debug -o "$out/afterimage" "$bin" ;;
  all) strip -o "$out/afterimage" "$bin" ;;
  none) cp "$bin" "$out/afterimage" ;;
  *) echo "build.sh: STRIP=$strip_mode: expected debug, all or none" >&2; exit 2 ;;
esac
chmod 0755 "$out/afterimage"
version=$("$out/afterimage" --version)
echo "build.sh: $out/afterimage: $version, $(($(stat -c %s "$out/afterimage") / 1000000)) MB (STRIP=$strip_mode)"
