"""HalfCheetah's own return (the paper's yardstick, Appendix G) of a drs-learn/drs-reuse policy, and
what the learned reward says about those episodes.

    .venv/bin/python results/half_cheetah/evaluate_policy.py RUN_DIR [--split train|test] [--episodes 3]

The training logs record the return under the reward being trained on (the learned DrS reward in
phase 1); this rolls the deterministic policy out with the env's own reward instead and prints its
return, the first step at which the running return passed 4800 (success) and, if the run has a
learned reward, the mean learned reward of the episode.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torchrl.envs.utils import ExplorationType, set_exploration_type

from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.models import make_sac_modules, read_policy_checkpoint
from drs_torchrl.tasks import get_family
from drs_torchrl.transforms import DrSReward


def main() -> None:
    torch.set_num_threads(1)
    p = argparse.ArgumentParser()
    p.add_argument("run_dir", type=Path)
    p.add_argument("--split", default=None, help="default: the run's split")
    p.add_argument("--episodes", type=int, default=3)
    a = p.parse_args()
    cfg = OmegaConf.load(a.run_dir / "config.yaml")
    family = get_family(cfg.env.family)
    # the paper's success threshold, whatever the run trained with
    env = make_family_env(
        family, a.split or cfg.env.split, reward_mode="dense", seed=12345, variant_overrides={"success_return": 4800.0}
    )
    _, ck = read_policy_checkpoint(a.run_dir)  # weights-only: a shared policy.pt runs no code
    actor, _ = make_sac_modules(env.observation_spec, env.action_spec, ck["policy_in_keys"], ck["hidden"])
    actor.load_state_dict(ck["actor"])
    reward_path = a.run_dir / "checkpoints" / "reward.pt"
    learned = DrSReward.from_checkpoint(reward_path) if reward_path.is_file() else None
    out = []
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for _ in range(a.episodes):
            td = env.rollout(1000, actor)
            ret = td["next", "reward"].reshape(-1).cumsum(0)
            passed = (ret > 4800).nonzero()
            row = {
                "return": float(ret[-1]),
                "steps": int(td.shape[0]),
                "success_step": int(passed[0]) if passed.numel() else None,
                "forward_velocity_mean": float(td["next", "observation"][:, 8].mean()),
            }
            if learned is not None:
                row["learned_reward_mean"] = float(learned.reward(td["next"]).mean())
            out.append(row)
    env.close()
    print(json.dumps({"run": str(a.run_dir), "split": a.split or cfg.env.split, "episodes": out}, indent=1))


if __name__ == "__main__":
    main()
