"""The checks of manifests.py catch the mistakes they are there for (deploy/check.sh runs
this after manifests.py passed): each case breaks one thing in a copy of a rendered overlay
and expects manifests.py to fail naming it.

    python selftest.py OUT_DIR OVERLAY [--binary PATH]

OVERLAY is prod (the memory case assumes its 6 GiB budget); without --binary the case of an
unknown config field is left out (only the server's loader knows the fields).
"""

import contextlib
import copy
import io
import sys
import tempfile
from pathlib import Path

import yaml

import manifests


def find(docs, kind):
    return next(d for d in docs if d['kind'] == kind)


def container(docs):
    return find(docs, 'Deployment')['spec']['template']['spec']['containers'][0]


def pod(docs):
    return find(docs, 'Deployment')['spec']['template']['spec']


# (what is broken, how, a piece of the message expected)
CASES = [
    ('a misspelt Deployment field',
     lambda d: container(d).__setitem__('readinesProbe', container(d).pop('readinessProbe')),
     "'readinesProbe' was unexpected"),
    ('a misspelt BackendTrafficPolicy field',
     lambda d: find(d, 'BackendTrafficPolicy')['spec']['loadBalancer'].__setitem__(
         'consistenHash', find(d, 'BackendTrafficPolicy')['spec']['loadBalancer'].pop('consistentHash')),
     'consistenHash'),
    ('hashing on another header',
     lambda d: find(d, 'BackendTrafficPolicy')['spec']['loadBalancer']['consistentHash'].__setitem__(
         'headers', [{'name': 'x-session'}]),
     'must hash on x-afterimage-route'),
    ('type Header without header',
     lambda d: find(d, 'BackendTrafficPolicy')['spec']['loadBalancer']['consistentHash'].__setitem__(
         'type', 'Header'),
     "'header' is a required property"),
    ('the policy not targeting the GRPCRoute',
     lambda d: find(d, 'BackendTrafficPolicy')['spec']['targetRefs'].pop(0),
     'does not target the GRPCRoute'),
    ("Envoy's 15 s route timeout left on",
     lambda d: find(d, 'BackendTrafficPolicy')['spec'].pop('timeout'),
     'requestTimeout 0s'),
    ('a grace period shorter than the drain',
     lambda d: pod(d).__setitem__('terminationGracePeriodSeconds', 12),
     'terminationGracePeriodSeconds 12'),
    ('a memory limit below the budget',
     lambda d: [container(d)['resources'][k].__setitem__('memory', '6Gi') for k in ('limits', 'requests')],
     'memory limit 6Gi'),
    ('a route backend on the wrong port',
     lambda d: find(d, 'HTTPRoute')['spec']['rules'][0]['backendRefs'][0].__setitem__('port', 50051),
     'HTTPRoute backend'),
    ('a route on a listener that does not admit it',
     lambda d: find(d, 'GRPCRoute')['spec']['parentRefs'][0].__setitem__('sectionName', 'http'),
     'does not admit GRPCRoute'),
    ('the gRPC port without h2c',
     lambda d: find(d, 'Service')['spec']['ports'][0].pop('appProtocol'),
     'appProtocol kubernetes.io/h2c'),
    ('a Service selector that misses the pods',
     lambda d: find(d, 'Service')['spec']['selector'].__setitem__('app.kubernetes.io/name', 'other'),
     'Service selector'),
    ('the keys file mounted elsewhere',
     lambda d: container(d)['volumeMounts'][1].__setitem__('mountPath', '/keys'),
     'api_keys_file'),
    ('root allowed',
     lambda d: pod(d)['securityContext'].pop('runAsNonRoot'),
     'numeric non-root user'),
    ('a writable root filesystem',
     lambda d: container(d)['securityContext'].__setitem__('readOnlyRootFilesystem', False),
     'readOnlyRootFilesystem'),
    ('an unknown field in the config file',
     lambda d: find(d, 'ConfigMap')['data'].__setitem__(
         'config.toml', find(d, 'ConfigMap')['data']['config.toml'] + '\nmax_sesions = 3\n'),
     'max_sesions'),
    ('a ServiceMonitor interval Prometheus cannot read',
     lambda d: find(d, 'ServiceMonitor')['spec']['endpoints'][0].__setitem__('interval', '30 s'),
     'interval'),
    ('an HTTPS listener without tls',
     lambda d: find(d, 'Gateway')['spec']['listeners'][0].__setitem__('protocol', 'HTTPS')
     if 'tls' not in find(d, 'Gateway')['spec']['listeners'][0]
     else find(d, 'Gateway')['spec']['listeners'][0].pop('tls'),
     "'tls' is a required property"),
]


def main():
    out, overlay = Path(sys.argv[1]), sys.argv[2]
    binary = sys.argv[sys.argv.index('--binary') + 1] if '--binary' in sys.argv else None
    base = [d for d in yaml.safe_load_all((out / f'{overlay}.yaml').read_text()) if d]
    validators = manifests.subset_validators()
    failed = ran = 0
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()):
        for what, breaks, expect in CASES:
            if what.startswith('an unknown field in the config') and not binary:
                continue  # only the server's loader knows its fields
            ran += 1
            docs = copy.deepcopy(base)
            breaks(docs)
            (Path(tmp) / 'case.yaml').write_text(yaml.safe_dump_all(docs))
            manifests.errors.clear()
            manifests.check_overlay(Path(tmp), 'case', validators, binary)
            if not any(expect in e for e in manifests.errors):
                failed += 1
                print(f'selftest.py: NOT CAUGHT: {what} (wanted "{expect}"; got {manifests.errors})',
                      file=sys.stderr)
    if failed:
        sys.exit(1)
    print(f'selftest.py: manifests.py catches all {ran} broken copies of {overlay}')


if __name__ == '__main__':
    main()
