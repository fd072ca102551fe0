"""TorchRL transforms of DrS: stage labelling (Eq. 2-3), the learned reward (Eq. 4) and the classifier
reward of the paper's learned baselines (VICE-RAQ, ORIL, GAIL), and a learned reward on transitions (s, a)."""

from drs_torchrl.transforms.classifier_reward import Classifier, ClassifierReward
from drs_torchrl.transforms.reward import DrSReward, RewardCheckpointError, StageDiscriminators, load_reward
from drs_torchrl.transforms.state_action_reward import StateActionReward
from drs_torchrl.transforms.stages import SemiSparseReward, StageIndicator, monotone_indicators, stage_index

__all__ = [
    "Classifier",
    "ClassifierReward",
    "DrSReward",
    "RewardCheckpointError",
    "SemiSparseReward",
    "StageDiscriminators",
    "StageIndicator",
    "StateActionReward",
    "load_reward",
    "monotone_indicators",
    "stage_index",
]
