"""The capacity model of deploy/README.md: sessions per replica and replicas for N streams,
per filter and resolution, from the binary's state sizes and the report's 1080p timings.

    python3 deploy/capacity.py [--binary target/release/afterimage] [--report docs/report/report.md]
        [--budget-mib 6144] [--cores 2] [--in-flight 1] [--streams 100] [--utilisation 0.8]
        [--max-sessions 64]

Prints the markdown table the README shows. Inputs and assumptions:

- state bytes/pixel: `afterimage filters --json` (state_bytes_per_pixel), plus, for a filter
  that holds frames back (pixel_trace: window/2 frames), the queued frames the server
  reserves, 2 x (lookahead + 1) x 12 B/px (crates/server/src/session/mod.rs). These are exactly the
  state_bytes a session reports when created (checked at 720p, 1080p and 4K).
- a frame in flight reserves wire + decoded + 2 x output bytes (crates/server/src/grpc.rs): wire
  4 B per component sent (f32; the filter's "uses" channels), decoded 4 B per component,
  output 12 B/px.
- ms/frame: the report's "Timing at 1920x1080" median, measured with 2 threads on the
  2-core machine; other sizes scaled by pixel count, other core counts linearly (both
  assumptions, not measured).
"""

import argparse
import json
import math
import re
import subprocess
from pathlib import Path

COMPONENTS = {'color': 3, 'depth': 1, 'motion': 2, 'motion_next': 2, 'normal': 3, 'object_id': 1,
              'albedo': 3}
SIZES = [('720p', 1280, 720), ('1080p', 1920, 1080), ('4K', 3840, 2160)]
P1080 = 1920 * 1080
MIB = 1 << 20


def report_ms(text):
    """Median ms/frame of each filter in the report's 1920x1080 timing tables."""
    ms = {}
    for table in re.split(r'^## ', text, flags=re.M):
        if not table.startswith('Timing at 1920x1080'):
            continue
        for line in table.splitlines():
            cells = [c.strip() for c in line.strip().strip('|').split('|')]
            if len(cells) > 2 and re.fullmatch(r'[\d.]+', cells[1]):
                name = cells[0].split(':')[0] if cells[0].endswith('spatiotemporal') else cells[0]
                if ':' not in name:
                    ms.setdefault(name, float(cells[1]))
    return ms


def lookahead(f):
    if f['name'] == 'pixel_trace':
        return int(f['defaults'].get('window', 16)) // 2
    return 0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--binary', default='target/release/afterimage')
    ap.add_argument('--report', default='docs/report/report.md')
    ap.add_argument('--budget-mib', type=int, default=6144)
    ap.add_argument('--cores', type=float, default=2)
    ap.add_argument('--in-flight', type=int, default=1)
    ap.add_argument('--streams', type=int, default=100)
    ap.add_argument('--utilisation', type=float, default=0.8)
    ap.add_argument('--max-sessions', type=int, default=64)
    a = ap.parse_args()
    filters = json.loads(subprocess.run([a.binary, 'filters', '--json'], capture_output=True, text=True,
                                        check=True).stdout)
    ms = report_ms(Path(a.report).read_text())
    budget = a.budget_mib * MIB
    cores = f'{a.cores:g}'
    print(f'| filter | size | state MiB | frame in flight MiB | sessions in {a.budget_mib} MiB | core-ms/frame '
          f'| cores per stream @30 fps | @60 fps | sessions per {cores}-core replica @30 | @60 '
          f'| replicas for {a.streams} streams @30 | @60 |')
    print('|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
    for f in filters:
        if f['name'] not in ms:
            continue
        comps = sum(COMPONENTS[c] for c in f['uses'])
        la = lookahead(f)
        state_bpp = f['state_bytes_per_pixel'] + (2 * (la + 1) * 12 if la else 0)
        frame_bpp = 4 * comps + 4 * comps + 2 * 12
        for label, w, h in SIZES:
            px = w * h
            state, frame = state_bpp * px, frame_bpp * px
            by_mem = min(a.max_sessions, budget // (state + a.in_flight * frame))
            core_ms = ms[f['name']] * 2 * px / P1080  # the report ran 2 threads on 2 cores
            row = [f['name'], label, f'{state / MIB:.0f}', f'{frame / MIB:.0f}', str(by_mem), f'{core_ms:.0f}']
            per_replica = []
            for rate in (30, 60):
                need = rate * core_ms / 1000
                row.append(f'{need:.2f}')
                fits = need <= a.cores
                per_replica.append(min(by_mem, math.floor(a.cores / need)) if fits else None)
            for s in per_replica:
                row.append('-' if s is None else str(s))
            for s in per_replica:
                row.append('-' if not s else str(math.ceil(a.streams / (s * a.utilisation)) + 1))
            print('| ' + ' | '.join(row) + ' |')


if __name__ == '__main__':
    main()
