"""Run a drs-torchrl app by name on the device machine (no console scripts there): python3 app.py learn_main ARGS."""

import sys

if __name__ == "__main__":  # collector workers re-import this file: they must not run the app
    from drs_torchrl.apps import cli as apps

    getattr(apps, sys.argv.pop(1))()
