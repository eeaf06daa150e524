"""``grip-bench stream``: GRIP frame by frame over JSON lines (stdin/stdout or a TCP socket)."""

from __future__ import annotations

import argparse
import contextlib
import json
import socket
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:
    from ..grip.stream import GripStream

DESCRIPTION = """\
Stream GRIP (--method, a GRIP variant, from --checkpoint) over JSON lines: each input
line is one frame, each output line the hands of that frame (docs/streaming.md).

input line:  {"body":   {"global_orient": [3], "body_pose": [63], "transl": [3]},
              "object": {"global_orient": [3], "transl": [3]},
              "hands":  {"left":  {"global_orient": [3], "transl": [3]},
                         "right": {"global_orient": [3], "transl": [3]}},
              "reset": true}                      (optional: a new take starts here)
output line: {"frame": k, "ms": latency,
              "left":  {"global_orient": [3], "hand_pose": [45], "transl": [3]},
              "right": {...}, "body_pose": [63]}  (+ "vertices" per hand with --vertices)

Axis-angle radians, metres, world frame (GRAB's parameter layout); "hands" are the input
wrists. Each output depends only on the frames up to it (online mode). A malformed line
ends the stream with `error: line N: FIELD: what` (exit 1); end of input ends it cleanly.
--socket HOST:PORT serves the same protocol to one TCP client at a time (each connection
a new take; a malformed line answers {"error": ...} and closes that connection); only
loopback addresses unless --allow-remote. --precision auto runs int8 where the CPU has
int8 dot products (the fastest at batch 1), else fp32."""


# grip.frozen.STREAM_PRECISION_CHOICES, spelled out: importing it brings torch into every
# grip-bench start-up (build_parser registers every command); a test keeps the two equal
STREAM_PRECISION_CHOICES = ("auto", "fp32", "bf16", "int8")


def register(sub: argparse._SubParsersAction) -> None:
    from .meshopts import add_mesh_flags

    p = sub.add_parser("stream", help="run GRIP frame by frame over JSON lines",
                       description=DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  grip-bench stream --method grip --checkpoint grip.pt "
                              "--object data/tools/object_meshes/contact_meshes/mug.ply "
                              "< frames.jsonl > hands.jsonl")
    p.add_argument("--method", default="grip", help="a GRIP variant (default grip)")
    p.add_argument("--checkpoint", type=Path, required=True, metavar="CKPT")
    p.add_argument("--object", type=Path, required=True, metavar="MESH",
                   help="the object's mesh (its data folder's, or any trimesh-readable file)")
    p.add_argument("--precision", default="auto", choices=STREAM_PRECISION_CHOICES,
                   help="network arithmetic (default auto: int8 where native, else fp32)")
    p.add_argument("--socket", default=None, metavar="HOST:PORT",
                   help="serve over TCP instead of stdin/stdout (port 0: any free port)")
    p.add_argument("--allow-remote", action="store_true",
                   help="allow a --socket address other than loopback")
    p.add_argument("--max-connections", type=int, default=None, metavar="N",
                   help="with --socket: stop after N connections (default: serve forever)")
    p.add_argument("--height", type=float, default=None, metavar="M", help="subject stature (m)")
    p.add_argument("--hand-scale", type=float, default=None, metavar="S",
                   help="hand size multiplier")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the input (Hz)")
    p.add_argument("--no-anet", action="store_true", help="use the input wrists (no arm denoising)")
    p.add_argument("--vertices", action="store_true", help="also write the hands' vertices")
    p.add_argument("--threads", type=int, default=1, metavar="N",
                   help="torch threads (default 1: batch-1 GEMVs gain little from more and "
                        "lose much on shared cores)")
    add_mesh_flags(p)
    p.set_defaults(func=run)


def parse_address(text: str, allow_remote: bool) -> tuple[str, int]:
    """(host, port) of ``HOST:PORT``; a non-loopback host needs ``allow_remote``."""
    import ipaddress

    from ..core.errors import InputError

    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise InputError("expected HOST:PORT (e.g. 127.0.0.1:8765)", "--socket")
    host = host.strip("[]")
    try:
        addrs = {info[4][0] for info in socket.getaddrinfo(host, int(port))}
    except socket.gaierror as e:
        raise InputError(f"cannot resolve host {host!r} ({e.strerror})", "--socket") from None
    if not allow_remote and not all(ipaddress.ip_address(a).is_loopback for a in addrs):
        raise InputError(f"{host} is not a loopback address (use --allow-remote to serve "
                         "other machines)", "--socket")
    return host, int(port)


