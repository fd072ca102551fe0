"""Demonstrations in the RL batch (beyond the paper, RLPD-style; ``demos.sac_share``, ``demos.stage_buffers``).

Phase 1 can draw a share of every SAC batch from the demonstrations' transitions, rewarded at sampling by the
current learned reward like every other sample, and (the recipe, ``docs/recipe.md``) keep them out of the stage
buffers so that the discriminators' positives are the agent's own successes. Own code: TorchRL's
``OfflineToOnlineReplayBuffer`` mixes two buffers by a ratio, but here the share's resolution (``auto``) depends
on what the demonstrations hold, and both parts must pass through the learned reward of the moment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, ReplayBuffer

from drs_torchrl.runtime.errors import ConfigError

# demos.sac_share=auto (the default): this share of every SAC batch from the demonstrations where they carry
# the agent's actions; the best of issue 12's phase-1 comparison on pick_cube (results/demos_compare/pick_cube/)
AUTO_SAC_SHARE = 0.25


def requested_sac_share(raw) -> float | None:
    """``demos.sac_share`` as asked: a number in [0, 1), or None for ``auto``."""
    if raw is None:
        return 0.0
    if isinstance(raw, str) and raw.strip().lower() == "auto":
        return None
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise ConfigError(f"demos.sac_share must be auto or a number in [0, 1), got {raw!r}; e.g. demos.sac_share=0.25")
    if not 0 <= float(raw) < 1:
        raise ConfigError(f"demos.sac_share must be in [0, 1), got {raw}")
    return float(raw)


def carries_actions(demos, action_dim: int) -> bool:
    """The demonstrations hold the states and the agent's own (same-sized) actions."""
    ep = demos[0]
    return "action" in ep.keys() and "state" in ep.keys() and int(ep["action"].shape[-1]) == int(action_dim)


def share_problems(demos, path, action_dim: int, control_mode: str, root_keys, learned: bool) -> list[str]:
    """Why the demonstrations cannot fill a share of the SAC batch (empty when they can)."""
    if not learned or not demos:
        return [
            "demos.sac_share needs demonstrations (demos.path) and a reward learned in this run "
            "(drs-learn reward=drs|vice_raq|oril|gail), which rewards them at sampling"
        ]
    if "action" not in demos[0].keys() or "state" not in demos[0].keys():
        return [
            f"demos.sac_share: {path} holds states only; SAC needs the agent's actions and "
            "the states they were taken in (drs-demos records them in the agent's controller, as does --from-policy)"
        ]
    have = int(demos[0]["action"].shape[-1])
    if have != int(action_dim):
        return [
            f"demos.sac_share: the actions in {path} are {have}-dimensional; this run acts with "
            f"{action_dim}-dimensional {control_mode} commands. Record the demonstrations in the agent's controller "
            f"(drs-demos --control-mode {control_mode}, the default, or drs-demos --from-policy), or set demos.sac_share=0"
        ]
    missing = [k for k in root_keys if k not in demos[0].get("state").keys()]
    if missing:
        return [f"demos.sac_share: the demonstrations' states lack {missing}, which SAC reads"]
    return []


