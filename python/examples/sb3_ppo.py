"""Train Stable-Baselines3's PPO on fishprobe's environment, export it to ONNX, and hand it to
the fishprobe command line.

    pip install "./python[sb3]" onnx
    python python/examples/sb3_ppo.py --steps 200000 --out runs/sb3
    fishprobe evaluate --policy onnx:runs/sb3/sb3_zone.onnx --model Zone --episodes 18 --out runs/sb3/eval

The exported file follows fishprobe's policy contract (docs/onnx-models.md): input ``obs``
float32 [batch, 180], output the turn in radians [batch, 1].
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor

import fishprobe
from fishprobe.sb3 import VecEnv


class Deterministic(th.nn.Module):
    """obs (batch, 180) -> turn (batch, 1): the policy's mean action, in radians."""

    def __init__(self, policy):
        super().__init__()
        self.policy = policy

    def forward(self, obs):
        features = self.policy.extract_features(obs)
        latent_pi = self.policy.mlp_extractor.forward_actor(features)
        return self.policy.action_net(latent_pi)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--model", default="Zone")
    p.add_argument("--steps", type=int, default=200_000)
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/sb3")
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    env = VecMonitor(VecEnv(a.envs, model=a.model, seed=a.seed))
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=1024, seed=a.seed, verbose=0)
    started = time.perf_counter()
    model.learn(total_timesteps=a.steps)
    print(f"trained {a.steps} steps in {time.perf_counter() - started:.0f} s")
    model.save(out / f"sb3_{a.model.lower()}")

    onnx = out / f"sb3_{a.model.lower()}.onnx"
    th.onnx.export(
        Deterministic(model.policy.to("cpu")), th.zeros(1, 180), str(onnx),
        input_names=["obs"], output_names=["turn"],
        dynamic_axes={"obs": {0: "batch"}, "turn": {0: "batch"}}, opset_version=17,
        dynamo=False,
    )
    # The exported file, run by fishprobe's own ONNX engine, acts as SB3 does.
    obs = env.reset()
    sb3_turns, _ = model.predict(obs, deterministic=True)
    ours = fishprobe.Policy(f"onnx:{onnx}").act(obs)
    print(f"wrote {onnx}; largest difference from SB3's own action: "
          f"{np.abs(np.clip(sb3_turns, -np.pi, np.pi) - ours).max():.2e} rad")


if __name__ == "__main__":
    main()
