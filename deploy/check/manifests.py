"""Validates the rendered kustomize overlays (deploy/check.sh runs this).

    python manifests.py OUT_DIR [--binary PATH] OVERLAY...

reads OUT_DIR/OVERLAY.yaml (`kubectl kustomize deploy/k8s/overlays/OVERLAY`) and checks:

1. Kubernetes kinds against the Kubernetes OpenAPI schemas of kubernetes-validate, strict
   (unknown fields fail), for each version in K8S_VERSIONS (oldest supported, newest).
2. Gateway API, Prometheus Operator and Envoy Gateway kinds against the strict subset
   schemas in deploy/check/schemas (the upstream schemas of the first two are checked by
   validate.mjs as well).
3. That the objects fit together: selectors, port names and numbers, route parents and
   backends, the policy's targets and hash header, the probes, the config file and the
   keys file where the Deployment mounts them, the grace period against the drain
   deadline, the memory limit against the memory budget, the security context.
4. The config file with the server's own loader (`afterimage serve --config ...
   --print-config`, the Deployment's environment applied) when --binary is given.

It writes OUT_DIR/OVERLAY.json (the documents, for validate.mjs) and OUT_DIR/OVERLAY/
(config.toml, keys.toml and env of the Deployment, for smoke.sh).
"""

import base64
import json
import math
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import jsonschema
import kubernetes_validate
import yaml
from referencing import Registry, Resource

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
K8S_VERSIONS = os.environ.get('K8S_VERSIONS', '1.30.0 1.37.0').split()
ROUTE_HEADER = 'x-afterimage-route'
# Container memory limit over the server's memory budget: the process's own memory beyond
# what it reserves (measured 1.09-1.22x at 1080p, deploy/README.md) plus margin.
MEMORY_HEADROOM = 1.25
CORE = {'Namespace', 'ConfigMap', 'Secret', 'Service', 'Deployment', 'PodDisruptionBudget'}
CUSTOM = {'Gateway', 'HTTPRoute', 'GRPCRoute', 'ServiceMonitor', 'BackendTrafficPolicy'}

errors = []


def fail(where, msg):
    errors.append(f'{where}: {msg}')


def subset_validators():
    resources = {}
    for f in sorted((HERE / 'schemas').glob('*.yaml')):
        schema = yaml.safe_load(f.read_text())
        schema.setdefault('$schema', 'https://json-schema.org/draft/2020-12/schema')
        resources[f.name] = Resource.from_contents(schema)
    registry = Registry().with_resources(resources.items())
    return {kind: jsonschema.Draft202012Validator(resources[f'{kind}.yaml'].contents, registry=registry)
            for kind in CUSTOM}


def quantity_bytes(q):
    m = re.fullmatch(r'(\d+(?:\.\d+)?)(Ki|Mi|Gi|Ti|k|M|G|T)?', str(q))
    if not m:
        raise ValueError(f'memory quantity {q!r}')
    mult = {None: 1, 'Ki': 1 << 10, 'Mi': 1 << 20, 'Gi': 1 << 30, 'Ti': 1 << 40,
            'k': 10**3, 'M': 10**6, 'G': 10**9, 'T': 10**12}[m.group(2)]
    return float(m.group(1)) * mult


def cpu_cores(q):
    q = str(q)
    return float(q[:-1]) / 1000 if q.endswith('m') else float(q)


def matches(selector, labels):
    return all(labels.get(k) == v for k, v in (selector or {}).items())


def port_of(addr):
    return int(addr.rsplit(':', 1)[1])


def effective_config(where, cfg_path, env, binary):
    """The config the server would run with: its own loader when there is a binary."""
    if binary:
        run_env = {k: v for k, v in os.environ.items() if not k.startswith('AFTERIMAGE_')}
        run_env.update(env)
        p = subprocess.run([binary, 'serve', '--config', str(cfg_path), '--print-config'],
                           capture_output=True, text=True, env=run_env)
        if p.returncode != 0:
            fail(where, f'the server rejects the config file: {p.stderr.strip()}')
            return None
        return tomllib.loads(p.stdout)
    cfg = tomllib.loads(cfg_path.read_text())
    for k, v in env.items():  # the server's layering, for the fields checked here
        field = k.removeprefix('AFTERIMAGE_').lower()
        if k.startswith('AFTERIMAGE_') and field in ('memory_budget_mib', 'shutdown_deadline_s'):
            cfg[field] = int(v)
        elif k.startswith('AFTERIMAGE_') and field in ('grpc_addr', 'http_addr', 'api_keys_file'):
            cfg[field] = v
    cfg.setdefault('shutdown_deadline_s', 10)
    cfg.setdefault('memory_budget_mib', 8192)
    return cfg


