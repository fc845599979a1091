"""The specular HLSL of docs/format.md (`SpecularHHD`, `SHSpecular`, `SGSpecular`), ported line by
line to float32 numpy, equals core's specular (`core.encoding.hhd_specular.specular`,
`ggx.sh_specular`, `SGBasis.specular`) on random texels, normals, views, α and F0: a formula in the
docs that was never run is a defect. The table lookups sample a float32 texture built from
`ggx.table()` as the comments in the HLSL describe it (bilinear, clamp, texel centres on the grid
points); `RotateSH9` is `core.sh.to_world`, as the HLSL's comment says. Pure numpy, no bpy."""

import re
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import hhd, sh
from hhd_lightmapper.core.encoding import ggx, hhd_specular, sg

FORMAT_DOC = Path(__file__).resolve().parent.parent / "docs" / "format.md"
F = np.float32
PI = F(np.pi)


def hlsl_block(name: str) -> str:
    """The text of docs/format.md's HLSL function `name` (its signature to the closing brace)."""
    doc = FORMAT_DOC.read_text()
    start = doc.index(f"float3 {name}(")
    return doc[start : doc.index("\n}", start)]


# --- HLSL intrinsics, float32, over rows ------------------------------------------------------


def dot(a, b):
    return (a * b).sum(axis=-1)


