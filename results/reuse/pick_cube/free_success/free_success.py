"""How often a pick_cube episode succeeds with no skill: the cube starts within the goal threshold.

ManiSkill's PickCube draws the goal height from the cube's rest height upwards, so now and then the goal
lies on the cube. Any policy that keeps the arm still for a step then succeeds. This measures that floor
on each split through the same env and rollout the trainer's evaluation uses (zero actions, deterministic).

    OMP_NUM_THREADS=1 .venv/bin/python results/reuse/pick_cube/free_success/free_success.py --episodes 3000
"""

import argparse
import json
from pathlib import Path

import torch

from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.tasks import get_family


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=3000)
    p.add_argument("--steps", type=int, default=3, help="zero-action steps per episode")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(Path(__file__).with_name("free_success.json")))
    a = p.parse_args()
    family = get_family("pick_cube")
    result = {
        "command": f"results/reuse/pick_cube/free_success/free_success.py --episodes {a.episodes} "
        f"--steps {a.steps} --seed {a.seed}",
        "splits": {},
    }
    for k, split in enumerate(("train", "test")):
        torch.manual_seed(
            a.seed + k
        )  # independent draws per split; ManiSkill's unseeded resets draw from torch's global RNG
        env = make_family_env(family, split, seed=a.seed + 10_000, num_envs=1, reward_mode="sparse")
        base = env.base_env.unwrapped
        zero = torch.zeros(env.action_spec.shape)
        dists, successes = [], []
        for i in range(a.episodes):
            ep = env.rollout(a.steps, lambda td: td.set("action", zero), break_when_any_done=True)
            # the cube has not moved: the arm is still and the episode is at most a few steps long
            dists.append(float((base.cube.pose.p[0] - base.goal_site.pose.p[0]).norm()))
            if bool(ep["next", "success"].any()):
                successes.append(
                    {"episode": i, "steps": int(ep.shape[-1]), "cube_goal_distance_m": round(dists[-1], 4)}
                )
        env.close()
        n = a.episodes
        result["splits"][split] = {
            "episodes": n,
            "success_within_steps": len(successes),
            "success_rate": len(successes) / n,
            "cube_within_2.5cm_of_goal": sum(d <= 0.025 for d in dists),
            "cube_within_3cm_of_goal": sum(d <= 0.03 for d in dists),
            "successes": successes,
        }
        print(
            f"{split}: {len(successes)} of {n} episodes succeed within {a.steps} zero-action steps "
            f"({100 * len(successes) / n:.2f}%)"
        )
    Path(a.out).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
