"""The example scripts under python/examples parse as Python (they need libraries the test
environment lacks, Stable-Baselines3 or RLlib, so they are compiled, not run)."""

from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def test_there_are_examples():
    names = {p.name for p in EXAMPLES}
    assert {"sb3_ppo.py", "python_fish.py", "rllib_ppo.py"} <= names, names


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_compiles(path):
    compile(path.read_text(encoding="utf-8"), str(path), "exec")
