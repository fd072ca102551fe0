"""The one base class of the errors a user can fix: every console script (``console.console_script``) prints
such an error as one line and exits 2; any other exception is a bug and keeps its traceback."""


class UserError(Exception):
    """A problem the user can fix (a value, a path, a damaged file); its message names it and the fix."""


class ConfigError(UserError, ValueError):
    """A configuration value that cannot work, with the fix in its message."""
