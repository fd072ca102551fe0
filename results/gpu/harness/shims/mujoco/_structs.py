class _MjModelBodyViews:
    pass
