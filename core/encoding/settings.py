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
#: The values `solve` takes: how an SG encoding fits its lobes (`encoding.sg`).
SOLVES = ("adhoc", "ls", "nnls")


@dataclass
class EncoderSettings:
    """model: an encoding of `registry.ENCODINGS` ("hhd", "ahd", "sh_l1", … "sg12"); direction,
    ambient, phi_search, golden_iterations: keyword arguments of `hhd.encode` (see there);
    solve: the SG encodings' fit, one of SOLVES (`encoding.sg`)."""

    model: str = "hhd"
    direction: str = "searched"
    ambient: str = "luminance"
    phi_search: bool = False
    golden_iterations: int = GOLDEN_ITERATIONS
    solve: str = "nnls"

    def kwargs(self) -> dict:
        """The fields as a dict; `solve` only for an SG model (the HHD fit takes no such
        argument, and the sidecars of the other models stay as they were)."""
        out = asdict(self)
        if not self.model.startswith("sg"):
            out.pop("solve")
        return out
