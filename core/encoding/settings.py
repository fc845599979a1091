"""The encoder settings a bake or a re-encode uses. No bpy.

`model` picks the encoding (`encoding.registry`); the other fields are the options of the HHD/AHD
encoding's fit (see `core.hhd.encode`). The sidecar records `kwargs()` under `encoder`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from ..hhd import GOLDEN_ITERATIONS

#: The values `direction` and `ambient` take (`core.hhd.encode`).
DIRECTIONS = ("searched", "optimal_linear")
AMBIENTS = ("luminance", "rgb")


@dataclass
class EncoderSettings:
    """model: an encoding of `registry.ENCODINGS` ("hhd", "ahd"); direction, ambient, phi_search,
    golden_iterations: keyword arguments of `hhd.encode` (see there)."""

    model: str = "hhd"
    direction: str = "searched"
    ambient: str = "luminance"
    phi_search: bool = False
    golden_iterations: int = GOLDEN_ITERATIONS

    def kwargs(self) -> dict:
        return asdict(self)
