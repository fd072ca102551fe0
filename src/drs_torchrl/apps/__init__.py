"""The training path's apps: a run built from its Hydra config (``build``, ``factories``, ``schema``, ``validation``,
``overrides``, ``hydra_record``), drs-learn / drs-reuse (``cli``), drs-eval (``evaluate``) and drs-maze (``maze``).
The tools built on them live in :mod:`drs_torchrl.tools`, the run-time plumbing in :mod:`drs_torchrl.runtime`."""
