"""ManiSkill task variants that drs-torchrl registers: the parametrised envs behind the task families.

DrS (Sec. 3) learns a reward on the training variants of a task family and reuses it on held-out
ones. These envs take a pool of variants and draw one per episode (``pool.py``):

* ``PickCubeSized-v1`` / ``PickObject-v1`` (``pick.py``): pick-and-place with cubes of several
  sizes / objects of several primitive shapes, any of ManiSkill's asset-free arms (Appendix A);
* ``StackCubeSized-v1`` (``stack_cube.py``) and ``PlaceSphereSized-v1`` (``place_sphere.py``);
* ``RotateValveVariants-v1`` (``valve.py``): ManiSkill's RotateValve levels 0-4 in one scene;
* ``PickSingleYCBSplit-v1``, ``TurnFaucetSplit-v1``, ``OpenCabinetDoorSplit-v1`` (``assets.py``):
  the paper's asset-backed families, restricted to a split's models (assets must be downloaded).

Importing this package registers them with ManiSkill.
"""

from drs_torchrl.envs.variants import assets, pick, place_sphere, stack_cube, valve  # noqa: F401
