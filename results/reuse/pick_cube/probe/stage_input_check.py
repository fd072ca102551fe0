"""Why the probe's episodes change when the stages are labelled at 5 cm (--variant-override placed_thresh=0.05).

The pick policies read the stage indicators as inputs (``policy_in_keys: [observation, stage_indicators]``), so
an agent acts differently once its "placed" input turns on at 5 cm instead of 2.5 cm. This rolls out one agent
(``drs-sacdemos_s1``, sampled actions, seed 0) in both labellings and prints, per episode, the first step whose
stage label, observation and action differ::

    .venv/bin/python results/reuse/pick_cube/probe/stage_input_check.py > results/reuse/pick_cube/probe/stage_input_check.md
"""

import torch
from omegaconf import OmegaConf
from torchrl.envs.utils import ExplorationType, set_exploration_type

from drs_torchrl.runtime.console import quiet_libraries
from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.models import load_policy
from drs_torchrl.tasks import family_from_config

POLICY = "results/reuse/pick_cube/run_files/drs-sacdemos_s1"
EPISODES = 5


def first(mask: torch.Tensor):
    return int(mask.nonzero()[0]) if mask.any() else "-"


def main() -> None:
    quiet_libraries()
    torch.set_num_threads(1)
    cfg = OmegaConf.load(f"{POLICY}/config.yaml")
    family = family_from_config(cfg.env)
    runs = {}
    for label, overrides in (("2.5 cm", None), ("5 cm", {"placed_thresh": 0.05})):
        torch.manual_seed(0)
        env = make_family_env(
            family,
            "test",
            seed=0,
            variant_overrides=overrides,
            reward_mode="normalized_dense",
            control_mode=cfg.env.control_mode,
            max_episode_steps=cfg.env.max_episode_steps,
        )
        actor, _ = load_policy(POLICY, env.observation_spec, env.action_spec, family=family.name)
        if overrides is None:
            print(f"Policy inputs: {list(actor.in_keys)}.\n")
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            runs[label] = [env.rollout(1000, actor, break_when_any_done=True, auto_reset=True) for _ in range(EPISODES)]
        env.close()
    print(f"`{POLICY}`, sampled actions, seed 0: the same episodes with the stages labelled at 2.5 cm and at 5 cm.\n")
    print(
        "| episode | steps (2.5 / 5 cm) | first step whose stage label differs | first differing action | first differing observation |"
    )
    print("|---|---|---|---|---|")
    for i, (a, b) in enumerate(zip(runs["2.5 cm"], runs["5 cm"])):
        n = min(len(a), len(b))
        stage = first(a["next", "stage"][:n].reshape(n, -1).ne(b["next", "stage"][:n].reshape(n, -1)).any(-1))
        action = first((a["action"][:n] - b["action"][:n]).abs().amax(-1) > 0)
        obs = first((a["observation"][:n] - b["observation"][:n]).abs().amax(-1) > 0)
        print(f"| {i} | {len(a)} / {len(b)} | {stage} | {action} | {obs} |")


if __name__ == "__main__":
    main()
