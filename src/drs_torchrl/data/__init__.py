"""Data plumbing of DrS: stage buffers, their sampler, and trajectory assembly."""

from drs_torchrl.data.stage_buffers import (
    TRAJ_STAGE_KEY,
    StageBuffers,
    StageSampler,
    TrajectoryAssembler,
    trajectory_stage,
    truncate_failed,
)

__all__ = [
    "TRAJ_STAGE_KEY",
    "StageBuffers",
    "StageSampler",
    "TrajectoryAssembler",
    "trajectory_stage",
    "truncate_failed",
]
