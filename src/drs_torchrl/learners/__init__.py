"""The reward-learning core (Algorithm 1 without the RL algorithm) and the paper's learned baselines."""

from drs_torchrl.learners.base import RewardLearner, plain_step
from drs_torchrl.learners.classifiers import (
    DemoDiscriminatorLearner,
    OfflineClassifierLearner,
    SuccessClassifierLearner,
)
from drs_torchrl.learners.drs import DrSLearner

__all__ = [
    "DemoDiscriminatorLearner",
    "DrSLearner",
    "OfflineClassifierLearner",
    "RewardLearner",
    "SuccessClassifierLearner",
    "plain_step",
]
