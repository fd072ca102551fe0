"""The tools built on the library: building a run from its Hydra config (``build``, ``factories``,
``validation``), the console apps (``cli``: drs-learn / drs-reuse; ``maze``, ``quickstart``, ``study``, ``bench``,
``evaluate``, ``comparison``, ``reporting``, ``probe``), the plain reference loop and the maze's analysis."""
