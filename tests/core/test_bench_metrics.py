"""Fast checks of the benchmark's metric functions (bench/metrics.py) on tiny known inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.metrics import (
    correspondence_error,
    hole_mask,
    landmark_error,
    summarize_mm,
    surface_distance_stats,
    vertex_errors,
)


def test_vertex_errors_and_correspondence_in_mm():
    truth = np.zeros((4, 3))
    fit = np.array([[0.001, 0, 0], [0, 0.002, 0], [0, 0, 0.003], [0.004, 0, 0]])
    np.testing.assert_allclose(vertex_errors(fit, truth), [0.001, 0.002, 0.003, 0.004])
    e = correspondence_error(fit, truth)
    assert e["mean"] == pytest.approx(2.5)
    assert e["max"] == pytest.approx(4.0)
    assert e["p95"] == pytest.approx(np.percentile([1, 2, 3, 4], 95))
    assert e["n"] == 4


def test_correspondence_mask_and_empty_mask():
    truth = np.zeros((3, 3))
    fit = np.array([[0.001, 0, 0], [0.010, 0, 0], [0.100, 0, 0]])
    e = correspondence_error(fit, truth, np.array([False, True, False]))
    assert (e["mean"], e["max"], e["n"]) == (pytest.approx(10.0), pytest.approx(10.0), 1)
    empty = correspondence_error(fit, truth, np.zeros(3, bool))
    assert empty["n"] == 0 and math.isnan(empty["mean"])


def test_shape_errors_are_value_errors():
    with pytest.raises(ValueError, match="same n"):
        vertex_errors(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="mask"):
        correspondence_error(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(2, bool))
    with pytest.raises(ValueError):
        hole_mask(np.zeros((3, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError):
        landmark_error(np.zeros((3, 3)), np.zeros((3, 3)), np.array([5]))


def test_hole_mask_uses_radius():
    scan = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    truth = np.array([[0.004, 0, 0], [0.006, 0, 0], [1.0, 0.001, 0], [0.5, 0, 0]])
    np.testing.assert_array_equal(hole_mask(truth, scan), [False, True, False, True])
    np.testing.assert_array_equal(hole_mask(truth, scan, radius=0.01), [False, False, False, True])


def test_landmark_error_mean_over_given_vertices():
    truth = np.zeros((5, 3))
    fit = np.zeros((5, 3))
    fit[1, 0] = 0.002
    fit[3, 1] = 0.004
    fit[4, 2] = 1.0  # not a landmark
    assert landmark_error(fit, truth, np.array([1, 3])) == pytest.approx(3.0)


def test_surface_distance_stats_and_summarize():
    d = np.array([0.0005, 0.001, 0.0015])
    s = surface_distance_stats(d)
    assert s["mean"] == pytest.approx(1.0)
    assert s["p95"] == pytest.approx(np.percentile(d, 95) * 1000)
    assert "max" not in s
    assert summarize_mm(np.array([]))["n"] == 0
