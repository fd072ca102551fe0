"""What the command-line apps print: library chatter filtered, and output that survives a closed pipe.

* :func:`quiet_libraries` hides messages that do not concern the user: ManiSkill's render-device and
  initial-pose warnings, TorchRL's storage-initialisation notices and its ``init_random_frames``
  rounding warning, and a few deprecation warnings of the stack. ``logger.library_messages=true``
  (or ``DRS_LIBRARY_MESSAGES=1``) shows them again.
* :func:`survive_closed_output` makes ``sys.stdout``/``sys.stderr`` swallow a broken pipe: with
  ``drs-learn ... | tee log`` and Ctrl-C, ``tee`` dies first and every later write would raise
  ``BrokenPipeError``, which used to abort the run before its final save. Once a stream breaks,
  its file descriptor is pointed at ``/dev/null`` and the run carries on, saves, and exits with its
  own status.
"""
from __future__ import annotations

import errno
import logging
import os
import sys
import warnings

# (logger name, level below which its records are dropped)
_LOGGERS = {"mani_skill ": logging.ERROR, "mani_skill": logging.ERROR, "torchrl": logging.WARNING}  # ManiSkill's name ends in a space
# warning messages (regexes, matched at the start) that are the libraries' business, not the user's
_WARNINGS = [
    r"init_random_frames .* is not exactly a multiple of frames_per_batch",
    r".*env\.\w+ to get variables from other wrappers is deprecated",
    r".*The reward returned by `step\(\)` must be a float",
    r"No initial pose set for actor builder",
    r"Requested to use render device",
    r".*torch\._dynamo\.config\.inline_inbuilt_nn_modules",
    r".*TypedStorage is deprecated",
]


def library_messages_requested(cfg=None) -> bool:
    """True when the user asked to see the libraries' messages (config or environment)."""
    if os.environ.get("DRS_LIBRARY_MESSAGES", "0") not in ("", "0", "false"):
        return True
    try:
        return bool(cfg is not None and cfg.logger.get("library_messages", False))
    except AttributeError:
        return False


def quiet_libraries() -> None:
    """Filter the libraries' routine warnings and notices for this process (and its workers)."""
    os.environ.setdefault("RL_WARNINGS", "0")  # TorchRL's own switch, read by collector workers too
    os.environ["DRS_QUIET_LIBRARIES"] = "1"  # background collector workers call this again
    os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")
    try:  # ManiSkill and TorchRL set their loggers' levels when imported: import them first, then lower them
        import mani_skill.utils.logging_utils  # noqa: F401
        import torchrl  # noqa: F401
    except ImportError:
        pass
    for name, level in _LOGGERS.items():
        logging.getLogger(name).setLevel(level)
    for msg in _WARNINGS:
        warnings.filterwarnings("ignore", message=msg)
    warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"(gymnasium|mani_skill|sapien|torchrl|tensordict)")


class _PipeSafeStream:
    """A text stream that turns writes to a closed pipe into no-ops (see module docstring)."""

    def __init__(self, stream):
        self._stream = stream
        self.broken = False

    def _break(self) -> None:
        self.broken = True
        try:
            fd = self._stream.fileno()
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, fd)  # pending and later writes of the real stream go nowhere, quietly
            os.close(devnull)
        except (OSError, ValueError):
            pass

    def _guard(self, fn, *args):
        if self.broken:
            return None
        try:
            return fn(*args)
        except BrokenPipeError:
            self._break()
        except OSError as exc:
            if exc.errno not in (errno.EPIPE, errno.EIO):
                raise
            self._break()
        except ValueError:  # "I/O operation on closed file"
            self.broken = True
        return None

    def write(self, text):
        out = self._guard(self._stream.write, text)
        return len(text) if out is None else out

    def flush(self):
        self._guard(self._stream.flush)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def survive_closed_output() -> None:
    """Wrap ``sys.stdout`` and ``sys.stderr`` (once) so that a closed pipe cannot stop the process."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is not None and not isinstance(stream, _PipeSafeStream):
            setattr(sys, name, _PipeSafeStream(stream))
