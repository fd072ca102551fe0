"""TorchRL transforms of DrS: stage labelling (Eq. 2-3) and the learned reward (Eq. 4)."""
from drs_torchrl.transforms.reward import DrSReward, RewardCheckpointError, StageDiscriminators
from drs_torchrl.transforms.stages import StageIndicator, monotone_indicators, stage_index

__all__ = ["DrSReward", "RewardCheckpointError", "StageDiscriminators", "StageIndicator", "monotone_indicators", "stage_index"]
