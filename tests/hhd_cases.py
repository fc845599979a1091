"""Lighting set-ups with known HHD answers, as hemisphere-sampled radiance SH."""

import numpy as np

from hhd_lightmapper.core import sh


def hemisphere_light_sh(radiance, normals):
    """World SH `(N, 9, 3)` of constant radiance over the hemisphere of each normal (zero below)."""
    local = np.zeros((len(normals), 9, 3))
    local[:, 0] = np.sqrt(np.pi) * np.asarray(radiance)
    local[:, 2] = np.sqrt(3.0 * np.pi) / 2.0 * np.asarray(radiance)
    return sh.to_world(local, sh.tangent_frames(normals))


def delta_light_sh(direction, irradiance, n_rows):
    """World SH `(N, 9, 3)` of a light from `direction` giving `irradiance` (RGB) at normal incidence."""
    d = np.asarray(direction, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    y = sh.evaluate(d)
    return np.broadcast_to(np.pi * y[:, :, None] * np.asarray(irradiance).reshape(-1, 1, 3), (n_rows, 9, 3)).copy()


def tilted(normals, theta, rng):
    """Unit directions at angle theta from each normal, random azimuth `(N, 3)`."""
    f = sh.tangent_frames(normals)
    phi = rng.uniform(0, 2 * np.pi, len(normals))
    local = np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.full(len(normals), np.cos(theta))], 1
    )
    return np.einsum("nij,nj->ni", f, local)
