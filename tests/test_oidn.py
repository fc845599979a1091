"""core/post/denoise/oidn.py: Open Image Denoise's RTLightmap filter through Blender's own OIDN library.

The library is the one the bpy module ships (bpy/lib/, found without importing bpy); the weights
come from tools/fetch_oidn_weights.py (run here if missing: hash-checked, cached). Either absent:
the tests skip with the reason.
"""

import importlib.util
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core.post.denoise import oidn


def bpy_library_dirs() -> list[Path]:
    """Where the bpy module keeps Blender's shared libraries (bpy/lib), without importing bpy."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return []
    return [Path(d) / "lib" for d in spec.submodule_search_locations]


@pytest.fixture(scope="module")
def library() -> Path:
    path = oidn.find_library(bpy_library_dirs())
    if path is None:
        pytest.skip(f"no Open Image Denoise library in the bpy module ({bpy_library_dirs()})")
    return path


@pytest.fixture(scope="module")
def denoiser(library) -> oidn.Denoiser:
    import fetch_oidn_weights  # tools/ (conftest puts it on sys.path)

    try:
        fetch_oidn_weights.fetch()
    except (SystemExit, subprocess.CalledProcessError, OSError) as e:
        pytest.skip(f"OIDN lightmap weights unavailable (tools/fetch_oidn_weights.py: {e})")
    d = oidn.Denoiser(library, threads=4)
    yield d
    d.close()


def smooth(h: int, w: int, channels: int) -> np.ndarray:
    """A smooth HDR image (H, W, C) float32 in about [0.2, 1.8]: low-frequency waves per channel."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    waves = [1.0 + 0.6 * np.sin(x / (19 + 4 * c) + c) * np.cos(y / (23 - 3 * c)) + 0.2 * x / w for c in range(channels)]
    return np.stack(waves, axis=-1).astype(np.float32)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a.astype(np.float64) - b) ** 2)))


def test_library_versions_and_missing_weights_fail_the_commit(denoiser):
    """Blender's OIDN (2.5.0 in bpy 5.3, 2.3.0 in bpy 4.2) has the RTLightmap filter but not its
    weights: without them the commit fails, which is why the extension ships them."""
    assert denoiser.version.startswith("2.")
    lib, device = denoiser._lib, denoiser._device
    image = np.ones((8, 8, 3), np.float32)
    out = np.empty_like(image)
    filt = lib.oidnNewFilter(device, b"RTLightmap")
    assert filt
    try:
        lib.oidnSetSharedFilterImage(filt, b"color", image.ctypes.data, 3, 8, 8, 0, 0, 0)
        lib.oidnSetSharedFilterImage(filt, b"output", out.ctypes.data, 3, 8, 8, 0, 0, 0)
        lib.oidnCommitFilter(filt)
        with pytest.raises(oidn.DenoiserError, match="unsupported combination of input features"):
            denoiser._check("commit without weights")
    finally:
        lib.oidnReleaseFilter(filt)
    assert np.isfinite(denoiser.denoise(image)).all()  # with them it runs on the same device


def test_noisy_smooth_hdr_image_comes_out_much_closer_to_the_clean_one(denoiser):
    """Gaussian noise (sigma 0.15, ~15% of the mean) on a smooth image: the filter should remove
    most of it. The RMSE ratio (denoised / noisy) measured 0.125 with OIDN 2.5.0 and 2.3.0 alike
    (the weights decide it); a 3x3 box blur gets 0.34, a 5x5 one 0.20. The bound 0.2 demands better
    than a 5x5 blur and leaves 1.6x room for other CPUs' float order and OIDN versions."""
    rng = np.random.default_rng(1)
    clean = smooth(128, 160, 3)
    noisy = (clean + rng.normal(0.0, 0.15, clean.shape)).clip(0.0, None).astype(np.float32)
    out = denoiser.denoise(noisy, input_scale=1.0)
    assert out.shape == clean.shape and out.dtype == np.float32
    ratio = rmse(out, clean) / rmse(noisy, clean)
    assert ratio < 0.2, ratio
    assert abs(out.mean() / clean.mean() - 1.0) < 0.02  # no visible bias on a smooth image


