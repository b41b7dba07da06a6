"""Shared fixtures. The ``fishprobe`` binary (for files only the CLI writes) is found through
FISHPROBE_BIN, which .ci/run sets; the real tracking data through FISHPROBE_DATA: a test that
needs either finds it set but missing fails, and skips only when it is not set at all."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest


def _from_env(var: str, what: str) -> Path:
    value = os.environ.get(var)
    if not value:
        pytest.skip(f"{var} is not set ({what})")
    path = Path(value)
    if not path.exists():
        pytest.fail(f"{var}={value} is set but does not exist")
    return path


@pytest.fixture(scope="session")
def fishprobe_bin() -> Path:
    return _from_env("FISHPROBE_BIN", "the fishprobe binary, e.g. target/debug/fishprobe")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    return _from_env("FISHPROBE_DATA", "the shared tracking data directory")


@pytest.fixture()
def cli(fishprobe_bin):
    def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
        r = subprocess.run(
            [str(fishprobe_bin), *map(str, args)], capture_output=True, text=True, cwd=cwd
        )
        assert r.returncode == 0, f"fishprobe {' '.join(map(str, args))}: {r.stderr}"
        return r

    return run


@pytest.fixture(scope="session")
def smoke_policy(tmp_path_factory, fishprobe_bin) -> Path:
    """A policy trained by the CLI (smoke preset, Zone, seed 0)."""
    out = tmp_path_factory.mktemp("cli") / "zone"
    r = subprocess.run(
        [str(fishprobe_bin), "train", "--model", "Zone", "--preset", "smoke", "--seed", "0",
         "--out", str(out), "--jobs", "2"],
        capture_output=True, text=True,
    )
    assert r.returncode == 0, r.stderr
    return out


def which_fishprobe() -> str | None:
    return os.environ.get("FISHPROBE_BIN") or shutil.which("fishprobe")
