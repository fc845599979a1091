"""The channel specification: what each file of an atlas holds, and the Encoding interface. No bpy.

A `FileSpec` (one EXR per atlas) lists `Channel`s: EXR layers whose channels are
`<name>.<component>` (`Iz.R`, `Wa.V`, `Direction.X`, `SH4.G`, `Normal.Z`, `Coverage.V`). The
spec is the single source of
  * the EXR channel names, their order and storage type (`lightmap_files` writes them),
  * the sidecar's channel table (`{type, meaning}` per EXR channel),
  * the preview images and the node-group inputs that sample them (`files.preview`),
  * the channel tables of docs/format.md (`encoding.doc_tables`).
An `Encoding` turns radiance SH into the values of its file's channels, texel by texel; the
encode stage (`encoding.stage`) then fills texels without a bake value and packs the values.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: Storage types: half float, float32, or half unless a value exceeds half's range (one choice
#: per channel layer, recorded in the sidecar: values are never clipped).
HALF, FLOAT, HALF_OR_FLOAT = "half", "float", "half_or_float"

#: How the encode stage fills texels without a bake value of their own (outside charts, buried):
#: not at all; from the nearest chart texel (`dilate.Fill`); the same but buried texels no valid
#: texel of their own chart reaches set to 0 (the others take that texel's value: `TexelData.fill`).
NO_FILL, DILATE, DILATE_BURIED_BLACK = "none", "dilate", "dilate_buried_black"


@dataclass(frozen=True)
class Channel:
    """One layer of an EXR file: EXR channels `<name>.<component>` for each of `components`.

    dtype: HALF | FLOAT | HALF_OR_FLOAT;  meaning: the sidecar's text for each of its channels;
    fill: NO_FILL | DILATE | DILATE_BURIED_BLACK (see above);
    preview: key of the RGB preview image that shows it (`AtlasFiles.preview_image`), or None;
      one component is repeated into R, G, B, two are R, G with B = 0; a packed layer's shows
      its value unpacked (`unpack`: the direction as x, y, z, which a bilinear filter may blend);
    width: columns of the value an encoding returns for it, when they differ from the stored
      components (a unit vector of 3 stored as 2 octahedral coordinates);
    pack: `(M, width)` value -> `(M, len(components))` stored components, applied after filling;
    unpack: its inverse, `(M, len(components))` -> `(M, width)` (for the preview image);
    when: (setting, value): written only under that encoder setting (docs show it), or None.
    """

    name: str
    components: tuple[str, ...]
    dtype: str
    meaning: str
    fill: str = NO_FILL
    preview: str | None = None
    width: int | None = None
    pack: Callable[[np.ndarray], np.ndarray] | None = field(default=None, compare=False)
    unpack: Callable[[np.ndarray], np.ndarray] | None = field(default=None, compare=False)
    when: tuple[str, str] | None = None

    @property
    def exr_names(self) -> list[str]:
        return [f"{self.name}.{c}" for c in self.components]

    @property
    def value_width(self) -> int:
        """Columns of the value an encoding returns for this layer."""
        return self.width or len(self.components)

    def applies(self, settings) -> bool:
        """Written under `settings` (an object with the `when` setting as attribute)?"""
        return self.when is None or getattr(settings, self.when[0]) == self.when[1]


@dataclass(frozen=True)
class FileSpec:
    """One EXR file of an atlas: `<atlas name><suffix>`, listed under `key` in the sidecar's
    `files` and `channels`. `channels`: every layer it may hold, in file order."""

    key: str
    suffix: str
    channels: tuple[Channel, ...]

    @property
    def exr_names(self) -> list[str]:
        return [n for ch in self.channels for n in ch.exr_names]

    def channel(self, name: str) -> Channel:
        return next(ch for ch in self.channels if ch.name == name)

    def for_settings(self, settings) -> FileSpec:
        """The layers written under `settings` (see `Channel.when`)."""
        return FileSpec(self.key, self.suffix, tuple(ch for ch in self.channels if ch.applies(settings)))


@dataclass
class Encoded:
    """What `Encoding.encode` returns for N texels: `values` {layer name: `(N, value_width)`
    array} for every layer of its file, and `stats`: this call's partial statistics, combined
    over the calls of one atlas by `Encoding.summary`."""

    values: dict[str, np.ndarray]
    stats: dict


class Encoding(Protocol):
    """An encoding of radiance SH into the layers of one file.

    file: the FileSpec it writes (with the layers of its settings);
    settings: what the sidecar records under `encoder` (JSON-able dict);
    encode(sh `(N, 9, 3)` float32/64 world-space radiance SH, n_v `(N, 3)`) -> Encoded;
    summary(stats of each encode call, in order; texels encoded) -> the sidecar's statistics.
    """

    file: FileSpec
    settings: dict

    def encode(self, sh: np.ndarray, n_v: np.ndarray) -> Encoded: ...

    def summary(self, stats: list[dict], texels: int) -> dict: ...