@contextlib.contextmanager
def _library(mesh: Path, args: argparse.Namespace) -> Iterator[tuple[object, str]]:
    """(ObjectLibrary, object name) of a mesh file: its own data folder when it sits at
    ``DATA/tools/object_meshes/contact_meshes/NAME.ply``, else a temporary one holding it."""
    from ..core.errors import InputError
    from ..data.grab_io import object_mesh_path
    from ..data.library import ObjectLibrary
    from .meshopts import mesh_options

    if not mesh.is_file():
        raise InputError("object mesh not found", mesh)
    name = mesh.stem
    root = mesh.resolve().parents[3] if len(mesh.resolve().parents) > 3 else None
    if root is not None and object_mesh_path(root, name) == mesh.resolve():
        yield ObjectLibrary(root, mesh_options(args)), name
        return
    import trimesh

    with tempfile.TemporaryDirectory(prefix="grip-bench-stream-") as tmp:
        dest = object_mesh_path(tmp, name)
        dest.parent.mkdir(parents=True)
        try:
            trimesh.load(mesh, force="mesh", process=False).export(dest)
        except Exception as e:  # trimesh raises many types for unreadable files
            raise InputError(f"cannot read the mesh ({e})", mesh) from None
        yield ObjectLibrary(Path(tmp), mesh_options(args)), name


def run(args: argparse.Namespace) -> int:
    import torch

    from ..core.errors import InputError
    from ..grip.frozen import resolve_stream_precision
    from ..grip.stream import GripStream

    if not args.checkpoint.is_file():
        raise InputError("checkpoint file not found", args.checkpoint)
    address = parse_address(args.socket, args.allow_remote) if args.socket else None
    precision, warning = resolve_stream_precision(args.precision)
    if warning:
        print(f"warning: --precision: {warning}", file=sys.stderr)
    if args.threads:
        torch.set_num_threads(args.threads)
    with _library(args.object, args) as (library, name):
        stream = GripStream.from_checkpoint(
            args.checkpoint, library, name, method=args.method, precision=precision,
            use_anet=not args.no_anet, vertices=args.vertices, height=args.height,
            hand_scale=args.hand_scale, fps=args.fps)
        stream.warm_up()  # the first frames' one-off costs, before any input arrives
        if address is None:
            serve_lines(stream, sys.stdin, sys.stdout)
        else:
            serve_socket(stream, address, args.max_connections)
    return 0


def serve_lines(stream: GripStream, lines: IO[str], out: IO[str]) -> int:
    """Answer every JSON line of ``lines`` on ``out`` until end of input; returns the frames
    answered. A malformed line raises :class:`InputError` ``line N: FIELD: what``."""
    from ..core.errors import InputError

    n = 0
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.write(answer(stream, line) + "\n")
        except InputError as e:
            raise InputError(e.what, f"line {number}: {e.where}" if e.where else
                             f"line {number}") from None
        out.flush()  # each frame's hands leave now: the client waits for them
        n += 1
    return n


def answer(stream: GripStream, line: str) -> str:
    """The output line (JSON) of one input line."""
    from ..core.errors import InputError

    try:
        frame = json.loads(line)
    except json.JSONDecodeError as e:
        raise InputError(f"not JSON ({e.msg} at column {e.colno})", "frame") from None
    if isinstance(frame, dict) and frame.get("reset"):
        stream.reset()
    t0 = time.perf_counter()
    k = stream.frame_index
    hands = stream.step(frame)
    ms = (time.perf_counter() - t0) * 1e3
    out: dict = {"frame": k, "ms": round(ms, 3)}
    for key, value in hands.items():
        out[key] = ({f: v.tolist() for f, v in value.items()} if isinstance(value, dict)
                    else value.tolist())
    return json.dumps(out)


def serve_socket(stream: GripStream, address: tuple[str, int],
                 max_connections: int | None = None) -> None:
    """Serve :func:`serve_lines` to one TCP client at a time (each a new take). Prints
    ``listening on HOST:PORT`` to stderr once bound (port 0 picks a free one)."""
    from ..core.errors import InputError

    family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(address)
        server.listen(1)
        host, port = server.getsockname()[:2]
        print(f"listening on {host}:{port}", file=sys.stderr, flush=True)
        served = 0
        while max_connections is None or served < max_connections:
            conn, _ = server.accept()
            served += 1
            stream.reset()
            with conn, conn.makefile("r", encoding="utf-8") as rf, \
                    conn.makefile("w", encoding="utf-8") as wf:
                try:
                    serve_lines(stream, rf, wf)
                except InputError as e:
                    print(f"error: {e.message}", file=sys.stderr, flush=True)
                    with contextlib.suppress(OSError):
                        wf.write(json.dumps({"error": e.message}) + "\n")
                        wf.flush()
                except (ConnectionError, BrokenPipeError):
                    pass  # the client went away: wait for the next one
