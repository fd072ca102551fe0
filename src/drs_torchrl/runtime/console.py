"""What the command-line apps print: one line for a user's error, library chatter filtered, output that
survives a closed pipe.

* :func:`console_script` wraps every console script's entry function: a :class:`UserError` (a value, a
  path or a file the user can fix; the apps' own error classes derive from it), a Hydra composition error,
  a file that cannot be read or written and damaged YAML print ``PROG: error: ...`` in one line and exit 2;
  Ctrl-C outside a run's own handler exits 130; anything else is a bug: its traceback is printed and kept
  in a log file whose path the last line names, exit 1.
* :func:`quiet_libraries` hides messages that do not concern the user: ManiSkill's render-device and
  initial-pose warnings, TorchRL's storage-initialisation notices and its ``init_random_frames``
  rounding warning, and a few deprecation warnings of the stack, in this process and (through
  :func:`in_quiet_worker` / ``DRS_QUIET_LIBRARIES``) in its collector workers; :func:`library_prints`
  counts what a library prints (the motion planner's "screw plan failed"). ``logger.library_messages=true``
  (or ``DRS_LIBRARY_MESSAGES=1``) shows them again.
* :func:`at_least` is the ``type`` of the apps' count options (``--jobs``, ``--episodes``, ...): argparse
  then refuses ``--jobs 0`` naming the option, instead of a run that starts nothing and blames something else.
* :func:`survive_closed_output` makes ``sys.stdout``/``sys.stderr`` swallow a broken pipe: with
  ``drs-learn ... | tee log`` and Ctrl-C, ``tee`` dies first and every later write would raise
  ``BrokenPipeError``, which used to abort the run before its final save. Once a stream breaks,
  its file descriptor is pointed at ``/dev/null`` and the run carries on, saves, and exits with its
  own status.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import errno
import functools
import io
import logging
import os
import sys
import tempfile
import time
import traceback
import warnings


from drs_torchrl.config_dir import renamed_hint
from drs_torchrl.runtime.errors import UserError  # noqa: E402  (re-exported: the one base class of user errors)


def _library_user_errors() -> tuple[type, ...]:
    """Hydra's (a bad override, an unknown config option) and PyYAML's (damaged YAML; its marks name the file)."""
    found = []
    if "hydra.errors" in sys.modules:
        found.append(sys.modules["hydra.errors"].HydraException)
    if "yaml" in sys.modules:
        found.append(sys.modules["yaml"].YAMLError)
    return tuple(found)


def at_least(minimum: int):
    """An argparse ``type``: an integer >= ``minimum`` (argparse's error names the option and exits 2)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse


def one_line(text) -> str:
    """A library's multi-line message as one line (an indented list after "...:" joined by commas)."""
    lines = [ln.strip() for ln in str(text).split("Config search path")[0].splitlines()]
    parts: list[str] = []
    options: list[str] | None = None
    for line in lines:
        if not line or line.startswith(("full_key:", "object_type=", "Set the environment variable HYDRA_FULL_ERROR")):
            continue
        if options is not None and " " not in line:
            options.append(line)
            continue
        if options:
            parts[-1] += " " + ", ".join(options)
        options = [] if line.endswith(":") else None
        parts.append(line)
    if options:
        parts[-1] += " " + ", ".join(options)
    return "".join(
        p + ("" if i == len(parts) - 1 else (" " if p.endswith((".", ":", ";", ",")) else "; "))
        for i, p in enumerate(parts)
    )


_OS_HINTS = {
    errno.EEXIST: "a file is where a folder is needed: give another path",
    errno.ENOTDIR: "part of the path is a file, not a folder: give another path",
    errno.EISDIR: "it is a folder: give a file name",
    errno.EACCES: "give a path you may write (or read)",
    errno.EPERM: "give a path you may write (or read)",
    errno.EROFS: "give a path on a writable filesystem",
    errno.ENOENT: "check the path",
}


def user_error_message(exc: BaseException) -> str | None:
    """The one-line message of an error the user caused, or None for a bug."""
    if isinstance(exc, UserError):  # written for the user: as it is
        return str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)
    if isinstance(exc, _library_user_errors()):
        cause = exc.__cause__  # Hydra's "Could not override 'x'" is caused by OmegaConf's "Key 'x' is not in struct"
        return (
            one_line(exc)
            + (f" ({one_line(cause)})" if cause is not None and type(cause).__module__.startswith("omegaconf") else "")
            + _quoting_hint(exc)
            + renamed_hint(str(exc))
        )
    if isinstance(exc, ValueError) and str(exc).startswith("Config group override must be"):  # Hydra: GROUP=null
        hint = "a config group (env=, algo=, reward=, ...) takes one of its options' names (--help lists them)"
        return f"{one_line(exc)}: {hint}"
    if isinstance(exc, OSError) and (exc.filename or exc.errno in (errno.ENOSPC, errno.EDQUOT)):
        msg = f"{exc.filename}: {exc.strerror or exc}" if exc.filename else str(exc.strerror or exc)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT) and exc.filename:
            from drs_torchrl.runtime.rundir import free_bytes

            return f"{msg} ({free_bytes(exc.filename) / 2**20:.1f} MiB free there); free some space or write elsewhere"
        return f"{msg}; {_OS_HINTS[exc.errno]}" if exc.errno in _OS_HINTS else msg
    gym_error = getattr(sys.modules.get("gymnasium.error"), "Error", None)
    if gym_error is not None and isinstance(exc, gym_error):
        msg = one_line(exc).rstrip(".")
        return f"gymnasium: {msg}" + ("" if "Did you mean" in msg else _close_env_ids(msg))
    return None


