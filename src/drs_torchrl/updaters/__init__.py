"""RL algorithms as updaters of the loop of Algorithm 1 (:mod:`drs_torchrl.loop`): each is one module and one
``conf/algo`` file whose ``updater`` node names its builder."""

from drs_torchrl.updaters.base import NonFiniteError, UpdateBudget, Updater, backward_and_step
from drs_torchrl.updaters.dqn import DQNUpdater, make_dqn_updater
from drs_torchrl.updaters.ppo import PPOUpdater, make_ppo_updater
from drs_torchrl.updaters.sac import SACUpdater, make_sac_updater

__all__ = [
    "NonFiniteError",
    "UpdateBudget",
    "Updater",
    "backward_and_step",
    "SACUpdater",
    "make_sac_updater",
    "DQNUpdater",
    "make_dqn_updater",
    "PPOUpdater",
    "make_ppo_updater",
]
