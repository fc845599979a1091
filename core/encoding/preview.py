"""What each EEVEE preview mode samples: layers of the channel spec. No bpy.

Each layer is shown through its preview image (`Channel.preview`, an RGB EXR the writer stages
beside the files) and feeds the node-group input of the same name (`Channel.name`):
shaders/node_groups.py names its inputs from here, shaders/preview.py links image to input.
"""

from __future__ import annotations

from .hhd import DIRECTION, IZ, WA
from .raw import SH_LAYERS
from .spec import Channel

MODES: dict[str, tuple[Channel, ...]] = {
    "HHD": (IZ, WA, DIRECTION),
    "AHD": (IZ, WA, DIRECTION),
    "L1": SH_LAYERS[:4],
    "L2": SH_LAYERS,
    "SCALAR": (IZ,),
}


def sampled(mode: str) -> tuple[Channel, ...]:
    """The layers preview mode `mode` ('HHD', 'AHD', 'L1', 'L2', 'SCALAR') samples, in input order."""
    return MODES[mode]