def normalize(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def saturate(x):
    return np.clip(x, F(0), F(1))


def reflect(i, n):
    return i - F(2) * dot(i, n)[:, None] * n


def cross(a, b):
    return np.cross(a, b).astype(F)


def frame(n):
    """Frame(n) of docs/format.md: rows t, b, n `(N, 3, 3)`."""
    s = np.where(n[:, 2] >= 0, F(1), F(-1))
    a = F(-1) / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([F(1) + s * n[:, 0] * n[:, 0] * a, s * b, -s * n[:, 0]], -1)
    bt = np.stack([b, s + n[:, 1] * n[:, 1] * a, -n[:, 1]], -1)
    return np.stack([t, bt, n], 1)


def sample_level(texture, uv):
    """Texture2D.SampleLevel(LinearClamp, uv, 0): `texture (H, W, C)` (row j = v), bilinear
    between texel centres ((i + ½)/W, (j + ½)/H), clamped at the edges -> `(N, C)` float32."""
    h, w = texture.shape[:2]
    p = uv * np.array([w, h], F) - F(0.5)
    i0 = np.floor(p).astype(int)
    f = (p - i0).astype(F)
    x0, x1 = np.clip(i0[:, 0], 0, w - 1), np.clip(i0[:, 0] + 1, 0, w - 1)
    y0, y1 = np.clip(i0[:, 1], 0, h - 1), np.clip(i0[:, 1] + 1, 0, h - 1)
    fx, fy = f[:, :1], f[:, 1:]
    top = texture[y0, x0] * (F(1) - fx) + texture[y0, x1] * fx
    bottom = texture[y1, x0] * (F(1) - fx) + texture[y1, x1] * fx
    return top * (F(1) - fy) + bottom * fy


def albedo_texture():
    """GgxAlbedo: texel (i, j) = ggx.table()[i, j, 0, :] / 0.282095, i along u (n·v), j along v (√α)."""
    return (ggx.table()[:, :, 0, :] / F(0.282095)).transpose(1, 0, 2).astype(F)


def lobe_texture():
    """The 12 values of ggx.table() per grid point, laid out like GgxAlbedo: `(32, 32, 6, 2)`."""
    return ggx.table().transpose(1, 0, 2, 3).astype(F)


# --- SpecularHHD --------------------------------------------------------------------------------


def hlsl_lookup_albedo(nv, alpha):
    g = np.stack([saturate(nv), saturate((np.sqrt(alpha) - F(0.1)) / F(0.9))], -1)
    return sample_level(albedo_texture(), (g * F(31) + F(0.5)) / F(32))


def hlsl_g1(x, a2):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(x > 0, F(2) * x / (x + np.sqrt(a2 + (F(1) - a2) * x * x)), F(0))


def hlsl_specular_hhd(iz, wa, d, nv, n, v, alpha, f0, ahd):
    """SpecularHHD; wa `(N, 3)` (.rrr), alpha `(N,)`, f0 `(N, 3)`."""
    cd = (F(1) - wa) * iz / np.maximum(dot(d, nv), F(0.01))[:, None]
    ca = wa * iz
    a2, nl, nvv = alpha * alpha, dot(n, d), dot(n, v)
    h = normalize(d + v)
    nh = dot(n, h)
    q = nh * nh * (a2 - F(1)) + F(1)
    fres = f0 + (F(1) - f0) * ((F(1) - saturate(dot(v, h))) ** F(5))[:, None]
    lit = (nl > 0) & (nvv > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        term = (a2 / (PI * q * q)) * hlsl_g1(nl, a2) * hlsl_g1(nvv, a2) / (F(4) * nvv)
    s = np.where(lit[:, None], PI * cd * term[:, None] * fres, F(0))
    vis = np.ones_like(alpha)
    if not ahd:
        m = normalize(reflect(-v, n) + alpha[:, None] * (n - reflect(-v, n)))  # lerp(r, n, alpha)
        vis = saturate(F(0.5) + F(0.5) * np.maximum(F(1), F(0.4) / alpha) * dot(m, nv))
    ab = hlsl_lookup_albedo(nvv, alpha)
    return s + np.where((nvv > 0)[:, None], ca * (f0 * ab[:, :1] + ab[:, 1:]) * vis[:, None], F(0))


def random_views(rng, nv, count, max_tilt=60.0):
    """Unit shading normals up to `max_tilt`° off n_v, views over n's whole sphere (a tenth of
    them exactly n), α with √α uniform in [0.1, 1] plus a few below the table's floor, F0."""
    frames = sh.tangent_frames(nv)
    theta = np.radians(rng.uniform(0, max_tilt, count))
    phi = rng.uniform(0, 2 * np.pi, count)
    local = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    n = np.einsum("nij,nj->ni", frames, local)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[: count // 10] = n[: count // 10]
    alpha = rng.uniform(0.1, 1.0, count) ** 2
    alpha[-count // 20 :] = rng.uniform(0.002, 0.01, count // 20)
    return n, v, alpha, rng.uniform(0.02, 1.0, count)


def compare(name, hlsl, core) -> tuple[float, float]:
    """|HLSL − core| relative to each row's largest value (floor: 1e-4 of the largest): its 99.9%
    quantile and max over the rows; asserted below 1e-4 and 1e-3 (float32 against float64: the
    max is at grazing n·v, where the warp's λ_x ∝ 1/(n·v)² is ill-conditioned)."""
    scale = np.maximum(np.abs(core).max(axis=1, keepdims=True), 1e-4 * np.abs(core).max())
    rows = (np.abs(hlsl - core) / scale).max(axis=1)
    stats = float(np.quantile(rows, 0.999)), float(rows.max())
    print(name, "relative error (99.9%, max):", stats)
    return stats


@pytest.mark.parametrize("model", ["hhd", "ahd"])
def test_documented_specular_hhd_matches_core(model):
    text = hlsl_block("SpecularHHD")
    assert "max(dot(d, nv), 0.01)" in text and f"{hhd.MIN_COS * 0.5:g}" == "0.01"
    assert re.search(r"max\(1\.0, 0\.4 / alpha\)", text) and hhd_specular.VISIBILITY_SLOPE == 0.4
    assert "LookupAlbedo" in text and "ggx.table()[i, j, 0, :] / 0.282095" in FORMAT_DOC.read_text()
    rng = np.random.default_rng(59)
    count = 20000
    nv = rng.normal(size=(count, 3))
    nv /= np.linalg.norm(nv, axis=1, keepdims=True)
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where((np.einsum("ni,ni->n", d, nv) < 0)[:, None], -d, d)  # a few under the 0.01 floor
    iz = rng.uniform(0.0, 1.0, (count, 3)) * rng.uniform(0.1, 50.0, (count, 1))
    wa = rng.uniform(0.0, 1.0, count)
    n, v, alpha, f0 = random_views(rng, nv, count)
    # what the shader reads: float32 n_v and lighting (the files' halves are a different test)
    iz32, wa32, d32, nv32 = iz.astype(F), wa.astype(F), d.astype(F), nv.astype(F)
    n32, v32, alpha32, f032 = n.astype(F), v.astype(F), alpha.astype(F), f0.astype(F)
    wa3, f03 = np.repeat(wa32[:, None], 3, 1), np.repeat(f032[:, None], 3, 1)  # .rrr, F0 per channel

    def port(wa, ahd):
        return hlsl_specular_hhd(iz32, wa, d32, nv32, n32, v32, alpha32, f03, ahd)

    shader = port(wa3, model == "ahd")
    params = hhd.HHDParams(iz32.astype(float), wa32.astype(float), d32.astype(float), model=model)
    core = hhd_specular.specular(params, nv32, n32, v32, alpha32.astype(float), f032.astype(float))
    assert shader.dtype == F and np.isfinite(shader).all()
    assert (core > 0).mean() > 0.4 and (core == 0).any()  # lit and unlit (n·v ≤ 0) rows
    quantile, worst = compare(model, shader, core)
    assert quantile < 1e-4 and worst < 1e-3, (quantile, worst)
    # the ambient and the visibility matter: without them the port is far off
    wrong = port(np.zeros((count, 3), F), model == "ahd")
    assert compare("without the ambient", wrong, core)[0] > 0.1
    other = port(wa3, model != "ahd")
    assert compare("the other model's visibility", other, core)[0] > 0.01


# --- SGSpecular ---------------------------------------------------------------------------------


def hlsl_sg_specular(a, mu, lam, n, v, alpha, f0):
    """SGSpecular of one lobe: a `(N, 3)`, mu `(3,)` (or `(N, 3)`), n, v `(N, 3)` in mu's space."""
    m2 = alpha * alpha
    ndf_lambda, ndf_amp = F(2) / m2, F(1) / (PI * m2)
    z = reflect(-v, n)
    x = cross(n, z)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.where((dot(x, x) > F(1e-6))[:, None], normalize(x), frame(z)[:, 0])
    y = cross(z, x)
    o = np.maximum(dot(v, n), F(1e-4))
    lx, ly, nu = ndf_lambda / (F(8) * o * o), ndf_lambda / F(8), F(lam) / F(2)
    cx, cy = nu * lx / (nu + lx), nu * ly / (nu + ly)
    camp = PI / np.sqrt((nu + lx) * (nu + ly))
    conv = camp * saturate(dot(mu, z)) * np.exp(-cx * dot(mu, x) * dot(mu, x) - cy * dot(mu, y) * dot(mu, y))
    nl, nvv = saturate(dot(n, z)), saturate(dot(n, v))
    vis = F(1) / (nl + np.sqrt(m2 + (F(1) - m2) * nl * nl)) / (nvv + np.sqrt(m2 + (F(1) - m2) * nvv * nvv))
    f = f0 + (F(1) - f0) * (F(1) - saturate(dot(z, normalize(z + v)))) ** F(5)
    return np.maximum((conv * ndf_amp * vis * f * nl)[:, None] * a, F(0))


@pytest.mark.parametrize("count", [5, 12])
def test_documented_sg_specular_matches_core(count):
    text = hlsl_block("SGSpecular")
    assert "Frame(z)[0]" in text and "max(dot(v, n), 1e-4)" in text
    rng = np.random.default_rng(count)
    texels = 20000
    nv = rng.normal(size=(texels, 3))
    nv /= np.linalg.norm(nv, axis=1, keepdims=True)
    n, v, alpha, _ = random_views(rng, nv, texels)
    f0 = F(0.04)
    amp = rng.uniform(-0.5, 3.0, (texels, count, 3))  # negative amplitudes: an ls / adhoc fit
    axes, lam = sg.layout(count)
    nv32, n32, v32, alpha32, amp32 = nv.astype(F), n.astype(F), v.astype(F), alpha.astype(F), amp.astype(F)
    to_frame = frame(nv32)  # mul(Frame(n_v), ·): n and v into the frame of the constant axes
    n_t, v_t = np.einsum("nij,nj->ni", to_frame, n32), np.einsum("nij,nj->ni", to_frame, v32)
    shader = sum(hlsl_sg_specular(amp32[:, k], axes[k].astype(F), lam, n_t, v_t, alpha32, f0) for k in range(count))
    core = sg.SGBasis(count).specular(amp32.astype(float), nv32, n32, v32, alpha32.astype(float), float(f0))
    assert shader.dtype == F and np.isfinite(shader).all()
    assert (core > 0).mean() > 0.4
    quantile, worst = compare(f"sg{count}", shader, core)
    assert quantile < 1e-4 and worst < 1e-3, (quantile, worst)


# --- SHSpecular ---------------------------------------------------------------------------------


def hlsl_lookup_lobe(uv, f0):
    """LookupLobe: g `(N, 9)`, F0 A_k + B_k at k = 0, 2, 3, 6, 7, 8, bilinear at uv · 31."""
    ab = sample_level(lobe_texture().reshape(32, 32, 12), (uv * F(31) + F(0.5)) / F(32)).reshape(-1, 6, 2)
    g = np.zeros((len(uv), 9), F)
    g[:, list(ggx.LOBE_COEFFS)] = f0 * ab[..., 0] + ab[..., 1]
    return g


def hlsl_sh_specular(c, n, v, alpha, f0):
    """SHSpecular: c `(N, 9, 3)`."""
    x = v - dot(v, n)[:, None] * n
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.where((dot(x, x) > F(1e-6))[:, None], normalize(x), frame(n)[:, 0])
    y = cross(n, x)
    uv = np.stack([saturate(dot(n, v)), saturate((np.sqrt(alpha) - F(0.1)) / F(0.9))], -1)
    g = hlsl_lookup_lobe(uv, f0)
    g = sh.to_world(g.astype(float), np.stack([x, y, n], -1).astype(float)).astype(F)  # RotateSH9
    return np.einsum("nk,nkc->nc", g, c)


def test_documented_sh_specular_matches_core():
    text = hlsl_block("SHSpecular")
    assert "Frame(n)[0]" in text and "saturate((sqrt(alpha) - 0.1) / 0.9)" in text
    assert (ggx.SQRT_ALPHA_MIN, ggx.TABLE_NV, ggx.TABLE_ROUGH) == (0.1, 32, 32)
    rng = np.random.default_rng(9)
    texels = 20000
    nv = rng.normal(size=(texels, 3))
    nv /= np.linalg.norm(nv, axis=1, keepdims=True)
    n, v, alpha, _ = random_views(rng, nv, texels)
    f0 = F(0.04)
    c = rng.normal(size=(texels, 9, 3)) * np.array([1.0, 0.6, 0.6, 0.6, 0.3, 0.3, 0.3, 0.3, 0.3])[None, :, None]
    c[:, 0] += 2.0
    n32, v32, alpha32, c32 = n.astype(F), v.astype(F), alpha.astype(F), c.astype(F)
    shader = hlsl_sh_specular(c32, n32, v32, alpha32, f0)
    core = ggx.sh_specular(c32.astype(float), n32, v32, alpha32.astype(float), float(f0))
    assert shader.dtype == F and np.isfinite(shader).all()
    quantile, worst = compare("L2 SH", shader, core)
    assert quantile < 1e-4 and worst < 1e-3, (quantile, worst)