@dataclass
class DemoUse:
    """How a run uses its demonstrations: filed into the top stage buffer (Algorithm 1, line 3) and/or a share of
    every SAC batch; ``resolved`` holds what an ``auto`` setting chose (by dotted key, recorded in config.yaml),
    ``notes`` says why."""

    stage_buffers: bool = True
    sac_share: float = 0.0
    resolved: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def plan_demo_use(
    demos,
    *,
    stage_buffers="auto",
    sac_share="auto",
    path=None,
    files_in_stage_buffers: bool = True,
    learned: bool = True,
    action_dim: int = 0,
    control_mode: str | None = None,
    root_keys=(),
) -> DemoUse:
    """``demos.stage_buffers`` and ``demos.sac_share`` resolved for ``demos`` (None: none loaded). ``auto`` shares
    :data:`AUTO_SAC_SHARE` of each batch where the demonstrations carry the agent's actions and a reward ``learned``
    in this run rewards them, else 0 (saying why); for DrS a share keeps them out of the stage buffers (the recipe,
    docs/recipe.md), so the discriminators' positives are the agent's own successes. Raises :class:`ConfigError` for
    an asked share the demonstrations cannot fill, or demonstrations that would not be used at all."""
    asked = requested_sac_share(sac_share)
    use = DemoUse()
    if stage_buffers != "auto":
        use.stage_buffers = bool(stage_buffers)
    elif demos:  # (with nothing to file, auto stays auto: a fresh run from this config is refused nothing)
        use.stage_buffers = not (files_in_stage_buffers and asked != 0 and carries_actions(demos, action_dim))
        use.resolved["demos.stage_buffers"] = use.stage_buffers
        use.notes.append(
            f"demos.stage_buffers=auto -> {str(use.stage_buffers).lower()}: "
            + (
                "the demonstrations go into the top stage buffer (the paper's Algorithm 1, line 3)"
                if use.stage_buffers
                else "the demonstrations feed the SAC batch only; the discriminators' positives are the agent's own "
                "successes"
            )
        )
    if asked is None and not demos:  # auto, and no demonstrations (or no reward learned here): nothing to share
        use.resolved["demos.sac_share"] = 0.0
        return use
    if asked != 0:
        problems = share_problems(demos, path, action_dim, control_mode, root_keys, learned)
        if asked is not None and problems:
            raise ConfigError(problems[0])
        use.sac_share = asked if asked is not None else (0.0 if problems else AUTO_SAC_SHARE)
        if asked is None:
            use.resolved["demos.sac_share"] = use.sac_share  # recorded: a resume keeps this run's choice
            use.notes.append(
                f"demos.sac_share=auto -> {use.sac_share:g}: "
                + (
                    problems[0]
                    if problems
                    else f"a share of every SAC batch from the {len(demos)} demonstrations' transitions "
                    "(beyond the paper: demos.sac_share=0 is its phase 1; results/demos_compare/pick_cube/)"
                )
            )
    if demos and use.sac_share == 0 and use.stage_buffers is False:
        shown = use.resolved.get("demos.sac_share", sac_share)
        raise ConfigError(
            f"demos.stage_buffers=false keeps the demonstrations out of the stage buffers, and demos.sac_share "
            f"is {shown}: they would not be used at all; set demos.sac_share=0.25 "
            "(demonstrations with the agent's actions: drs-demos' default) or demos.stage_buffers=true"
        )
    return use


def demo_transitions(demos, root_keys, next_keys) -> TensorDict:
    """The demonstrations as one flat TensorDict of transitions (``root_keys`` of the state, the action, and
    ``next_keys`` of the next state); an episode ends (terminates) on its last step when it succeeded."""
    rows = []
    for ep in demos:
        T = ep.shape[0]
        ends = torch.zeros(T, 1, dtype=torch.bool)
        ends[-1] = bool(ep["success"][-1])  # demonstrations end on success
        nxt = TensorDict({k: ep.get(k) for k in next_keys}, batch_size=[T])
        nxt.update(
            {
                "reward": torch.zeros(T, 1),
                "done": ends.clone(),
                "terminated": ends.clone(),
                "truncated": torch.zeros(T, 1, dtype=torch.bool),
            }
        )
        rows.append(
            TensorDict(
                {**{k: ep.get("state").get(k) for k in root_keys}, "action": ep.get("action"), "next": nxt},
                batch_size=[T],
            )
        )
    return torch.cat(rows, 0)


def demo_replay_buffer(demos, root_keys, reward, device) -> ReplayBuffer:
    """A replay buffer of the demonstrations' transitions whose sampling transform is the learned ``reward``."""
    next_keys = list(dict.fromkeys([*root_keys, *reward.reward_in_keys, "stage"]))
    data = demo_transitions(demos, root_keys, next_keys)
    buffer = ReplayBuffer(storage=LazyTensorStorage(data.shape[0], device=device), transform=reward)
    buffer.extend(data.to(device))
    return buffer
