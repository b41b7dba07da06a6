"""Throughput of fishprobe from Python: ``python -m fishprobe.bench``.

Measures, on this machine, (1) one ``LeadToGoalEnv`` stepped with random actions on one core,
(2) a ``VectorEnv`` of 64 environments on all cores, and (3) the cost of a fish model written
in Python (``fishprobe.models.Attractor``), per simulated frame. With ``--cli PATH`` it also
runs ``PATH bench sim --json`` and prints the vector environment's share of the CLI's all-core
figure for the same model. A step is one policy action (one simulated second, 25 frames).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time

import numpy as np

from .env import LeadToGoalEnv
from .models import Attractor
from .vector import VectorEnv


def single(model, seconds: float, seed: int = 0) -> float:
    env = LeadToGoalEnv(model=model)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-np.pi, np.pi, (4096, 1)).astype(np.float32)
    steps = 0
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for a in actions[:256]:
            _, _, _, truncated, _ = env.step(a)
            steps += 1
            if truncated:
                env.reset()
        actions = np.roll(actions, 1, axis=0)
    return steps / elapsed


def vector(model, num_envs: int, seconds: float, seed: int = 0) -> float:
    env = VectorEnv(num_envs, model=model, seed=seed)
    env.reset()
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-np.pi, np.pi, (16, num_envs, 1)).astype(np.float32)
    steps = 0
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for a in actions:
            env.step(a)
            steps += num_envs
    return steps / elapsed


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m fishprobe.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="Zone")
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--cli", help="the fishprobe binary, to compare with `fishprobe bench sim`")
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)

    frames = 25  # per step at the default settings
    r: dict = {"model": a.model, "cores": os.cpu_count()}
    r["single_steps_per_s"] = single(a.model, a.seconds)
    r["vector_envs"] = a.envs
    r["vector_steps_per_s"] = vector(a.model, a.envs, a.seconds)
    py_sps = single(Attractor(), a.seconds)
    builtin_follow = single("Follow", a.seconds)
    r["python_model_single_steps_per_s"] = py_sps
    r["follow_single_steps_per_s"] = builtin_follow
    r["python_model_us_per_frame"] = 1e6 * (1 / py_sps - 1 / builtin_follow) / frames
    if a.cli:
        out = subprocess.run(
            [a.cli, "bench", "sim", "--json", "--seconds", str(a.seconds), "--envs", str(a.envs)],
            capture_output=True, text=True, check=True,
        ).stdout
        rows = [x for x in json.loads(out)["results"] if x["model"].lower() == a.model.lower()]
        if rows:
            best = max(rows, key=lambda x: x["threads"])
            r["cli_all_cores_steps_per_s"] = best["policy_steps_per_s"]
            r["vector_share_of_cli"] = r["vector_steps_per_s"] / best["policy_steps_per_s"]
    if a.json:
        print(json.dumps(r, indent=2))
        return r
    print(f"model {a.model}, {r['cores']} cores; a step is one action (1 s simulated, {frames} frames)")
    print(f"  LeadToGoalEnv, one core, random actions   {r['single_steps_per_s']:>12,.0f} steps/s")
    print(f"  VectorEnv({a.envs}), all cores               {r['vector_steps_per_s']:>12,.0f} steps/s")
    print(f"  Python fish model (Attractor), one env    {py_sps:>12,.0f} steps/s "
          f"(Follow in Rust: {builtin_follow:,.0f}); Python costs {r['python_model_us_per_frame']:.1f} us per frame")
    if "cli_all_cores_steps_per_s" in r:
        print(f"  fishprobe bench sim, all cores            {r['cli_all_cores_steps_per_s']:>12,.0f} steps/s"
              f" (VectorEnv reaches {100 * r['vector_share_of_cli']:.0f} %)")
    return r


if __name__ == "__main__":
    main()
