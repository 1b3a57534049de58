#!/usr/bin/env python3
"""An example afterimage client in Python: the remote-renderer side of the gRPC contract.

It renders a small synthetic sequence with numpy (a moving HDR pattern with exact motion
vectors and depth, plus Monte-Carlo-like noise, and the clean image as a reference),
opens a session, streams the frames in chunks, decodes the filtered frames and prints
the server's per-frame figures.

    examples/python/run.sh --server 127.0.0.1:50051 --filter taa --frames 24

With --check it also verifies the contract end to end and exits non-zero on any failure
(CI runs it this way against a real `afterimage serve`):
  - the filter list is well formed and has the filter;
  - a `passthrough` session returns the sent colour bit for bit (this encoder and decoder
    agree with the server's);
  - the filter's replies arrive in order, finite, with PSNR, and beat passthrough's PSNR
    against the same reference by at least --min-gain dB over the second half;
  - a bad parameter gets INVALID_ARGUMENT naming it, and the server keeps serving;
  - a closed session is NOT_FOUND;
  - with --api-key, a call without the key is UNAUTHENTICATED.

Every call carries the routing key `x-afterimage-route` (`--route`, default random), which
a proxy in front of several replicas hashes on. A server with API keys takes `--api-key
KEY` (or AFTERIMAGE_API_KEY), sent as `authorization: Bearer KEY` metadata on every call; a server with TLS takes
`--tls-ca cert.pem` (the CA, or the self-signed certificate, to trust) and, when the
certificate's name is not the address's host, `--tls-domain NAME`.

The protocol itself (chunking, encoding, metadata, TLS) is the `afterimage-client` package's
(clients/python, installed into the example's venv by run.sh): this script is its user.
"""

import argparse
import os
import sys
import time

import grpc
import numpy as np

from afterimage_client import Client, Frame, RequestRejected, ServerUnavailable
from afterimage_client.proto import afterimage_pb2 as pb
from afterimage_client.proto import afterimage_pb2_grpc as pb_grpc


class CheckFailed(Exception):
    """A --check expectation did not hold."""


def expect(condition, message):
    if not condition:
        raise CheckFailed(message)