def check_overlay(out, name, validators, binary):
    src = out / f'{name}.yaml'
    docs = [d for d in yaml.safe_load_all(src.read_text()) if d]
    (out / f'{name}.json').write_text(json.dumps(docs))
    by_kind = {}
    for d in docs:
        by_kind.setdefault(d['kind'], []).append(d)
    kinds = set(by_kind)
    if kinds != CORE | CUSTOM:
        fail(name, f'kinds {sorted(kinds)}; expected {sorted(CORE | CUSTOM)} (a new kind needs a validator here)')

    # 1 and 2: schemas.
    for d in docs:
        where = f'{name}: {d["kind"]}/{d.get("metadata", {}).get("name")}'
        if d['kind'] in CORE:
            for v in K8S_VERSIONS:
                try:
                    kubernetes_validate.validate(d, v, strict=True)
                except Exception as e:  # ValidationError, SchemaNotFoundError
                    fail(where, f'Kubernetes {v} schema: {str(e).splitlines()[0]}')
        elif d['kind'] in CUSTOM:
            for e in validators[d['kind']].iter_errors(d):
                fail(where, f'schema: /{"/".join(map(str, e.absolute_path))}: {e.message}')

    one = {k: v[0] for k, v in by_kind.items()}
    if any(len(v) > 1 for k, v in by_kind.items() if k != 'Namespace'):
        fail(name, 'more than one object of a kind: the checks below assume one')
    dep, svc = one.get('Deployment'), one.get('Service')
    if not dep or not svc:
        return
    ns = one['Namespace']['metadata']['name']
    for d in docs:
        if d['kind'] != 'Namespace' and d['metadata'].get('namespace') != ns:
            fail(name, f'{d["kind"]}/{d["metadata"]["name"]} is not in namespace {ns}')
    if one['Namespace']['metadata'].get('labels', {}).get('pod-security.kubernetes.io/enforce') != 'restricted':
        fail(name, f'namespace {ns} does not enforce the restricted Pod Security Standard')

    # 3. Deployment, pod, container.
    spec, pod = dep['spec'], dep['spec']['template']['spec']
    pod_labels = dep['spec']['template']['metadata']['labels']
    if not matches(spec['selector']['matchLabels'], pod_labels):
        fail(name, 'the Deployment selector does not match its pod labels')
    (c,) = pod['containers']
    if c['image'] == 'afterimage' or ':' not in c['image'].rsplit('/', 1)[-1]:
        fail(name, f'image {c["image"]!r} has no tag: pin it in the overlay (images:)')
    sc, csc = pod.get('securityContext', {}), c.get('securityContext', {})
    if not (sc.get('runAsNonRoot') and isinstance(sc.get('runAsUser'), int) and sc['runAsUser'] > 0):
        fail(name, 'the pod must run as a numeric non-root user (runAsNonRoot, runAsUser)')
    if sc.get('seccompProfile', {}).get('type') != 'RuntimeDefault':
        fail(name, 'seccompProfile is not RuntimeDefault')
    if not csc.get('readOnlyRootFilesystem') or csc.get('allowPrivilegeEscalation') is not False \
            or csc.get('capabilities', {}).get('drop') != ['ALL']:
        fail(name, 'the container needs readOnlyRootFilesystem, allowPrivilegeEscalation false, drop ALL')
    if pod.get('enableServiceLinks') is not False:
        fail(name, 'enableServiceLinks must be false: Service variables of a Service named afterimage '
                   'start with AFTERIMAGE_, the server config prefix')
    ports = {p['name']: p['containerPort'] for p in c['ports']}
    if set(ports) != {'grpc', 'http'}:
        fail(name, f'container ports {sorted(ports)}; expected grpc and http')
    for probe, path in (('readinessProbe', '/readyz'), ('livenessProbe', '/healthz')):
        g = c.get(probe, {}).get('httpGet', {})
        if g.get('path') != path or g.get('port') != 'http':
            fail(name, f'{probe} must GET {path} on the http port, not {g}')

    # Environment, as the container gets it.
    limits = c['resources']['limits']
    env = {}
    for e in c.get('env', []):
        if 'value' in e:
            env[e['name']] = e['value']
        elif e.get('valueFrom', {}).get('resourceFieldRef', {}).get('resource') == 'limits.cpu':
            env[e['name']] = str(math.ceil(cpu_cores(limits['cpu'])))
    if env.get('AFTERIMAGE_THREADS') != str(math.ceil(cpu_cores(limits['cpu']))):
        fail(name, 'AFTERIMAGE_THREADS should follow the CPU limit (resourceFieldRef limits.cpu)')

    # Config file and keys file, where the Deployment mounts them.
    mounts = {m['name']: m for m in c.get('volumeMounts', [])}
    vols = {v['name']: v for v in pod.get('volumes', [])}
    args = c.get('args', [])
    cfg_path = args[args.index('--config') + 1] if '--config' in args else None
    cm_name = vols.get('config', {}).get('configMap', {}).get('name')
    sec_name = vols.get('api-keys', {}).get('secret', {}).get('secretName')
    cm, sec = one.get('ConfigMap'), one.get('Secret')
    if not cm or cm['metadata']['name'] != cm_name:
        fail(name, f'volume config names ConfigMap {cm_name}, which the render lacks')
        return
    if not sec or sec['metadata']['name'] != sec_name:
        fail(name, f'volume api-keys names Secret {sec_name}, which the render lacks')
        return
    m = mounts.get('config', {})
    if not cfg_path or m.get('mountPath') != cfg_path or m.get('subPath') not in cm['data']:
        fail(name, f'--config {cfg_path} is not the mounted ConfigMap file {m}')
        return
    work = out / name
    work.mkdir(exist_ok=True)
    (work / 'config.toml').write_text(cm['data'][m['subPath']])
    keys = {k: base64.b64decode(v).decode() for k, v in sec.get('data', {}).items()}
    keys.update(sec.get('stringData', {}))
    for k, v in keys.items():
        if re.search(r'aik_[0-9a-f]{16,}', v):
            fail(name, f'Secret {sec_name} key {k} holds a client secret (aik_...): only [[key]] hashes belong there')
    (work / 'keys.toml').write_text(next(iter(keys.values()), ''))
    (work / 'env').write_text(''.join(f'{k}={v}\n' for k, v in sorted(env.items())))
    cfg = effective_config(name, work / 'config.toml', env, binary)
    if cfg is None:
        return
    keys_file = cfg.get('api_keys_file', '')
    km = mounts.get('api-keys', {}).get('mountPath', '')
    if not keys_file or os.path.dirname(keys_file) != km or os.path.basename(keys_file) not in keys:
        fail(name, f'api_keys_file {keys_file!r} is not a key of Secret {sec_name} mounted at {km!r}')
    if cfg.get('allow_unauthenticated'):
        fail(name, 'allow_unauthenticated is true: every pod would serve without API keys')
    for field, port in (('grpc_addr', 'grpc'), ('http_addr', 'http')):
        addr = cfg.get(field, '')
        if not addr.startswith('0.0.0.0:') or port_of(addr) != ports.get(port):
            fail(name, f'{field} {addr!r} is not 0.0.0.0 on container port {port} ({ports.get(port)})')
    sleep = c.get('lifecycle', {}).get('preStop', {}).get('sleep', {}).get('seconds', 0)
    grace = pod.get('terminationGracePeriodSeconds', 30)
    deadline = cfg['shutdown_deadline_s']
    if grace < sleep + deadline + 5:
        fail(name, f'terminationGracePeriodSeconds {grace} < preStop sleep {sleep} + shutdown_deadline_s '
                   f'{deadline} + 5: the kubelet would kill a draining server')
    budget = cfg['memory_budget_mib'] << 20
    limit = quantity_bytes(limits['memory'])
    if limit < budget * MEMORY_HEADROOM or quantity_bytes(c['resources']['requests']['memory']) != limit:
        fail(name, f'memory limit {limits["memory"]} must equal the request and be at least '
                   f'{MEMORY_HEADROOM} x the memory budget ({cfg["memory_budget_mib"]} MiB)')

    # Service, PDB, ServiceMonitor.
    if not matches(svc['spec']['selector'], pod_labels):
        fail(name, 'the Service selector does not match the pods')
    sports = {p['name']: p for p in svc['spec']['ports']}
    for pname in ('grpc', 'http'):
        p = sports.get(pname)
        if not p or p.get('targetPort') not in (pname, ports.get(pname)):
            fail(name, f'Service port {pname} does not target the container port {pname}')
    if sports.get('grpc', {}).get('appProtocol') != 'kubernetes.io/h2c':
        fail(name, 'Service port grpc needs appProtocol kubernetes.io/h2c (Envoy speaks HTTP/2 to it)')
    if not matches(one['PodDisruptionBudget']['spec']['selector']['matchLabels'], pod_labels):
        fail(name, 'the PodDisruptionBudget selector does not match the pods')
    sm = one['ServiceMonitor']['spec']
    if not matches(sm['selector'].get('matchLabels'), svc['metadata'].get('labels', {})):
        fail(name, 'the ServiceMonitor selector does not match the Service labels')
    for ep in sm['endpoints']:
        if ep['port'] not in sports or ep.get('path', '/metrics') != '/metrics':
            fail(name, f'ServiceMonitor endpoint {ep} is not the Service http port /metrics')
        if cfg.get('metrics_require_key') and 'authorization' not in ep:
            fail(name, 'metrics_require_key is true but the ServiceMonitor sends no authorization')

    # Gateway, routes, policy.
    gw = one['Gateway']
    listeners = {lst['name']: lst for lst in gw['spec']['listeners']}
    proto = (ROOT / 'crates/client/proto/afterimage/v1/afterimage.proto').read_text()
    service = '%s.%s' % (re.search(r'^package\s+([\w.]+);', proto, re.M).group(1),
                         re.search(r'^service\s+(\w+)', proto, re.M).group(1))
    for kind, pname in (('GRPCRoute', 'grpc'), ('HTTPRoute', 'http')):
        r = one[kind]
        for ref in r['spec']['parentRefs']:
            lst = listeners.get(ref.get('sectionName'))
            if ref['name'] != gw['metadata']['name'] or not lst:
                fail(name, f'{kind} parent {ref} is not a listener of Gateway {gw["metadata"]["name"]}')
            elif kind not in [k['kind'] for k in lst.get('allowedRoutes', {}).get('kinds', [])]:
                fail(name, f'{kind} attaches to listener {lst["name"]}, which does not admit {kind}')
        for rule in r['spec']['rules']:
            for b in rule['backendRefs']:
                if b['name'] != svc['metadata']['name'] or b['port'] != sports.get(pname, {}).get('port'):
                    fail(name, f'{kind} backend {b} is not Service {svc["metadata"]["name"]} port {pname}')
    methods = [m.get('method', {}) for rule in one['GRPCRoute']['spec']['rules'] for m in rule.get('matches', [])]
    if methods and not any(m.get('service') == service for m in methods):
        fail(name, f'GRPCRoute matches {methods}, not the proto service {service}')
    btp = one['BackendTrafficPolicy']['spec']
    targets = {(t['kind'], t['name']) for t in btp['targetRefs']}
    for kind in ('GRPCRoute', 'HTTPRoute'):
        if (kind, one[kind]['metadata']['name']) not in targets:
            fail(name, f'the BackendTrafficPolicy does not target the {kind}: its requests would not be hashed')
    ch = btp.get('loadBalancer', {}).get('consistentHash', {})
    hashed = [h['name'].lower() for h in ch.get('headers', [])] + \
        ([ch['header']['name'].lower()] if 'header' in ch else [])
    if btp.get('loadBalancer', {}).get('type') != 'ConsistentHash' or hashed != [ROUTE_HEADER]:
        fail(name, f'the BackendTrafficPolicy must hash on {ROUTE_HEADER} alone, not {hashed}')
    if btp.get('timeout', {}).get('http', {}).get('requestTimeout') != '0s':
        fail(name, 'the BackendTrafficPolicy must set timeout.http.requestTimeout 0s: Envoy\'s default '
                   '15 s route timeout would cut every gRPC Stream')

    print(f'{name}: {len(docs)} objects; {dep["spec"].get("replicas")} replicas of {c["image"]}, '
          f'{limits["cpu"]} CPU / {limits["memory"]}, budget {cfg["memory_budget_mib"]} MiB, '
          f'grace {grace} s >= preStop {sleep} s + drain {deadline} s'
          + (' (config checked by the server\'s loader)' if binary else ''))


def main():
    args = sys.argv[1:]
    binary = None
    if '--binary' in args:
        i = args.index('--binary')
        binary = args[i + 1]
        del args[i:i + 2]
    out, overlays = Path(args[0]), args[1:]
    validators = subset_validators()
    for f in sorted((ROOT / 'deploy/k8s').rglob('*')):
        if f.is_file() and re.search(r'aik_[0-9a-f]{16,}', f.read_text()):
            fail(str(f.relative_to(ROOT)), 'holds a client secret (aik_...)')
    for name in overlays:
        check_overlay(out, name, validators, binary)
    if errors:
        print('\n'.join('manifests.py: ' + e for e in errors), file=sys.stderr)
        sys.exit(1)
    print(f'manifests.py: {len(overlays)} overlays pass: Kubernetes {", ".join(K8S_VERSIONS)} schemas '
          f'(strict), the subset schemas of {", ".join(sorted(CUSTOM))}, and the cross-checks')


if __name__ == '__main__':
    main()
