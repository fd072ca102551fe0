def _absent(*args, **kwargs):
    raise RuntimeError("IPython is not installed on this machine (device-check stand-in)")


display = _absent


class HTML:
    def __init__(self, *args, **kwargs):
        _absent()
