"""Colour constants shared by every stage. No bpy.

Linear RGB throughout is Blender's scene-linear Rec.709 (sRGB primaries, D65), so luminance is
the Rec.709 relative luminance: ITU-R BT.709-6, item 3.2 (Y = 0.2126 R + 0.7152 G + 0.0722 B).
"""

from __future__ import annotations

import numpy as np

#: Rec.709 relative luminance weights of linear RGB (ITU-R BT.709-6 §3.2): power of emitters
#: and HDRI pixels, the noise target's I_z, the luminance ambient weight, the sidecar's statistics.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