def render(width, height, frames, seed=1, speed=(1.25, 0.5), noise=0.15):
    """A pattern translating by `speed` pixels per frame. Yields dicts of float32 arrays in
    image layout (height x width x components) for color, depth, motion and reference.

    Motion follows the internal convention: from the current pixel to where it was in the
    previous frame, in pixels (so it is -speed everywhere)."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    for i in range(frames):
        # Scene coordinates of each pixel centre at frame i.
        u = xs - speed[0] * i
        v = ys - speed[1] * i
        base = 0.5 + 0.4 * np.sin(u * 0.23) * np.cos(v * 0.19)
        tint = 0.5 + 0.5 * np.sin(u * 0.071 + v * 0.053)
        # Smooth HDR highlights (peaks of about 8), so the reference needs no antialiasing
        # and what a filter can win is noise.
        glow = 7.0 * np.exp(-((np.sin(u * 0.045) * np.sin(v * 0.06)) - 1.0) ** 2 / 0.01)
        reference = np.stack([base * (0.6 + 0.8 * tint), base, base * (1.4 - 0.8 * tint)], axis=-1) + glow[..., None]
        # Drawn channel by channel (planes), as this example always has, so a seed gives the
        # same frames as before.
        color = reference * (1.0 + noise * rng.standard_normal((3, height, width)).transpose(1, 2, 0))
        color = np.maximum(color, 0.0)
        depth = 4.0 + 0.01 * v
        motion = np.stack([np.full_like(xs, -speed[0]), np.full_like(ys, -speed[1])], axis=-1)
        yield {
            "color": color.astype(np.float32),
            "depth": depth.astype(np.float32),
            "motion": motion.astype(np.float32),
            "reference": reference.astype(np.float32),
        }


def run_session(client, args, filter_name, params, frames, send):
    """Opens a session, streams `frames` (only the channels in `send`), returns the
    filtered frames, the session and the wall time."""
    session = client.create_session(filter_name, params=params, width=args.width, height=args.height,
                                    motion="internal", channels=[c for c in send if c != "reference"])
    start = time.perf_counter()
    out = list(session.stream([Frame(**{c: f[c] for c in send}) for f in frames], f16=args.f16, reply_f16=args.f16))
    wall = time.perf_counter() - start
    return session, out, wall


def mean(xs):
    return sum(xs) / len(xs) if xs else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--server", default="127.0.0.1:50051", help="gRPC address (host:port)")
    ap.add_argument("--filter", default="taa", help="filter name (see ListFilters)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="parameter override")
    ap.add_argument("--size", default="160x90", help="frame size WxH")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--f16", action="store_true", help="send and receive half floats")
    ap.add_argument("--check", action="store_true", help="verify the contract; exit 1 on any failure")
    ap.add_argument("--min-gain", type=float, default=1.0,
                    help="with --check: dB the filter must gain over passthrough")
    ap.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the server")
    ap.add_argument("--api-key", default=os.environ.get("AFTERIMAGE_API_KEY"),
                    help="API key of a server that has keys (default: $AFTERIMAGE_API_KEY)")
    ap.add_argument("--tls-ca", help="PEM file of the CA that signed the server's TLS certificate")
    ap.add_argument("--tls-domain", help="the name in the server's certificate, when not the host")
    ap.add_argument("--route", default=os.urandom(8).hex(),
                    help="routing key sent as x-afterimage-route on every call (default: random)")
    args = ap.parse_args()
    args.width, args.height = (int(x) for x in args.size.lower().split("x"))
    params = dict(kv.split("=", 1) for kv in args.set)

    try:
        client = Client(args.server, api_key=args.api_key, tls_ca=args.tls_ca, tls_domain=args.tls_domain,
                        route=args.route, wait=args.wait)
    except ServerUnavailable as e:
        print(e, file=sys.stderr)
        return 2

    filters = client.filters()
    print("server filters:", ", ".join(filters))
    if args.filter not in filters:
        print(f"unknown filter {args.filter!r}", file=sys.stderr)
        return 2
    info = filters[args.filter]
    send = ["color"] + [c for c in ("depth", "motion") if c in info.uses] + ["reference"]
    frames = list(render(args.width, args.height, args.frames))

    session, out, wall = run_session(client, args, args.filter, params, frames, send)
    print(f"session {session.id[:8]}...: {args.filter} {session.params}, "
          f"{args.width}x{args.height}, sending {', '.join(send)}")
    for o in out:
        r = o.figures
        stages = " ".join(f"{s.name}={s.ms:.2f}" if s.ms is not None else f"{s.name}=skipped"
                          for s in r.stages)
        print(f"  frame {o.index:3d}: server {r.server_ms:7.2f} ms, PSNR {r.psnr:6.2f} dB, "
              f"SSIM {r.ssim:.4f}, clipped {r.history_clipped:6d} | {stages}")
    half = out[len(out) // 2:]
    psnr = mean([o.figures.psnr for o in half])
    print(f"{len(out)} frames in {wall:.2f} s ({len(out) / wall:.1f} frames/s); "
          f"mean PSNR over the second half {psnr:.2f} dB")

    if not args.check:
        session.close()
        return 0

    try:
        for f in filters.values():
            expect(set(f.needs) <= set(f.uses) | {"color"}, f"{f.name}: needs {list(f.needs)} not within uses")
            expect(f.stages, f"{f.name}: no stages")
        expect([o.index for o in out] == list(range(args.frames)),
               f"replies out of order: {[o.index for o in out]}")
        expect(all(np.isfinite(o.color).all() for o in out), "a filtered frame has non-finite samples")
        expect(all(o.color.shape == (args.height, args.width, 3) for o in out), "a reply has the wrong size")

        _, passed, _ = run_session(client, args, "passthrough", {}, frames, ["color", "reference"])
        for o, f in zip(passed, frames):
            sent = f["color"].astype(np.float16).astype(np.float32) if args.f16 else f["color"]
            expect(np.array_equal(o.color, sent), f"passthrough frame {o.index} differs from what was sent")
        base = mean([o.figures.psnr for o in passed[len(passed) // 2:]])
        print(f"check: passthrough returned every frame bit for bit; its PSNR {base:.2f} dB, "
              f"{args.filter} {psnr:.2f} dB ({psnr - base:+.2f} dB)")
        expect(psnr >= base + args.min_gain,
               f"{args.filter} gains {psnr - base:.2f} dB over passthrough, expected at least {args.min_gain}")

        try:
            client.create_session(args.filter, params={"no_such_param": "1"}, width=args.width, height=args.height)
            raise CheckFailed("an unknown parameter was accepted")
        except RequestRejected as e:
            expect(e.code == grpc.StatusCode.INVALID_ARGUMENT, f"unknown parameter: got {e.code}")
            expect("no_such_param" in e.details, f"the message does not name the parameter: {e.details}")
            print(f"check: bad parameter -> {e.code.name}: {e.details}")
        got = session.refresh()
        expect(got.frames == args.frames, f"session counts {got.frames} frames, sent {args.frames}")
        closed = session.close()
        expect(closed == args.frames, f"close reports {closed} frames")
        try:
            session.refresh()
            raise CheckFailed("a closed session is still there")
        except RequestRejected as e:
            expect(e.code == grpc.StatusCode.NOT_FOUND, f"closed session: got {e.code}")
        if args.api_key:
            try:
                pb_grpc.AfterimageStub(client.raw_channel).ListFilters(pb.ListFiltersRequest())
                raise CheckFailed("a call without the API key was served")
            except grpc.RpcError as e:
                expect(e.code() == grpc.StatusCode.UNAUTHENTICATED, f"no key: got {e.code()}")
                print(f"check: no key -> {e.code().name}: {e.details()}")
        print("check: all passed")
        return 0
    except CheckFailed as e:
        print(f"check FAILED: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
