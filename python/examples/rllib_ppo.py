"""Train RLlib 2.0.1's PPO, the trainer the paper used, on fishprobe's lead-to-goal task with the
paper's published settings (or fewer epochs and more steps), and export the policy's mean action
to ONNX (fishprobe's policy contract), so `fishprobe evaluate` and `fishprobe assay approach` can
run it next to fishprobe's own PPO (docs/validation.md, "Does PPO learn?").

RLlib 2.0.1 has wheels up to Python 3.10 and speaks gym 0.23's API; these pins install it:

    python3.10 -m venv rllib
    rllib/bin/pip install "ray[rllib]==2.0.1" torch ./python
    rllib/bin/pip install "numpy==1.24.4" "setuptools<70" "onnx==1.16.2" "ml_dtypes<0.5"
    rllib/bin/python python/examples/rllib_ppo.py --model Zone --out runs/rllib_zone        # 100 epochs, ~40 min
    rllib/bin/python python/examples/rllib_ppo.py --model Zone --steps 6658400 --epochs 2 --out runs/rllib_zone_8x
    fishprobe evaluate --policy onnx:runs/rllib_zone/policy.onnx --model Zone --out runs/rllib_zone_eval
    fishprobe assay approach --policy onnx:runs/rllib_zone/policy.onnx

`progress.jsonl` holds each iteration's mean return and RLlib's learner statistics; `policy.onnx`
the mean action (fishprobe's ONNX policy contract); `policy/` the whole Gaussian as a fishprobe
policy directory with RLlib's unbounded log-s.d., for `fishprobe evaluate --stochastic` and
`fishprobe assay approach --stochastic` (RLlib's default, `explore=True`).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import gym  # RLlib 2.0.1 speaks gym 0.2x's API
import numpy as np
import ray
import torch
from ray.rllib.algorithms.ppo import PPOConfig

import fishprobe


def patch_gym() -> None:
    """gym 0.23's seeded Generator subclass unpickles with numpy >= 1.24's two-argument
    constructor helper only if its own helper takes the second argument."""
    from gym.utils import seeding

    def ctor(bit_generator="MT19937", bit_generator_ctor=None):
        if isinstance(bit_generator, str):
            bit_generator = getattr(np.random, bit_generator)()
        return seeding.RandomNumberGenerator(bit_generator)

    seeding.RandomNumberGenerator._generator_ctor = staticmethod(ctor)


patch_gym()


class GymEnv(gym.Env):
    """fishprobe's Gymnasium environment behind gym 0.23's API. The time limit ends the episode
    (`done`), as RLlib 2.0.1 treats it."""

    def __init__(self, config):
        patch_gym()
        self.env = fishprobe.LeadToGoalEnv(model=config.get("model", "Zone"))
        self.observation_space = gym.spaces.Box(0.0, 1.0, self.env.observation_space.shape, np.float32)
        self.action_space = gym.spaces.Box(-math.pi, math.pi, (1,), np.float32)
        idx = getattr(config, "worker_index", 0) * 1000 + getattr(config, "vector_index", 0)
        self.seed0 = int(config.get("seed", 0)) * 1_000_003 + idx
        self.first = True

    def reset(self):
        if self.first:
            obs, _ = self.env.reset(seed=self.seed0)
            self.first = False
        else:
            obs, _ = self.env.reset()
        return obs

    def step(self, action):
        obs, r, term, trunc, info = self.env.step(np.asarray(action, np.float32).reshape(1))
        return obs, float(r), bool(term or trunc), {"goals": info["goals_reached"]}


def write_fishprobe_policy(model, out: Path, about: dict) -> None:
    """The policy as a fishprobe policy directory (`policy.safetensors` and its sidecar), with
    RLlib's unbounded log-s.d., so `fishprobe evaluate --stochastic` and `fishprobe assay
    approach --stochastic` sample it as RLlib's `compute_single_action` does by default."""
    sd = {k: v.detach().cpu().numpy() for k, v in model.state_dict().items()}
    layers = {
        "pi": ["_hidden_layers.0", "_hidden_layers.1", "_logits"],
        "vf": ["_value_branch_separate.0", "_value_branch_separate.1", "_value_branch"],
    }
    tensors = {}
    for net, names in layers.items():
        for l, name in enumerate(names):
            tensors[f"{net}.{l}.weight"] = sd[f"{name}._model.0.weight"].T  # [out, in] -> [in, out]
            tensors[f"{net}.{l}.bias"] = sd[f"{name}._model.0.bias"]
    header, blobs, offset = {}, [], 0
    for k in sorted(tensors):
        b = np.ascontiguousarray(tensors[k], dtype="<f4").tobytes()
        header[k] = {"dtype": "F32", "shape": list(tensors[k].shape), "data_offsets": [offset, offset + len(b)]}
        blobs.append(b)
        offset += len(b)
    h = json.dumps(header).encode()
    h += b" " * ((8 - len(h) % 8) % 8)
    out.mkdir(parents=True, exist_ok=True)
    (out / "policy.safetensors").write_bytes(len(h).to_bytes(8, "little") + h + b"".join(blobs))
    meta = {
        "format": "fishprobe-policy",
        "version": 1,
        "obs_dim": 180,
        "pi": {"hidden": "tanh", "sizes": [180, 256, 256, 2]},
        "vf": {"hidden": "tanh", "sizes": [180, 256, 256, 1]},
        "action": "normalised; env action = clip(a, -1, 1) * pi rad",
        "log_std_max": None,
        "about": about,
    }
    (out / "policy.safetensors.json").write_text(json.dumps(meta, indent=2))


class Mean(torch.nn.Module):
    """obs (batch, 180) -> turn (batch, 1): the Gaussian's mean, unsquashed as RLlib does."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, obs):
        logits, _ = self.model({"obs": obs, "obs_flat": obs}, [], None)
        return torch.clamp(logits[:, :1], -1.0, 1.0) * math.pi


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--model", default="Zone")
    p.add_argument("--steps", type=int, default=832_300)
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--envs", type=int, default=8)
    p.add_argument("--out", required=True)
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    config = (
        PPOConfig()
        .environment(
            env=GymEnv,
            env_config={"model": a.model, "seed": a.seed},
            observation_space=gym.spaces.Box(0.0, 1.0, (180,), np.float32),
            action_space=gym.spaces.Box(-math.pi, math.pi, (1,), np.float32),
            normalize_actions=True,
        )
        .framework("torch")
        .rollouts(num_rollout_workers=1, num_envs_per_worker=a.envs)
        .training(
            lr=0.00026,
            train_batch_size=8192,
            sgd_minibatch_size=512,
            num_sgd_iter=a.epochs,
            gamma=0.9453,
            lambda_=0.9652,
            entropy_coeff=0.0,
            vf_loss_coeff=1.0,
            clip_param=0.1112,
            model={"fcnet_hiddens": [256, 256], "fcnet_activation": "tanh"},
        )
        .resources(num_gpus=0)
        .debugging(seed=a.seed)
    )
    algo = config.build()
    started = time.perf_counter()
    log = open(out / "progress.jsonl", "w")
    steps = 0
    while steps < a.steps:
        r = algo.train()
        steps = r["timesteps_total"]
        row = {
            "iteration": r["training_iteration"],
            "steps": steps,
            "return": r["episode_reward_mean"],
            **{
                k: round(float(v), 4)
                for k, v in r["info"]["learner"]["default_policy"]["learner_stats"].items()
                if k in ("entropy", "kl", "vf_explained_var", "cur_kl_coeff", "vf_loss")
            },
            "seconds": round(time.perf_counter() - started, 1),
        }
        log.write(json.dumps(row) + "\n")
        log.flush()
        print(row, flush=True)
    policy = algo.get_policy()
    model = policy.model.to("cpu").eval()
    torch.onnx.export(
        Mean(model), torch.zeros(1, 180), str(out / "policy.onnx"),
        input_names=["obs"], output_names=["turn"],
        dynamic_axes={"obs": {0: "batch"}, "turn": {0: "batch"}}, opset_version=17, dynamo=False,
    )
    write_fishprobe_policy(
        model, out / "policy",
        {"model": a.model, "trainer": "RLlib 2.0.1", "seed": a.seed, "timesteps": steps, "epochs": a.epochs},
    )
    # The exported file and the policy directory act as RLlib's own deterministic action.
    obs = np.random.default_rng(0).random((8, 180), dtype=np.float32) * 0.3
    theirs = np.array([algo.compute_single_action(o, explore=False) for o in obs]).reshape(-1)
    theirs = np.clip(theirs, -math.pi, math.pi)
    onnx_turns = fishprobe.Policy(f"onnx:{out / 'policy.onnx'}").act(obs).reshape(-1)
    dir_turns = fishprobe.Policy(str(out / "policy")).act(obs).reshape(-1)
    print(f"trained {steps} steps in {time.perf_counter() - started:.0f} s; largest difference "
          f"from RLlib's own action: {np.abs(theirs - onnx_turns).max():.2e} rad (policy.onnx), "
          f"{np.abs(theirs - dir_turns).max():.2e} rad (policy/)")


if __name__ == "__main__":
    main()
