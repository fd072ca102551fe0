"""Stand-in (device check only): pytorch_kinematics.mjcf imports mujoco at import; MJCF parsing is never called here."""


class _Absent:
    def __init__(self, *args, **kwargs):
        raise RuntimeError("mujoco is not installed on this machine (device-check stand-in)")

    @classmethod
    def from_xml_string(cls, *args, **kwargs):
        cls()


class mjtJoint:
    mjJNT_HINGE = 3
    mjJNT_SLIDE = 2


MjModel = _Absent
