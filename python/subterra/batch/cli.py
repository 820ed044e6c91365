"""The command-line options every batch command shares (``fly-batch``, ``drive-batch``,
``sweep``): the engine, its workers, the cluster address, the output folder and
``--resume``."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from subterra.batch.engine import ENGINES
from subterra.errors import InputError

__all__ = ["add_engine_options", "engine_options", "out_dir", "save_and_report"]


def add_engine_options(p: argparse.ArgumentParser, *, unit: str) -> None:
    """Adds ``--engine``, ``--address``, ``--workers``, ``--resume`` and ``--out``."""
    from subterra.cli import int_in, nonempty

    p.add_argument("--engine", default="threads", choices=ENGINES,
                   help="threads (default: a thread pool here) or ray (a Ray cluster; pip install 'subterra[cluster]')")
    p.add_argument("--address", default=None,
                   help="ray: join this cluster (e.g. ray://head:10001 or auto) instead of starting a local one")
    p.add_argument("--workers", type=int_in(1, 256), default=None,
                   help=f"parallel {unit}s (default: the CPU count; ray: the local cluster's CPUs, or no cap on a cluster)")
    p.add_argument("--resume", action="store_true",
                   help=f"continue the batch in --out: run only the {unit}s its log does not hold")
    p.add_argument("--out", type=nonempty, default=None, help="output folder (default runs/<command>-<scenario>-<time>)")


def engine_options(args: argparse.Namespace) -> dict[str, Any]:
    """The engine keywords of the batch functions, from the parsed options."""
    return {"engine": args.engine, "workers": args.workers, "address": args.address, "resume": args.resume}


def out_dir(args: argparse.Namespace, default_stem: str) -> Path:
    """``--out``, or ``runs/<default_stem>-<time>``; ``--resume`` needs ``--out``."""
    if args.resume and args.out is None:
        raise InputError("argument --resume needs --out (the folder of the batch to continue)")
    return Path(args.out or f"runs/{default_stem}-{time.strftime('%Y%m%d-%H%M%S')}")


def save_and_report(result: Any, out: Path, args: argparse.Namespace, unit: str) -> int:
    """Writes ``result`` into ``out`` (figures unless ``--no-plots``) and prints its table,
    the count, the time and the files; the command's exit code."""
    paths = result.save(out, plots=not args.no_plots)
    print(result.markdown())
    resumed = result.settings.get("resumed", 0)
    tail = f" ({resumed} of them from the log)" if resumed else ""
    print(f"{len(result.rows)} {unit}s in {result.wall_s:.0f} s{tail}")
    for kind, path in paths.items():
        print(f"  {kind}: {path}")
    return 0
