"""Blender reads the EXRs `exr.write_file` writes (ZIP blocks compressed by `zip_exr`, not by
OpenEXR) to the pixels it reads from the OpenEXR binding's writer's file of the same channels:
a preview image (R, G, B, half or float, as `lightmap_files.stage_preview` writes it) loaded
with `bpy.data.images.load`. Blender's own OpenEXR is the reader here, not the binding."""

import numpy as np
import OpenEXR
import pytest

from hhd_lightmapper.core.files import exr


def loaded_pixels(path) -> np.ndarray:
    """The image at `path` as Blender loads it: `(height, width, 4)` float32 RGBA, rows bottom-up."""
    import bpy

    image = bpy.data.images.load(str(path))
    try:
        w, h = image.size
        pixels = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(pixels)
        return pixels.reshape(h, w, 4)
    finally:
        bpy.data.images.remove(image)


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
@pytest.mark.parametrize("shape", [(1, 1), (37, 1), (61, 45)])
def test_blender_loads_a_preview_as_it_loads_the_binding_s_file(tmp_path, dtype, shape):
    rng = np.random.default_rng(shape[0])
    rgb = {c: exr.to_exr_rows(rng.uniform(0.0, 4.0, size=shape).astype(dtype)) for c in "RGB"}
    rgb["G"][0, 0] = 0.0
    ours, theirs = tmp_path / "ours.exr", tmp_path / "binding.exr"
    exr.write_file(ours, rgb, {"hhdPreviewValue": "unpacked"}, threads=2)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "hhdPreviewValue": "unpacked"}
    OpenEXR.File(header, dict(rgb)).write(str(theirs))  # (it replaces the dict's arrays by Channels)
    got, expected = loaded_pixels(ours), loaded_pixels(theirs)
    assert got.tobytes() == expected.tobytes()
    stored = np.stack([rgb[c][::-1].astype(np.float32) for c in "RGB"], -1)
    assert np.array_equal(got[..., :3], stored)  # and the values stored, rows bottom-up
