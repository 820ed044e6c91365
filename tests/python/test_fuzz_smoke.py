"""A short seeded run of every fuzz target (``fuzz/targets.py``) inside ``make test``.

Each target gets its committed seeds, mutated copies of them and fixed pseudo-random inputs,
in this process (no coverage guidance: ``make fuzz`` does that). A target lets only
``SubterraError`` through silently, so any other exception, a Rust panic or an abort fails
the test. One target also runs under libFuzzer through ``fuzz/run.py`` to prove the wiring.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

atheris = pytest.importorskip("atheris", reason="atheris is not installed (make test installs it)")

FUZZ = Path(__file__).resolve().parents[2] / "fuzz"
sys.path.insert(0, str(FUZZ))
import targets  # noqa: E402

SEEDS = FUZZ / "seeds"
REGRESSIONS = FUZZ / "regressions"  # inputs of past findings, one folder per target
RANDOM_INPUTS = 24
MUTANTS_PER_SEED = 6


@pytest.fixture(scope="module", autouse=True)
def scratch(tmp_path_factory: pytest.TempPathFactory) -> None:
    targets._SCRATCH = tmp_path_factory.mktemp("fuzz-scratch")


def _mutants(data: bytes, rnd: random.Random) -> list[bytes]:
    """Truncations, byte flips and splices of one seed, the damage libFuzzer starts with."""
    out = []
    for _ in range(MUTANTS_PER_SEED):
        b = bytearray(data)
        k = rnd.randrange(4)
        if k == 0 and b:
            del b[rnd.randrange(len(b)):]
        elif k == 1 and b:
            for _ in range(rnd.randint(1, 8)):
                b[rnd.randrange(len(b))] = rnd.randrange(256)
        elif k == 2 and b:
            i = rnd.randrange(len(b))
            b[i:i] = rnd.randbytes(rnd.randint(1, 64))
        else:
            b += rnd.randbytes(rnd.randint(0, 256))
        out.append(bytes(b))
    return out


def test_every_target_has_seeds() -> None:
    missing = [name for name in targets.TARGETS if not any((SEEDS / name).glob("*"))]
    assert not missing, f"no seeds in fuzz/seeds for {missing}: run python fuzz/make_corpus.py"
    stray = sorted(p.name for p in SEEDS.iterdir() if p.is_dir() and p.name not in targets.TARGETS)
    assert not stray, f"seed folders of no target: {stray}"


@pytest.mark.parametrize("name", list(targets.TARGETS))
def test_target_survives_seeds_and_mutants(name: str) -> None:
    target = targets.load(name)
    rnd = random.Random(zlib.crc32(name.encode()))
    inputs = []
    for seed in sorted((SEEDS / name).glob("*")):
        data = seed.read_bytes()
        inputs += [data, *_mutants(data, rnd)]
    inputs += [rnd.randbytes(rnd.choice([0, 1, 7, 64, 300, 1500])) for _ in range(RANDOM_INPUTS)]
    for i, data in enumerate(inputs):
        try:
            target(data)
        except Exception as e:  # noqa: BLE001 - reported with the input that raised it
            pytest.fail(f"{name}: input {i} ({len(data)} bytes, {data[:48]!r}...) raised {type(e).__name__}: {e}")


@pytest.mark.parametrize(
    "path", sorted(REGRESSIONS.glob("*/*")), ids=lambda p: f"{p.parent.name}/{p.name}"
)
def test_past_findings_stay_fixed(path: Path) -> None:
    """Every input a fuzz campaign found a bug with runs clean through its target. An
    out-of-memory finding (``oom-*``) runs in a process of its own whose peak resident memory
    must stay under half the campaign's limit (``fuzz/run.py``: 2048 MB)."""
    assert path.parent.name in targets.TARGETS, f"{path}: no target {path.parent.name!r}"
    if not path.name.startswith("oom-"):
        targets.load(path.parent.name)(path.read_bytes())
        return
    code = ("import resource, sys; sys.path.insert(0, sys.argv[1]); import targets; "
            "targets.load(sys.argv[2])(open(sys.argv[3], 'rb').read()); "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    proc = subprocess.run([sys.executable, "-c", code, str(FUZZ), path.parent.name, str(path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    peak_mb = int(proc.stdout.split()[-1]) / 1024
    assert peak_mb < 1024, f"{path.name}: peak resident memory {peak_mb:.0f} MB"


def test_libfuzzer_run_writes_its_report(tmp_path: Path) -> None:
    """``fuzz/run.py`` drives one target under libFuzzer and reports executions and findings."""
    report, totals = tmp_path / "report.json", tmp_path / "totals.json"
    cmd = [sys.executable, str(FUZZ / "run.py"), "--only", "path_follower", "--seconds", "3",
           "--corpus", str(tmp_path / "corpus"), "--crashes", str(tmp_path / "crashes"),
           "--report", str(report), "--totals", str(totals), "--", "-seed=7"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    got = json.loads(report.read_text())
    (entry,) = got["targets"]
    assert entry["target"] == "path_follower" and entry["findings"] == [] and entry["returncode"] == 0
    assert entry["executions"] > 0, proc.stdout
    assert json.loads(totals.read_text()) == {"path_follower": entry["executions"]}
