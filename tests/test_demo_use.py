"""How a run uses its demonstrations (``demos.stage_buffers``, ``demos.sac_share``), decided without a simulator:
:func:`drs_torchrl.data.demo_mix.plan_demo_use` on synthetic episodes."""

import pytest
import torch
from tensordict import TensorDict

from drs_torchrl.data.demo_mix import AUTO_SAC_SHARE, plan_demo_use
from drs_torchrl.runtime.errors import ConfigError


def episodes(action_dim: int | None = 4, n: int = 2, T: int = 5):
    eps = []
    for _ in range(n):
        state = TensorDict({"observation": torch.zeros(T, 3)}, batch_size=[T])
        ep = TensorDict({"observation": torch.zeros(T, 3), "state": state}, batch_size=[T])
        if action_dim is not None:
            ep["action"] = torch.zeros(T, action_dim)
        eps.append(ep)
    return eps


KW = dict(path="x.demos", action_dim=4, control_mode="pd_ee_delta_pos", root_keys=["observation"])


def test_auto_shares_the_batch_and_keeps_drs_demonstrations_out_of_the_stage_buffers():
    use = plan_demo_use(episodes(), **KW)
    assert (use.stage_buffers, use.sac_share) == (False, AUTO_SAC_SHARE)
    assert use.resolved == {"demos.stage_buffers": False, "demos.sac_share": AUTO_SAC_SHARE}
    assert any("the agent's own successes" in n for n in use.notes)


def test_auto_files_state_only_demonstrations_in_the_stage_buffers_and_says_why_it_shares_nothing():
    use = plan_demo_use(episodes(action_dim=None), **KW)
    assert (use.stage_buffers, use.sac_share) == (True, 0.0)
    assert use.resolved == {"demos.stage_buffers": True, "demos.sac_share": 0.0}
    assert any("holds states only" in n for n in use.notes)


def test_a_classifier_reward_keeps_its_demonstrations_and_shares_the_batch():
    use = plan_demo_use(episodes(), files_in_stage_buffers=False, **KW)
    assert (use.stage_buffers, use.sac_share) == (True, AUTO_SAC_SHARE)


def test_no_demonstrations_resolve_the_share_to_zero_and_leave_stage_buffers_auto():
    use = plan_demo_use(None, **KW)
    assert (use.stage_buffers, use.sac_share, use.resolved, use.notes) == (True, 0.0, {"demos.sac_share": 0.0}, [])


def test_an_explicit_share_is_taken_as_asked_and_resolves_nothing():
    use = plan_demo_use(episodes(), sac_share=0.5, stage_buffers=True, **KW)
    assert (use.stage_buffers, use.sac_share, use.resolved) == (True, 0.5, {})


def test_an_explicit_share_the_demonstrations_cannot_fill_is_refused():
    with pytest.raises(ConfigError, match="2-dimensional; this run acts with 4-dimensional"):
        plan_demo_use(episodes(action_dim=2), sac_share=0.25, **KW)
    with pytest.raises(ConfigError, match="a reward learned in this run"):
        plan_demo_use(episodes(), sac_share=0.25, learned=False, **KW)


def test_demonstrations_used_nowhere_are_refused():
    with pytest.raises(ConfigError, match="would not be used at all"):
        plan_demo_use(episodes(), sac_share=0, stage_buffers=False, **KW)
    # auto share that resolves to 0 for state-only demonstrations, with the stage buffers turned off
    with pytest.raises(ConfigError, match="demos.sac_share is 0.0: they would not be used"):
        plan_demo_use(episodes(action_dim=None), stage_buffers=False, **KW)


def test_a_share_given_wrong_is_named():
    with pytest.raises(ConfigError, match=r"demos.sac_share must be in \[0, 1\), got 1.5"):
        plan_demo_use(episodes(), sac_share=1.5, **KW)
