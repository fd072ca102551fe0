"""Stopping a run cleanly on SIGINT/SIGTERM (own code: TorchRL's trainers install no signal handling).

The loop installs a :class:`StopRequest` and stops at the next batch boundary; a checkpoint being written holds
the signals (:class:`signals_deferred`) and re-delivers them once it is complete; a background collector's
worker ignores SIGINT (:func:`worker_env`), so Ctrl-C reaches the trainer only.
"""

from __future__ import annotations

import os
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class StopRequest:
    """SIGINT/SIGTERM handler of the training loop: it records the request and the loop stops at the
    next batch boundary. Raising inside TorchRL/tensordict code (what Python's default SIGINT does) can
    leave library context managers in a broken state; a second SIGINT still forces KeyboardInterrupt."""

    def __init__(self):
        self.signum: int | None = None

    def __call__(self, signum, frame):
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum

    def __enter__(self) -> StopRequest:
        self._previous = {sig: signal.signal(sig, self) for sig in STOP_SIGNALS} if in_main_thread() else {}
        return self

    def __exit__(self, *exc) -> bool:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        return False


class signals_deferred:
    """Hold SIGINT/SIGTERM while a checkpoint is written; re-deliver them once it is complete."""

    def __enter__(self):
        self.pending: list[int] = []
        self.previous = {}
        if in_main_thread():
            for sig in STOP_SIGNALS:
                self.previous[sig] = signal.signal(sig, lambda signum, frame: self.pending.append(signum))
        return self

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(self.pending):
            signal.raise_signal(sig)  # to the handler in place again (the loop's stop request)
        return False


def worker_env(make_env):
    """Build the env in a background collector's worker process, which ignores SIGINT (Ctrl-C reaches the
    whole process group; the trainer decides how to stop)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.environ.get("DRS_QUIET_LIBRARIES") == "1":
        from drs_torchrl.runtime.console import quiet_libraries

        quiet_libraries()
    return make_env()
