"""The probe preview's lighting mode as the scene carries it for the node groups.

The node group "HHD Probe Lighting" (shaders/probe_nodes.py) reads the mode as a number from the
scene custom property `hhd_probe_mode` (a View Layer Attribute node): 0 plain SH, 1 the talk's
HLSH hemisphere, 2 HLSH + AO cone. The panel's enum `scene.hhd.probe_mode` (properties.py) is
mirrored there when it changes and when the preview is shown (shaders/probe_preview.py).
"""

#: scene custom property holding the mode as a number
MODE = "hhd_probe_mode"
#: the enum's identifiers (`scene.hhd.probe_mode`) → the number the node group reads
MODES = {"SH": 0, "HLSH": 1, "HLSH_CONE": 2}
#: the number of the enum's default, for a scene without the settings
DEFAULT_MODE = MODES["HLSH_CONE"]


def mirror(scene, mode: str) -> None:
    """Write enum identifier `mode` (a key of MODES) into `scene[MODE]` as its number."""
    scene[MODE] = MODES[mode]
