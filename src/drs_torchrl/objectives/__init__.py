"""Losses of DrS beyond TorchRL's SAC: the per-stage discriminator loss."""

from drs_torchrl.objectives.discriminator import DiscriminatorLoss

__all__ = ["DiscriminatorLoss"]
