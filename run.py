#!/usr/bin/env python3
"""Set up the project's virtual environment if needed, then run the main job or the tests.

    python3 run.py            # the closed-loop demo: drive, give way, dock; outputs in out/demo/
    python3 run.py test       # lint (ruff), import contracts, mypy --strict on agent/, tests
    python3 run.py -- ARGS    # run `sensor-agent ARGS` inside the environment

Needs only Python 3.11+. The environment lives in `.venv/` beside this file and is reused
until `pyproject.toml` changes.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".installed-from"


def _venv_python() -> Path:
    return VENV / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def _ensure_environment() -> Path:
    if sys.version_info < (3, 11):  # noqa: UP036 - run.py must explain itself on an old Python
        sys.exit(f"run.py: Python 3.11 or newer is needed, this is {sys.version.split()[0]}")
    wanted = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    python = _venv_python()
    if python.exists() and STAMP.exists() and STAMP.read_text().strip() == wanted:
        return python
    if not python.exists():
        print("run.py: creating .venv ...", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    print("run.py: installing the project and its test tools into .venv ...", flush=True)
    pip = [str(python), "-m", "pip", "install", "--disable-pip-version-check", "--quiet"]
    subprocess.run([*pip, "--upgrade", "pip"], check=True)
    # The test tools, and the cluster extra (Dask) that the test of evaluate --cluster runs on.
    subprocess.run([*pip, "-e", f"{ROOT}[test,cluster]"], check=True)
    print("run.py: compiling the compiled kernels (once, about a minute) ...", flush=True)
    subprocess.run([str(python.parent / "sensor-agent"), "warm-up"], check=True, cwd=ROOT)
    STAMP.write_text(wanted + "\n")
    return python


# What `run.py test` checks before the tests, each with how to fix what it finds.
CHECKS = (
    (["ruff", "check", "."], "fix with: .venv/bin/ruff check --fix ."),
    (["ruff", "format", "--check", "."], "fix with: .venv/bin/ruff format ."),
    (["lint-imports"], "an import crosses the layering declared in pyproject.toml"),
    (["mypy"], "agent/ must type-check under mypy --strict"),
)


def main(argv: list[str]) -> int:
    python = _ensure_environment()
    bindir = python.parent
    if argv[:1] == ["test"]:
        for check, fix in CHECKS:
            status = subprocess.run([str(bindir / check[0]), *check[1:]], cwd=ROOT).returncode
            if status != 0:
                print(f"run.py: {' '.join(check)} found problems ({fix})", file=sys.stderr)
                return status
        pytest = [str(python), "-m", "pytest"]
        if argv[1:]:  # the caller chose what to run
            return subprocess.run([*pytest, *argv[1:]], cwd=ROOT).returncode
        # Unit tests on every core; then the system tests, which start real process graphs
        # and check their rates and restart times, alone on the machine.
        for run in (["-n", "auto", "tests/unit"], ["tests/system"]):
            status = subprocess.run([*pytest, *run], cwd=ROOT).returncode
            if status != 0:
                return status
        return 0
    if argv[:1] == ["--"]:
        return subprocess.run([str(bindir / "sensor-agent"), *argv[1:]], cwd=ROOT).returncode
    if argv:
        sys.exit(f"run.py: unknown command {argv[0]!r}; use no argument, 'test', or '-- ARGS'")
    # The closed loop on the shipped demo world, in lock-step (one process, simulated clock:
    # the same outcome on every machine); `-- demo` alone runs it as processes in real time.
    job = [str(bindir / "sensor-agent"), "demo", "--lockstep", "--out", "out/demo"]
    return subprocess.run(job, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
