"""The package a robot installs: Python 3.10 compatible source, an abi3 wheel that installs
into a fresh virtual environment with NumPy only, and extras that say what is missing."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / "python" / "subterra"


def test_the_package_is_python_310_compatible():
    """No syntax, stdlib module or member newer than Python 3.10 in the package (vermin:
    3.10 is not installed on this machine), and ruff finds no 3.10 syntax error."""
    vermin = shutil.which("vermin", path=str(Path(sys.executable).parent)) or shutil.which("vermin")
    if vermin is None:
        pytest.skip("vermin is not installed (make test installs it)")
    run = subprocess.run([vermin, "-t=3.10-", "--violations", "--no-tips", "--eval-annotations", str(PACKAGE)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is not None:
        run = subprocess.run([ruff, "check", "--no-cache", "--target-version", "py310", "--select", "E9", str(PACKAGE)],
                             capture_output=True, text=True)
        assert run.returncode == 0, run.stdout + run.stderr


def test_version_and_debug_after_the_subcommand():
    from subterra import __version__

    run = subprocess.run([sys.executable, "-m", "subterra.cli", "--version"], capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.strip() == f"subterra {__version__}"
    # --debug after the subcommand: the traceback instead of the one-line error.
    run = subprocess.run([sys.executable, "-m", "subterra.cli", "sim", "render", "nope", "--debug"],
                         capture_output=True, text=True)
    assert run.returncode != 0 and "Traceback" in run.stderr
    run = subprocess.run([sys.executable, "-m", "subterra.cli", "sim", "render", "nope"], capture_output=True, text=True)
    assert run.returncode == 2 and "Traceback" not in run.stderr and run.stderr.startswith("error:")


def test_license_files_match_the_declared_licences():
    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    assert 'license = { text = "MIT OR Apache-2.0" }' in text
    assert "MIT License" in (REPO / "LICENSE-MIT").read_text(encoding="utf-8")
    assert "Apache License" in (REPO / "LICENSE-APACHE").read_text(encoding="utf-8")


@pytest.mark.skipif(os.environ.get("SUBTERRA_SKIP_WHEEL") == "1", reason="SUBTERRA_SKIP_WHEEL=1")
def test_the_wheel_installs_into_a_fresh_venv_and_the_core_needs_numpy_only(tmp_path):
    """`maturin build` (the build `make build` left, repackaged) gives an abi3 wheel for
    CPython >= 3.10; in a fresh virtual environment with only NumPy, `subterra --version`
    runs, a perception step runs, the core imports nothing optional, and a part whose extra
    is missing raises MissingExtraError naming the extra (one line from the CLI)."""
    maturin = Path(sys.executable).parent / "maturin"
    if not maturin.exists():
        pytest.skip("maturin is not installed next to this Python (make test installs it)")
    env = dict(os.environ, CARGO_TARGET_DIR=str(REPO / "target" / "maturin"), VIRTUAL_ENV=str(Path(sys.executable).parent.parent))
    build = subprocess.run([str(maturin), "build", "--release", "--quiet", "--out", str(tmp_path / "dist")], cwd=REPO, env=env,
                           capture_output=True, text=True)
    assert build.returncode == 0, build.stderr[-3000:]
    wheels = list((tmp_path / "dist").glob("subterra-*.whl"))
    assert len(wheels) == 1 and "-cp310-abi3-" in wheels[0].name, wheels
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    install = subprocess.run([str(py), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", str(wheels[0])],
                             capture_output=True, text=True)
    assert install.returncode == 0, install.stderr[-3000:]
    listed = subprocess.run([str(py), "-m", "pip", "list", "--format=freeze"], capture_output=True, text=True).stdout
    names = {line.split("==")[0].lower() for line in listed.splitlines()}
    assert names <= {"subterra", "numpy", "pip", "setuptools", "wheel"}, names
    version = subprocess.run([str(venv / "bin" / "subterra"), "--version"], capture_output=True, text=True)
    assert version.returncode == 0 and version.stdout.startswith("subterra "), version.stderr
    script = textwrap.dedent("""
        import sys
        import numpy as np
        import subterra
        from subterra.errors import MissingExtraError
        p = subterra.DepthPerception(subterra.PinholeCamera.d435(), preset="flight")
        out = p.update(np.full((480, 640), 800, np.uint16))
        assert 0.0 <= out.p_free < 1.0, out.p_free
        nav = subterra.Navigator(goal=[4.0, 0.0])
        optional = {"matplotlib", "rosbags", "mcap", "tqdm", "yaml", "PIL", "cyclonedds", "scipy"}
        loaded = optional & set(sys.modules)
        assert not loaded, loaded
        from subterra.io import ros
        try:
            ros.default_typestore()
        except MissingExtraError as exc:
            assert "pip install 'subterra[io]'" in str(exc), exc
        else:
            raise AssertionError("rosbags is not installed: expected MissingExtraError")
        print("core ok")
    """)
    run = subprocess.run([str(py), "-c", script], capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0 and "core ok" in run.stdout, run.stdout + run.stderr
    node = subprocess.run([str(venv / "bin" / "subterra"), "node", "ground", "--loopback", "--duration", "1"],
                          capture_output=True, text=True, cwd=tmp_path)
    assert node.returncode == 2 and node.stderr.strip().startswith("error:") and "subterra[ros]" in node.stderr, node.stderr
