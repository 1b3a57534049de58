#!/usr/bin/env bash
# The server as the pod runs it, without a container runtime (none runs on these machines):
# the binary, the rendered ConfigMap's config file, the Deployment's environment, UID 10001
# with no supplementary groups and no_new_privs, every mount read-only, in a network
# namespace of its own (so 0.0.0.0 is only that namespace's loopback). deploy/check.sh runs
#
#   deploy/check/smoke.sh BINARY RENDERED_DIR   (RENDERED_DIR: deploy/.out/prod, from manifests.py)
#
# and it checks: with the placeholder keys file the server refuses to start; with a key from
# `afterimage keygen` the Dockerfile's HEALTHCHECK command passes, /readyz and /metrics answer,
# the API wants the key, a session opens with x-afterimage-route; SIGTERM ends it with exit 0
# within the grace period less the preStop sleep. Needs root (unshare, mount, setpriv).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)

if [ "${1:-}" != --inside ]; then
  bin=$1 rendered=$2
  [ "$(id -u)" = 0 ] || { echo "smoke.sh: SKIPPED: needs root for unshare and setpriv"; exit 0; }
  unshare --net --mount --fork true 2>/dev/null ||
    { echo "smoke.sh: SKIPPED: this machine does not allow new network and mount namespaces"; exit 0; }
  for t in setpriv ip python3; do
    command -v $t >/dev/null || { echo "smoke.sh: SKIPPED: no $t"; exit 0; }
  done
  # A directory UID 10001 can read (the checkout may sit under a private home).
  d=$(mktemp -d)
  trap 'rm -rf "$d"' EXIT
  chmod 0755 "$d"
  mkdir "$d/run"
  cp "$bin" "$d/afterimage"
  cp "$rendered/config.toml" "$d/config.toml"
  # Keys files as the Secret volume has them: group 10001 (fsGroup), mode 0440.
  cp "$rendered/keys.toml" "$d/placeholder.toml"
  "$bin" keygen --name smoke >"$d/keygen.out"
  sed -n 2p "$d/keygen.out" | cut -c3- >"$d/secret"
  grep -v '^#' "$d/keygen.out" >"$d/keys.toml"
  chown root:10001 "$d/keys.toml" "$d/placeholder.toml"
  chmod 0440 "$d/keys.toml" "$d/placeholder.toml"
  chmod 0644 "$d/config.toml"
  # The HEALTHCHECK command, as the image would run it.
  python3 - "$here/../Dockerfile" >"$d/healthcheck.json" <<'PY'
import json, re, sys
text = open(sys.argv[1]).read().replace('\\\n', ' ')
m = re.search(r'^HEALTHCHECK\b.*?\bCMD\s+(\[.*\])\s*$', text, re.M)
print(json.dumps(json.loads(m.group(1))))
PY
  cp "$rendered/env" "$d/env"
  unshare --net --mount --fork "$0" --inside "$d"
  exit 0
fi

# ---- inside the namespaces -------------------------------------------------------------------
d=$2
ip link set lo up
for m in $(findmnt -rn -o TARGET | grep -vE '^/(proc|sys|dev)(/|$)'); do
  mount -o remount,bind,ro "$m" 2>/dev/null || true
done
mount -t tmpfs -o size=16m tmpfs "$d/run" # the harness's logs; the server gets no writable path
if touch "$d/probe" 2>/dev/null || touch /tmp/afterimage-smoke-probe 2>/dev/null; then
  echo "smoke.sh: the mounts did not turn read-only" >&2
  exit 1
fi
mapfile -t penv <"$d/env"
# The pod's environment (HOSTNAME: the pod's name, the replica name in NOT_FOUND answers), then
# its user: UID/GID 10001, no supplementary groups, no capabilities, no_new_privs.
pod_env=(env -i PATH=/usr/local/bin:/usr/bin:/bin HOSTNAME=afterimage-smoke-0 "${penv[@]}")
as_pod=(setpriv --reuid=10001 --regid=10001 --clear-groups --no-new-privs --inh-caps=-all --bounding-set=-all)
serve=("${as_pod[@]}" "$d/afterimage" serve --config "$d/config.toml")
http_port=$(sed -n 's/^AFTERIMAGE_HTTP_ADDR=.*://p' "$d/env")

