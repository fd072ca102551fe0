"""The run-time plumbing, apart from the RL library: the console (``console``), run directories (``rundir``: one writer,
atomic files), logging (``run_logger``), signals (``signals``), provenance (``provenance``), errors (``errors``), files
from elsewhere (``safe_files``) and the training state on disk (``checkpoint``)."""
