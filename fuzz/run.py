"""Runs subterra's fuzz targets, each in its own libFuzzer process, for a set time.

For every target (``fuzz/targets.py`` lists them) this starts ``python fuzz/targets.py
TARGET`` with

- ``-max_total_time`` (``--seconds``), ``-timeout=5`` (an input that takes longer is a hang)
  and ``-rss_limit_mb=2048`` (a process that grows past it is a finding);
- the grown corpus ``fuzz/corpus/TARGET/`` (written, git-ignored) and the committed seeds
  ``fuzz/seeds/TARGET/`` (read);
- crash, timeout and out-of-memory inputs written to ``fuzz/crashes/TARGET/`` (git-ignored).

It prints one line per target, writes ``fuzz/last-run.json`` (executions, new corpus
entries, findings per target) and adds the executions to ``fuzz/totals.json``, the running
count per target over every run on this checkout, as each target finishes. ``--until N``
runs each target only until its total reaches N executions (``-runs``; ``--seconds`` stays
the cap), and leaves out targets already there. The exit status is 1 when any target
found something: once it is fixed, copy the input from ``fuzz/crashes/TARGET/`` into
``fuzz/regressions/TARGET/`` (``make test`` replays every file there through its target).

    python fuzz/run.py [--seconds 60] [--jobs 1] [--until N] [--only NAME ...] [--skip NAME ...] [--list]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import targets  # noqa: E402  (the registry)

TIMEOUT_S = 5
RSS_LIMIT_MB = 2048
_EXECS = re.compile(r"stat::number_of_executed_units:\s*(\d+)")
_DONE = re.compile(r"#(\d+)\s+DONE")
_PULSE = re.compile(r"^#(\d+)\s", re.M)
_ARTIFACT = re.compile(r"Test unit written to (\S+)")


@dataclass
class Outcome:
    target: str
    seconds: float
    executions: int = 0
    corpus_added: int = 0
    returncode: int = 0
    findings: list[str] = field(default_factory=list)  # artifact paths
    summary: str = ""  # the finding's first line (exception, "timeout", "out-of-memory", signal)


def run_target(name: str, seconds: int, *, corpus_root: Path, seeds_root: Path, crash_root: Path,
               extra: list[str], runs: int | None = None) -> Outcome:
    corpus, seeds, crashes = corpus_root / name, seeds_root / name, crash_root / name
    corpus.mkdir(parents=True, exist_ok=True)
    crashes.mkdir(parents=True, exist_ok=True)
    before = sum(1 for _ in corpus.iterdir())
    max_len = targets.MAX_LEN.get(name, targets.DEFAULT_MAX_LEN)
    cmd = [
        sys.executable, str(HERE / "targets.py"), name,
        f"-max_total_time={seconds}", f"-timeout={TIMEOUT_S}", f"-rss_limit_mb={RSS_LIMIT_MB}",
        f"-max_len={max_len}", f"-artifact_prefix={crashes}/", "-print_final_stats=1",
        *([f"-runs={runs}"] if runs is not None else []), *extra,
        str(corpus), *([str(seeds)] if seeds.is_dir() else []),
    ]
    env = dict(os.environ, PYTHONHASHSEED="0")
    t0 = time.monotonic()
    # The process's own guard: libFuzzer stops itself at -max_total_time; this catches a
    # harness that does not (a hang outside an input, a stuck import).
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, errors="replace", env=env,
                              timeout=seconds + 120)
        log, rc = proc.stderr + proc.stdout, proc.returncode
    except subprocess.TimeoutExpired as e:
        log = (e.stderr or b"").decode("utf-8", "replace") if isinstance(e.stderr, bytes) else (e.stderr or "")
        rc = -9
    out = Outcome(name, round(time.monotonic() - t0, 1), returncode=rc)
    m = _EXECS.search(log) or _DONE.search(log)
    if m:
        out.executions = int(m.group(1))
    else:  # killed before the final stats: the last status line
        pulses = _PULSE.findall(log)
        out.executions = int(pulses[-1]) if pulses else 0
    out.corpus_added = sum(1 for _ in corpus.iterdir()) - before
    out.findings = _ARTIFACT.findall(log)
    if rc != 0 or out.findings:
        (crashes / "last.log").write_text(log[-200_000:])
        out.summary = _first_finding(log, rc)
    return out


def _first_finding(log: str, rc: int) -> str:
    for pattern in (r"=== Uncaught Python exception: ===\n(.+)\n(?:.*\n)*?(\w+(?:\.\w+)*(?:Error|Exception|Panic)[^\n]*)",
                    r"ERROR: libFuzzer: (\S+)", r"(Traceback[^\n]*)"):
        m = re.search(pattern, log)
        if m:
            return m.group(m.lastindex or 0)[:300]
    return f"exit status {rc}" + (": see last.log" if rc else "")


def _read_totals(path: Path) -> dict[str, int]:
    if not path.is_file():
        return {}
    try:
        return {k: int(v) for k, v in json.loads(path.read_text()).items()}
    except (ValueError, AttributeError, TypeError):
        print(f"warning: {path} unreadable; starting the totals again", file=sys.stderr)
        return {}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=int, default=int(os.environ.get("FUZZ_SECONDS", "60")),
                        help="fuzzing time per target (default $FUZZ_SECONDS or 60)")
    parser.add_argument("--jobs", type=int, default=1, help="targets fuzzed at once (default 1)")
    parser.add_argument("--until", type=int, metavar="N",
                        help="stop each target once its total in --totals reaches N executions")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="fuzz only these targets")
    parser.add_argument("--skip", nargs="+", metavar="NAME", default=[], help="leave these targets out")
    parser.add_argument("--corpus", type=Path, default=HERE / "corpus", help="grown corpora (default fuzz/corpus)")
    parser.add_argument("--seeds", type=Path, default=HERE / "seeds", help="seed corpora (default fuzz/seeds)")
    parser.add_argument("--crashes", type=Path, default=HERE / "crashes", help="findings (default fuzz/crashes)")
    parser.add_argument("--report", type=Path, default=HERE / "last-run.json", help="this run's report")
    parser.add_argument("--totals", type=Path, default=HERE / "totals.json", help="running totals per target")
    parser.add_argument("--list", action="store_true", help="print the targets and what each fuzzes, and stop")
    parser.add_argument("libfuzzer", nargs="*", help="extra libFuzzer flags, after --")
    args = parser.parse_args(argv)
    if args.list:
        for name, fn in targets.TARGETS.items():
            print(f"{name:<26} {(fn.__doc__ or '').strip().splitlines()[0]}")
        return 0
    if args.seconds < 1:
        parser.error(f"--seconds must be at least 1, got {args.seconds}")
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")
    if args.until is not None and args.until < 1:
        parser.error(f"--until must be at least 1, got {args.until}")
    names = list(targets.TARGETS)
    unknown = [n for n in (args.only or []) + args.skip if n not in targets.TARGETS]
    if unknown:
        parser.error(f"unknown targets {unknown}; known: {', '.join(names)}")
    if args.only:
        names = [n for n in names if n in args.only]
    names = [n for n in names if n not in args.skip]
    totals = _read_totals(args.totals)
    if args.until is not None:
        done = [n for n in names if totals.get(n, 0) >= args.until]
        if done:
            print(f"{len(done)} targets already have {args.until:,} executions: {', '.join(done)}")
        names = [n for n in names if n not in done]

    print(f"fuzzing {len(names)} targets for {args.seconds} s each, {args.jobs} at a time "
          f"(-timeout={TIMEOUT_S} -rss_limit_mb={RSS_LIMIT_MB})", flush=True)
    outcomes: list[Outcome] = []
    lock = threading.Lock()

    def one(name: str) -> Outcome:
        runs = None if args.until is None else args.until - totals.get(name, 0)
        o = run_target(name, args.seconds, corpus_root=args.corpus, seeds_root=args.seeds,
                       crash_root=args.crashes, extra=args.libfuzzer, runs=runs)
        with lock:  # written as each target ends, so a stopped campaign keeps its counts
            totals[name] = totals.get(name, 0) + o.executions
            args.totals.write_text(json.dumps(dict(sorted(totals.items())), indent=1) + "\n")
        status = "ok" if not (o.returncode or o.findings) else f"FINDING {o.summary}"
        print(f"  {name:<26} {o.executions:>10,} execs  {o.executions / max(o.seconds, 1e-9):>8,.0f}/s  "
              f"+{o.corpus_added:<4} corpus  {status}", flush=True)
        return o

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        outcomes = list(pool.map(one, names))

    found = [o for o in outcomes if o.returncode or o.findings]
    report = {
        "seconds_per_target": args.seconds,
        "timeout_s": TIMEOUT_S,
        "rss_limit_mb": RSS_LIMIT_MB,
        "load_average": os.getloadavg(),
        "executions": sum(o.executions for o in outcomes),
        "totals": {n: totals.get(n, 0) for n in targets.TARGETS},
        "findings": len(found),
        "targets": [asdict(o) for o in outcomes],
    }
    args.report.write_text(json.dumps(report, indent=1) + "\n")
    print(f"{report['executions']:,} executions, {len(found)} targets with findings; "
          f"report {args.report}, totals {args.totals}")
    for o in found:
        print(f"  {o.target}: {o.summary} ({', '.join(o.findings) or 'see ' + str(args.crashes / o.target / 'last.log')})")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