# 1. Placeholder keys: the server refuses 0.0.0.0 and stops.
rc=0
timeout 10 "${pod_env[@]}" AFTERIMAGE_API_KEYS_FILE="$d/placeholder.toml" "${serve[@]}" \
  >"$d/run/placeholder.log" 2>&1 || rc=$?
if [ $rc = 0 ] || [ $rc = 124 ] || ! grep -q 'refusing to serve' "$d/run/placeholder.log"; then
  echo "smoke.sh: with the placeholder keys file the server should refuse to start (exit $rc):" >&2
  cat "$d/run/placeholder.log" >&2
  exit 1
fi
echo "smoke.sh: placeholder keys file: the server refuses to start (exit $rc, 'refusing to serve 0.0.0.0 ... without API keys')"

# 2. A real key: serve, probe, stop.
"${pod_env[@]}" AFTERIMAGE_API_KEYS_FILE="$d/keys.toml" "${serve[@]}" >"$d/run/server.log" 2>&1 &
server=$!
trap 'kill -KILL $server 2>/dev/null || true' EXIT
mapfile -t hc < <(python3 -c 'import json,sys; print("\n".join(json.load(open(sys.argv[1]))))' "$d/healthcheck.json")
healthy=0
for _ in $(seq 50); do
  if "${pod_env[@]}" "${as_pod[@]}" "${hc[@]}" 2>/dev/null; then
    healthy=1
    break
  fi
  kill -0 $server 2>/dev/null || break
  sleep 0.1
done
if [ $healthy = 0 ]; then
  echo "smoke.sh: the Dockerfile's HEALTHCHECK never passed; server log:" >&2
  cat "$d/run/server.log" >&2
  exit 1
fi
uid=$(awk '/^Uid:/ {print $2}' "/proc/$server/status" 2>/dev/null || echo '?')
python3 - "$http_port" "$(cat "$d/secret")" <<'PY'
import json, sys, urllib.request, urllib.error
port, key = sys.argv[1], sys.argv[2]
base = f'http://127.0.0.1:{port}'
def call(method, path, body=None, auth=True, route=None):
    req = urllib.request.Request(base + path, method=method,
                                 data=json.dumps(body).encode() if body is not None else None)
    if auth:
        req.add_header('Authorization', f'Bearer {key}')
    if route:
        req.add_header('x-afterimage-route', route)
    if body is not None:
        req.add_header('Content-Type', 'application/json')
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()
checks = [
    ('GET /readyz', call('GET', '/readyz', auth=False), 200),
    ('GET /metrics without a key (metrics_require_key = false)', call('GET', '/metrics', auth=False), 200),
    ('GET /v1/filters without a key', call('GET', '/v1/filters', auth=False), 401),
    ('GET /v1/filters with the key', call('GET', '/v1/filters'), 200),
    ('POST /v1/sessions with x-afterimage-route',
     call('POST', '/v1/sessions', {'filter': 'taa', 'width': 64, 'height': 36}, route='smoke-1'), 201),
    ('GET /v1/sessions/<unknown id>', call('GET', '/v1/sessions/0123456789abcdef0123456789abcdef', route='smoke-2'), 404),
]
bad = [f'{what}: {got[0]}, expected {want} ({got[1][:200]})' for what, got, want in checks if got[0] != want]
if bad:
    sys.exit('smoke.sh: ' + '\n'.join(bad))
print('smoke.sh: ' + '; '.join(f'{what.split(" (")[0]} -> {want}' for what, _, want in checks))
print('smoke.sh: the 404 body: ' + checks[-1][1][1].strip()[:300])
PY
# SIGTERM, as the kubelet sends after the preStop sleep: exit 0 well within the grace left.
kill -TERM $server
rc=0
t0=$(date +%s%N)
timeout 25 tail --pid=$server -f /dev/null || { echo "smoke.sh: no exit within 25 s of SIGTERM" >&2; exit 1; }
wait $server || rc=$?
ms=$((($(date +%s%N) - t0) / 1000000))
trap - EXIT
if [ $rc != 0 ]; then
  echo "smoke.sh: the server exited $rc after SIGTERM; log:" >&2
  cat "$d/run/server.log" >&2
  exit 1
fi
echo "smoke.sh: UID $uid, read-only mounts, own network namespace; SIGTERM -> exit 0 in $ms ms"
