"""Demonstrations for the top stage buffer (Algorithm 1, line 3: ``B_N <- B_N U D``).

DrS optionally seeds the top stage buffer with successful trajectories. The reward reads only next
states, so a demonstration is a sequence of states and the demonstrator may use another controller
than the RL agent. Three sources, one module each, all writing the format of :mod:`.store`:

* :mod:`.planner`: ManiSkill's motion-planning solvers (``drs-demos``), in joint-position control or
  replayed in the agent's controller.
* :mod:`.policy`: a trained ``drs-learn``/``drs-reuse`` policy's successful episodes
  (``drs-demos --from-policy RUN``), as the paper's demonstrations (Appendix A: "The demonstrations
  are from a trained RL agent"); works for families without a solver.
* :mod:`.maniskill_h5`: ManiSkill's own trajectory files (``X.h5`` + ``X.json``, e.g. its
  downloadable datasets), replayed in the family's env (``drs-demos --from-h5``).

The command line is :mod:`drs_torchrl.tools.demos`.
"""

from drs_torchrl.demos.maniskill_h5 import load_maniskill_h5
from drs_torchrl.demos.planner import record_demos
from drs_torchrl.demos.policy import record_policy_demos
from drs_torchrl.demos.store import (
    DEMO_FORMAT,
    DEMO_VERSION,
    DemoError,
    DemosOutTakenError,
    check_demos,
    check_demos_out,
    free_demos_path,
    leftover_notes,
    leftover_saves,
    load_demos,
    restage_demos,
    save_demos,
    variant_mismatches,
)

__all__ = [
    "DEMO_FORMAT",
    "DEMO_VERSION",
    "DemoError",
    "DemosOutTakenError",
    "check_demos",
    "check_demos_out",
    "free_demos_path",
    "leftover_notes",
    "leftover_saves",
    "load_demos",
    "load_maniskill_h5",
    "record_demos",
    "record_policy_demos",
    "restage_demos",
    "save_demos",
    "variant_mismatches",
]
