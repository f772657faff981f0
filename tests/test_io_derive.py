"""backward_from_forward: splat t-1's forward vectors into t with a depth test."""
from __future__ import annotations

import numpy as np
import pytest

from fgcli.io.derive import backward_from_forward, nearest_fill


def test_zero_vectors_give_zero_backward():
    mv, valid = backward_from_forward(np.zeros((2, 5, 7), np.float32))
    assert mv.shape == (2, 5, 7) and valid.shape == (1, 5, 7)
    assert (mv == 0).all() and valid.all()


def test_uniform_shift_known_answer_and_hole():
    f = np.zeros((2, 4, 6), np.float32)
    f[0] = 1.0  # everything moves one pixel right
    mv, valid = backward_from_forward(f)
    assert (mv[0] == -1).all() and (mv[1] == 0).all()  # holes take the nearest vector
    assert not valid[0, :, 0].any() and valid[0, :, 1:].all()  # column 0: disoccluded


def test_depth_test_nearest_wins():
    f = np.zeros((2, 1, 4), np.float32)
    f[0, 0, 0] = 2.0  # pixel 0 lands on pixel 2, which also stays put
    depth = np.array([[[1.0, 5.0, 5.0, 5.0]]], np.float32)
    mv, valid = backward_from_forward(f, depth)
    assert mv[0, 0, 2] == -2.0  # the nearer surface (pixel 0) wins
    depth2 = np.array([[[9.0, 5.0, 5.0, 5.0]]], np.float32)
    mv2, _ = backward_from_forward(f, depth2)
    assert mv2[0, 0, 2] == 0.0  # the farther one loses
    assert not valid[0, 0, 0]


def test_offscreen_nonfinite_and_invalid_sources_ignored():
    f = np.zeros((2, 3, 3), np.float32)
    f[0, 0, 0] = 100.0
    f[1, 1, 1] = np.nan
    ok = np.ones((3, 3), bool)
    ok[2, 2] = False
    mv, valid = backward_from_forward(f, None, ok)
    assert np.isfinite(mv).all()
    assert not valid[0, 0, 0] and not valid[0, 1, 1] and not valid[0, 2, 2]


def test_bad_shape():
    with pytest.raises(ValueError):
        backward_from_forward(np.zeros((3, 4, 4)))


def test_nearest_fill():
    v = np.arange(12, dtype=np.float32).reshape(1, 3, 4)
    ok = np.zeros((3, 4), bool)
    ok[0, 0] = ok[2, 3] = True
    out = nearest_fill(v, ok)
    assert out[0, 0, 1] == 0 and out[0, 2, 2] == 11 and out[0, 0, 0] == 0
    assert (nearest_fill(v, np.zeros((3, 4), bool)) == 0).all()