def test_one_and_two_channels_and_float64_input(denoiser):
    rng = np.random.default_rng(2)
    for c in (1, 2):
        clean = smooth(64, 64, c).astype(np.float64)
        noisy = clean + rng.normal(0.0, 0.15, clean.shape)
        out = denoiser.denoise(noisy)
        assert out.shape == (64, 64, c) and out.dtype == np.float32
        assert rmse(out, clean) < rmse(noisy, clean)


def test_directional_mode_stays_in_range_and_removes_noise(denoiser):
    """Normalised SH coefficients (L1 / L0) in [-1, 1] with noise sigma 0.2: the output stays in
    range (a few percent of slack) and is much closer to the clean coefficients (RMSE ratio
    measured 0.127; bound 0.25, as above)."""
    rng = np.random.default_rng(3)
    clean = (smooth(96, 96, 3) - 1.0).clip(-0.9, 0.9)
    noisy = (clean + rng.normal(0.0, 0.2, clean.shape)).clip(-1.0, 1.0).astype(np.float32)
    out = denoiser.denoise(noisy, directional=True)
    assert np.abs(out).max() < 1.05
    assert rmse(out, clean) < 0.25 * rmse(noisy, clean)


def test_black_stays_black_and_huge_values_stay_finite(denoiser):
    assert not denoiser.denoise(np.zeros((32, 48, 3), np.float32)).any()
    # black beside light: the network's floor (worst in the image's corner pixels) stays faint
    half = np.zeros((128, 128, 3), np.float32)
    half[:, 64:] = 1.0
    out = denoiser.denoise(half, input_scale=1.0)
    assert out[:, :56].mean() < 1e-3 and out[:, :56].max() < 0.2
    assert np.abs(out[:, 72:] - 1.0).max() < 0.1
    huge = denoiser.denoise(np.full((32, 48, 3), 1e6, np.float32))
    assert np.isfinite(huge).all()
    assert abs(huge.mean() / 1e6 - 1.0) < 0.05


def test_nan_and_inf_inputs_give_finite_output(denoiser):
    image = smooth(48, 48, 3)
    image[5, 7] = np.nan
    image[20, 30, 1] = np.inf
    image[40, 2, 2] = -np.inf
    out = denoiser.denoise(image)
    assert np.isfinite(out).all()
    assert np.isnan(image[5, 7]).all()  # the caller's array is not modified


def test_two_runs_are_bit_identical(denoiser):
    rng = np.random.default_rng(4)
    noisy = (smooth(80, 72, 3) + rng.normal(0.0, 0.2, (80, 72, 3))).clip(0.0, None).astype(np.float32)
    assert np.array_equal(denoiser.denoise(noisy), denoiser.denoise(noisy))


def test_rgba_is_refused_and_its_rgb_view_is_read_in_place(denoiser):
    rng = np.random.default_rng(5)
    rgba = np.ones((40, 56, 4), np.float32)
    rgba[..., :3] = smooth(40, 56, 3) + rng.normal(0.0, 0.1, (40, 56, 3)).clip(-0.2, 0.2)
    with pytest.raises(ValueError, match="1-3 channels"):
        denoiser.denoise(rgba)
    view = rgba[..., :3]  # 16-byte pixel stride
    assert view.strides[1] == 16
    assert np.array_equal(denoiser.denoise(view), denoiser.denoise(np.ascontiguousarray(view)))


def test_missing_library_or_weights_raise_unavailable(tmp_path, library, denoiser):
    assert oidn.find_library([tmp_path, tmp_path / "absent"]) is None
    with pytest.raises(oidn.DenoiserUnavailable, match="weights missing"):
        oidn.Denoiser(library, weights_dir=tmp_path)
    with pytest.raises(oidn.DenoiserUnavailable, match="did not load"):
        oidn.Denoiser(tmp_path / "libOpenImageDenoise.so.2")


def test_shipped_weights_match_their_pins():
    """The committed-beside licence is there; the blobs (if fetched) hash to core/post/denoise/oidn.py's pins."""
    assert (oidn.WEIGHTS_DIR / "LICENSE.txt").is_file() and (oidn.WEIGHTS_DIR / "README.md").is_file()
    for mode in oidn.WEIGHTS:
        if (oidn.WEIGHTS_DIR / oidn.WEIGHTS[mode][0]).is_file():
            assert len(oidn.load_weights(mode)) == oidn.WEIGHTS_BYTES
