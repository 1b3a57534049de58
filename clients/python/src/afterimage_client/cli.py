"""``python -m afterimage_client``: commands over a running afterimage server."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import List, Optional, Sequence

import numpy as np

from . import __version__
from .client import AfterimageError, Client, FilteredFrame
from .exr import PRESET_CHOICES, ExrError, find_frames, read_frame, write_filtered


def _param(text: str) -> tuple:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"{text!r} is not KEY=VALUE (e.g. alpha=0.05)")
    k, v = text.split("=", 1)
    if not k.strip():
        raise argparse.ArgumentTypeError(f"{text!r} has no key")
    return k.strip(), v.strip()


def _channels(text: str) -> List[str]:
    return [c.strip() for c in text.split(",") if c.strip()]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m afterimage_client",
        description="Client of an afterimage server (temporal anti-aliasing over gRPC).",
    )
    ap.add_argument("--version", action="version", version=f"afterimage-client {__version__}")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    conn = argparse.ArgumentParser(add_help=False)
    g = conn.add_argument_group("connection")
    g.add_argument("--server", required=True, metavar="HOST:PORT", help="the server's gRPC address (AFTERIMAGE_GRPC_ADDR of `afterimage serve`)")
    g.add_argument("--api-key", default=os.environ.get("AFTERIMAGE_API_KEY"), metavar="KEY",
                   help="API key of a server that has keys, sent as `authorization: Bearer KEY` (default: $AFTERIMAGE_API_KEY)")
    g.add_argument("--tls-ca", metavar="PEM", help="connect with TLS, trusting this CA (or self-signed) certificate")
    g.add_argument("--tls-domain", metavar="NAME", help="with --tls-ca: the name in the server's certificate, when not the address's host")
    g.add_argument("--wait", type=float, default=10.0, metavar="SECONDS", help="how long to wait for the server to answer (default: 10)")

    f = sub.add_parser(
        "filter",
        parents=[conn],
        help="stream a directory of EXR frames through a filter and write the filtered EXRs",
        description=(
            "Streams the EXR frames of a directory (in frame-number order, one session, one stream) "
            "through FILTER on the server and writes each filtered frame under its input's file name "
            "in the output directory: every channel and attribute of the input kept, the colour "
            "replaced (as `afterimage filter --keep all`), plus the per-frame record in the "
            "`afterimage.record` attribute and records.json (a list, with PSNR and SSIM when the frames have "
            "a reference channel). Channels are mapped by the presets of "
            "`afterimage filter` (see the package README); only those the filter uses are sent."
        ),
    )
    f.add_argument("--filter", required=True, metavar="NAME", help="the filter (taa, phlm, ...; `python -m afterimage_client filters` lists them)")
    f.add_argument("--preset", default="auto", choices=PRESET_CHOICES, help="channel-name preset of the files (default: auto, detected from the first frame)")
    f.add_argument("--param", "--set", action="append", default=[], type=_param, metavar="KEY=VALUE", dest="params",
                   help="a filter parameter (--param alpha=0.05); repeatable")
    f.add_argument("-i", "--input", required=True, metavar="DIR", help="directory of EXR frames, numbered (frame_0001.exr, ...) without gaps")
    f.add_argument("-o", "--output", required=True, metavar="DIR", help="directory for the filtered EXRs (created; existing files of the same names are replaced)")
    f.add_argument("--require", type=_channels, default=[], metavar="CHANNEL[,CHANNEL]",
                   help="channels every frame must have (--require motion,depth): a missing one is an error instead of the stages that read it being left out")
    f.add_argument("--backend", default="", choices=["", "cpu", "gpu", "auto", "gpu-f16", "auto-f16"], metavar="BACKEND",
                   help="where the filter runs on the server: cpu, gpu, auto, gpu-f16, auto-f16 (default: the server's default)")
    f.add_argument("--f16", action="store_true", help="send and receive half floats (half the bytes; the colour is then rounded to 11 bits and no longer the same as `afterimage filter`'s)")
    f.add_argument("--records", metavar="FILE", help="where to write the per-frame records as JSON (default: records.json in the output directory)")
    f.add_argument("-q", "--quiet", action="store_true", help="no per-frame progress lines, only the summary")

    sub.add_parser("filters", parents=[conn], help="list the server's filters with the channels they use and their parameters")
    return ap


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def cmd_filters(args, client: Client) -> int:
    for f in client.filters().values():
        print(f"{f.name}: {f.summary}")
        print(f"  needs {', '.join(f.needs)}; uses {', '.join(f.uses)}")
        for p in f.params.values():
            bounds = ""
            if p.HasField("min") or p.HasField("max"):
                bounds = f" [{p.min if p.HasField('min') else ''}..{p.max if p.HasField('max') else ''}]"
            choices = f" {{{', '.join(p.choices)}}}" if p.choices else ""
            print(f"  --param {p.name}={p.default_json} ({p.kind}{bounds}{choices}) {p.doc}")
    return 0


def cmd_filter(args, client: Client, frames) -> int:
    filters = client.filters()
    if args.filter not in filters:
        raise AfterimageError(f"the server at {args.server} has no filter {args.filter!r}; it has: {', '.join(filters)}")
    info = filters[args.filter]

    first, first_image, preset = read_frame(frames[0][1], args.preset, args.require, frames[0][0])
    width, height = first.size
    present = list(first.channels())
    send = [c for c in present if c in info.uses or c == "color"]
    missing_needed = [c for c in info.needs if c not in present]
    if missing_needed:
        raise AfterimageError(
            f"{frames[0][1]}: {args.filter} needs {', '.join(missing_needed)}, which preset {preset} "
            f"finds no pass for (it reads: {', '.join(present)})"
        )
    os.makedirs(args.output, exist_ok=True)
    params = dict(args.params)
    session = client.create_session(args.filter, width=width, height=height, params=params, channels=send,
                                    motion="internal", backend=args.backend)
    if not args.quiet:
        _log(f"{len(frames)} frames of {width}x{height} from {args.input} (preset {preset}); "
             f"session {session.id[:8]} on {args.server}: {args.filter} {json.dumps(session.params, sort_keys=True)}, "
             f"backend {session.info.backend}, sending {', '.join(send)}")

    images = {}

    def source():
        for n, path in frames:
            if n == frames[0][0]:
                frame, image = first, first_image
            else:
                frame, image, _ = read_frame(path, preset, args.require, n)
                if frame.size != (width, height):
                    raise ExrError(f"{path}: {frame.size[0]}x{frame.size[1]}, the shot's first frame {frames[0][1]} is {width}x{height}")
                lacking = [c for c in send if getattr(frame, c) is None]
                if lacking:
                    names = ", ".join(n for c in lacking for n in preset.names(c) or [])
                    raise ExrError(f"{path}: no {names} ({', '.join(lacking)}, which {frames[0][1]} had and the session was created with); the file has: {', '.join(sorted(image.channels))}")
            for c in list(frame.channels()):
                if c not in send and c != "reference":  # a reference gets PSNR/SSIM in the records
                    setattr(frame, c, None)
            images[n] = (path, image)
            yield frame

    records = []
    start = time.perf_counter()
    done = 0
    try:
        with session:
            for out in session.stream(source(), f16=args.f16, reply_f16=args.f16):
                path, image = images.pop(out.index)
                dest = os.path.join(args.output, os.path.basename(path))
                record = dict(out.figures.record)
                if out.figures.psnr is not None:  # the frame carried a reference
                    record["psnr"], record["ssim"] = out.figures.psnr, out.figures.ssim
                write_filtered(image, out.color, dest, preset, {"afterimage.record": json.dumps(record, separators=(",", ":"))})
                records.append(record)
                done += 1
                if not args.quiet:
                    _log(_progress(out, done, len(frames), dest))
    finally:
        if records:
            rec_path = args.records or os.path.join(args.output, "records.json")
            with open(rec_path, "w") as fh:
                json.dump(records, fh, indent=1)
    wall = time.perf_counter() - start
    if done != len(frames):
        raise AfterimageError(f"{len(frames)} frames sent, {done} filtered frames came back")
    med = float(np.median([r.get("total_ms", 0.0) for r in records])) if records else float("nan")
    _log(f"{args.filter}: {done} frames -> {args.output} in {wall:.2f} s ({done / wall:.1f} frames/s; server median {med:.2f} ms/frame)")
    psnr = [r["psnr"] for r in records if "psnr" in r]
    if psnr:
        _log(f"  vs the frames' reference channel: mean PSNR {np.mean(psnr):.3f} dB, "
             f"mean SSIM {np.mean([r['ssim'] for r in records if 'ssim' in r]):.4f}")
    return 0


def _progress(out: FilteredFrame, done: int, total: int, dest: str) -> str:
    f = out.figures
    rt = f", round trip {out.round_trip_s * 1000:.1f} ms" if out.round_trip_s is not None else ""
    return (f"[{done}/{total}] frame {out.index}: filter {f.total_ms:.2f} ms{rt}, "
            f"history clipped {f.history_clipped}, restarted {f.history_reset} -> {dest}")


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        # The input is checked before the server is asked anything.
        frames = find_frames(args.input) if args.command == "filter" else None
        with Client(args.server, api_key=args.api_key, tls_ca=args.tls_ca, tls_domain=args.tls_domain, wait=args.wait) as client:
            if args.command == "filters":
                return cmd_filters(args, client)
            return cmd_filter(args, client, frames)
    except AfterimageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `... | head`: the reader left; say nothing more
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
