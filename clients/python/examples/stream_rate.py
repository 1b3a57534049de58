"""Frames per second through a server from Python: streams random taa frames (colour,
depth, motion) of the given size through one session and prints the rate from the first
reply to the last, and this process's CPU time per frame.

    python examples/stream_rate.py --server 127.0.0.1:50051 --size 1280x720 --frames 48

The frames are made before the clock starts, so the figures are the client library's
encoding, sending, receiving and decoding, and the server's filtering.
"""

import argparse
import time

import numpy as np

from afterimage_client import Client, Frame


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--server", required=True, help="HOST:PORT of `afterimage serve`'s gRPC")
    ap.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT (default 1280x720)")
    ap.add_argument("--frames", type=int, default=48, help="frames to stream (default 48)")
    ap.add_argument("--filter", default="taa")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    rng = np.random.default_rng(1)
    # Four distinct frames, sent in turn: the arrays are shared, not copied per frame.
    base = [
        (rng.random((h, w, 3), np.float32), rng.random((h, w), np.float32) + 1, rng.random((h, w, 2), np.float32) - 0.5)
        for _ in range(4)
    ]
    frames = []
    for i in range(args.frames):
        color, depth, motion = base[i % 4]
        frames.append(Frame(color=color, depth=depth, motion=motion, index=i))
    with Client(args.server) as client:
        with client.create_session(args.filter, width=w, height=h) as session:
            arrivals = []
            cpu = time.process_time()
            for _ in session.stream(frames):
                arrivals.append(time.perf_counter())
            cpu = time.process_time() - cpu
    n = len(arrivals)
    if n < 2:
        raise SystemExit("fewer than two replies: no rate")
    rate = (arrivals[-1] - arrivals[0]) / (n - 1) * 1e3
    print(
        f"{n} frames of {w}x{h} through {args.filter}: {rate:.1f} ms per frame ({1e3 / rate:.1f} frames/s) "
        f"from the first reply to the last; client CPU {cpu / n * 1e3:.1f} ms per frame"
    )


if __name__ == "__main__":
    main()