def _quoting_hint(exc: BaseException) -> str:
    """For Hydra's override-grammar errors on a value with characters its grammar does not take unquoted
    (non-ASCII letters, ``,`` ``=`` ``[`` ...): how to quote it, shell quotes included."""
    import re

    if "override_grammar" not in str(exc) and "LexerNoViableAlt" not in str(exc):
        return ""
    m = re.search(r"(\S+?)=(.*?)(?:;|$)", one_line(exc).split(": ", 1)[-1])
    if not m:
        return ""
    key, value = m.group(1).lstrip("'\"+~"), m.group(2).strip().strip("'\"")
    return (
        f"; a value with such characters (a path, say) must be quoted for Hydra inside the shell's quotes: "
        f"'{key}=\"{value}\"'"
    )


def _close_env_ids(message: str) -> str:
    """The registered env ids close to the one quoted in gymnasium's message, as a hint."""
    import difflib
    import re

    m = re.search(r"`([^`]+)`", message)
    if not m:
        return ""
    registry = sys.modules["gymnasium"].registry
    close = difflib.get_close_matches(m.group(1), list(registry), n=3, cutoff=0.5)
    return (
        f"; did you mean {' or '.join(close)}?"
        if close
        else "; see the ids ManiSkill registers: python -c "
        '"import gymnasium, mani_skill.envs; print(sorted(gymnasium.registry))"'
    )


def crash_log_dir() -> str:
    """Where a bug's traceback is kept: ``$DRS_LOG_DIR``, else ``<tmp>/drs-torchrl``."""
    return os.environ.get("DRS_LOG_DIR") or os.path.join(tempfile.gettempdir(), "drs-torchrl")


def report_failure(prog: str, exc: BaseException) -> int:
    """Print ``exc`` as a user error (one line, returns 2) or as a bug (traceback and its log file, returns 1)."""
    msg = user_error_message(exc)
    if msg is not None:
        print(f"{prog}: error: {msg}", file=sys.stderr, flush=True)
        return 2
    text = "".join(traceback.format_exception(exc))
    sys.stderr.write(text)
    try:
        os.makedirs(crash_log_dir(), exist_ok=True)
        log = os.path.join(crash_log_dir(), f"{prog}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.log")
        with open(log, "w") as f:
            f.write(f"{' '.join(sys.argv)}\n\n{text}")
        where = f"the traceback above is kept in {log}"
    except OSError:
        where = "the traceback is above"
    print(
        f"{prog}: internal error ({type(exc).__name__}), a bug rather than your input; {where}: please report it",
        file=sys.stderr,
        flush=True,
    )
    return 1


def console_script(prog: str, *, quiet: bool = True):
    """Decorator of a console script's entry function (see the module docstring). ``quiet``: filter the
    libraries' messages now (Hydra apps pass False and decide once their config says ``logger.library_messages``)."""

    def wrap(fn):
        @functools.wraps(fn)
        def main(*args, **kwargs):
            survive_closed_output()
            if quiet and not library_messages_requested():
                quiet_libraries()
            hydra_errors = os.environ.get("HYDRA_FULL_ERROR")
            os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra re-raises instead of printing its own multi-line report
            try:
                return fn(*args, **kwargs)
            except KeyboardInterrupt:
                print(f"{prog}: interrupted", file=sys.stderr)
                sys.exit(130)
            except Exception as exc:  # noqa: BLE001 (the one place every failure of a command is reported)
                sys.exit(report_failure(prog, exc))
            finally:
                if hydra_errors is None:
                    os.environ.pop("HYDRA_FULL_ERROR", None)
                else:
                    os.environ["HYDRA_FULL_ERROR"] = hydra_errors

        main.console_script = prog
        return main

    return wrap


# (logger name, level below which its records are dropped)
_LOGGERS = {
    "mani_skill ": logging.ERROR,
    "mani_skill": logging.ERROR,
    "torchrl": logging.WARNING,
}  # ManiSkill's name ends in a space
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


class _AtLeast(logging.Filter):
    """Drops a logger's records below ``level`` (a filter stays when the library sets its logger's level on import)."""

    def __init__(self, level: int):
        super().__init__()
        self.level = level

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= self.level


def quiet_libraries() -> None:
    """Filter the libraries' routine warnings and notices for this process (and its workers)."""
    os.environ.setdefault("RL_WARNINGS", "0")  # TorchRL's own switch, read by collector workers too
    os.environ["DRS_QUIET_LIBRARIES"] = "1"  # background collector workers call this again (in_quiet_worker)
    os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")
    for name, level in _LOGGERS.items():
        logger = logging.getLogger(name)
        if not any(isinstance(f, _AtLeast) for f in logger.filters):
            logger.addFilter(_AtLeast(level))
    for msg in _WARNINGS:
        warnings.filterwarnings("ignore", message=msg)
    warnings.filterwarnings(
        "ignore", category=DeprecationWarning, module=r"(gymnasium|mani_skill|sapien|torchrl|tensordict)"
    )


def in_quiet_worker(make, *args, **kwargs):
    """``make(*args, **kwargs)`` after applying the parent's filter (:func:`quiet_libraries`) in this process: wrap
    a collector worker's env factory with ``functools.partial(in_quiet_worker, factory)``."""
    if os.environ.get("DRS_QUIET_LIBRARIES") == "1":
        quiet_libraries()
    return make(*args, **kwargs)


@contextlib.contextmanager
def library_prints(counts: collections.Counter):
    """Inside: what a library prints to stdout is counted in ``counts`` (line -> times), not shown, unless
    the user asked for the libraries' messages."""
    if library_messages_requested():
        yield counts
        return
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            yield counts
    finally:
        counts.update(ln.strip() for ln in buf.getvalue().splitlines() if ln.strip())


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
