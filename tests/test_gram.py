"""Closed-form Gram matrices against quadrature, entry by entry, and the slide's typos."""

import numpy as np
import pytest

import quadrature as quad
from hhd_lightmapper.core import gram, sh


def gram_by_quadrature(cos_alpha):
    dirs, w = quad.cap(cos_alpha)
    y = sh.evaluate(dirs)
    return y.T @ (y * w[:, None])


@pytest.mark.parametrize("cos_alpha", [-1.0, -0.6, 0.0, 0.25, 0.5, 0.9, 0.999])
def test_cone_gram_matches_quadrature_entry_by_entry(cos_alpha):
    np.testing.assert_allclose(gram.cone(cos_alpha), gram_by_quadrature(cos_alpha), atol=1e-13)


def test_vectorised_cone_gram():
    c = np.array([0.1, 0.7])
    np.testing.assert_allclose(gram.cone(c)[1], gram.cone(0.7))


def test_hemisphere_gram_is_the_papers_matrix():
    g = np.zeros((9, 9))
    np.fill_diagonal(g, 0.5)
    for (i, j), v in {
        (0, 2): np.sqrt(3) / 4,
        (1, 5): 3 * np.sqrt(5) / 16,
        (2, 6): np.sqrt(15) / 16,
        (3, 7): 3 * np.sqrt(5) / 16,
    }.items():
        g[i, j] = g[j, i] = v
    np.testing.assert_allclose(gram.hemisphere(), g, atol=1e-15)
    np.testing.assert_allclose(gram_by_quadrature(0.0), g, atol=1e-13)


def test_full_cone_is_the_sphere():
    np.testing.assert_allclose(gram.cone(-1.0), gram.sphere(), atol=1e-15)


def test_slide_cone_typos_are_really_wrong():
    """The slide's forms, evaluated, disagree with quadrature; ours agree (see gram.py)."""
    c = 0.4
    q = gram_by_quadrature(c)
    slide = {
        (0, 2): np.sqrt(5) / 4 * (1 - c * c),
        (1, 1): 0.5 * (2 - 3 * c + c**3),
        (2, 6): np.sqrt(15) / 20 * (1 + 2 * c * c - 3 * c**4),
        (4, 4): (1 - c) ** 3 * (8 + 3 * c) * (3 + c) / 16,
        (5, 5): 0.25 * (2 - 5 * c * c + 3 * c**4),
        (7, 7): 0.5 * (2 - 5 * c**3 + 3 * c**5),
    }
    for (i, j), v in slide.items():
        assert abs(v - q[i, j]) > 1e-3, (i, j)
        assert gram.cone(c)[i, j] == pytest.approx(q[i, j], abs=1e-13)
