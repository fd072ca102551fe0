"""Stand-in (device check only): ManiSkill imports IPython.display for notebooks; never called in a state-only run."""
