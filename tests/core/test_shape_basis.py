"""One shape-space interface for the body prior (``core.registration.shape_prior.ShapeBasis``):
the MakeHuman basis and a learned PCA shape space both drive the markers-only fit."""

from __future__ import annotations

import numpy as np
import pytest

from core.matching.markers_only import fit_markers_only
from core.registration.shape_prior import ShapeBasis, load_shape_basis
from core.shapespace.model import default_model
from core.template import load_template


@pytest.fixture(scope="module")
def pca():
    return default_model().space("joint").pca


def test_pca_as_basis_reconstructs_like_the_pca(pca):
    B = default_model().shape_basis("joint")
    assert B.k == pca.k and B.mean.shape == (13380, 3)
    w = pca.sample(np.random.default_rng(0))
    np.testing.assert_allclose(B.mean + B.U @ w, pca.reconstruct(w), atol=1e-12)
    np.testing.assert_allclose(B.variances, pca.variances)
    U = B.U.reshape(-1, B.k)
    np.testing.assert_allclose(U.T @ U, np.eye(B.k), atol=1e-5)  # orthonormal (float32 source)
    assert ShapeBasis.from_pca(pca, 3).k == 3
    assert load_shape_basis().mean is None  # the MakeHuman basis: displacements of the template


@pytest.mark.parametrize("seed", [1, 2])
def test_markers_only_fit_through_a_learned_shape_space(pca, seed):
    # a body of the learned space, seen only through its 62 landmarks: the learned space as the
    # prior finds it far better than the generic MakeHuman basis (measured: 0.8-1.0 vs 5.5-6.2 mm)
    tpl = load_template()
    V = pca.reconstruct(pca.sample(np.random.default_rng(seed))) + np.array([0.1, 0.0, -0.2])
    markers = {k: V[i] for k, i in tpl.landmarks.items()}
    learned = fit_markers_only(markers, basis=default_model().shape_basis("joint"))
    generic = fit_markers_only(markers)
    e_learned = np.linalg.norm(learned.vertices - V, axis=1).mean()
    e_generic = np.linalg.norm(generic.vertices - V, axis=1).mean()
    assert e_learned < 0.002 and e_learned < 0.5 * e_generic


def test_mean_of_another_topology_is_refused():
    B = load_shape_basis()
    bad = ShapeBasis(U=B.U, sigma=B.sigma, mean=np.zeros((10, 3)))
    markers = {k: load_template().V[i] for k, i in load_template().landmarks.items()}
    with pytest.raises(ValueError, match="V0"):
        fit_markers_only(markers, basis=bad)
