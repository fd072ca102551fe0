"""The tools built on the library and its runs, apart from the training path: studies (``study``, ``study_cluster``:
drs-study), speed (``bench``, ``plain_loop``: drs-bench), the first command (``quickstart``), reports (``comparison``,
``reporting``: drs-compare, drs-plot), reward probes (``probe``), demonstrations (``demos``: drs-demos) and the maze's
analysis (``maze_analysis``)."""
