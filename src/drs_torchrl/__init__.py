"""drs-torchrl: DrS (Dense reward learning from Stages, Mu et al., ICLR 2024) on TorchRL."""

__version__ = "0.1.0"
