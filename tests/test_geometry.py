import math

import numpy as np
import pytest

from semmap.geometry import (
    project_points,
    quaternion_to_yaw,
    se2_between,
    se2_compose,
    se2_inverse,
    se3_from_xyz_rpy,
    se3_inverse,
    wrap_angle,
    yaw_to_quaternion,
)


def test_wrap_angle_is_in_half_open_interval():
    a = np.array([-3 * math.pi, -math.pi, 0.0, math.pi, 3 * math.pi, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    assert w[1] == pytest.approx(math.pi)  # -pi maps to +pi
    assert np.allclose(np.cos(w), np.cos(a)) and np.allclose(np.sin(w), np.sin(a))


def test_se2_compose_inverse_roundtrip():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.normal(size=50), rng.normal(size=50), rng.uniform(-3, 3, 50)])
    b = np.column_stack([rng.normal(size=50), rng.normal(size=50), rng.uniform(-3, 3, 50)])
    ab = se2_compose(a, b)
    assert np.allclose(se2_between(a, ab), np.column_stack([b[:, :2], wrap_angle(b[:, 2])]), atol=1e-12)
    ident = se2_compose(a, se2_inverse(a))
    assert np.allclose(ident, 0.0, atol=1e-12)


def test_se2_compose_moves_forward_along_heading():
    p = se2_compose([1.0, 2.0, math.pi / 2], [1.0, 0.0, 0.0])
    assert p == pytest.approx([1.0, 3.0, math.pi / 2])


def test_quaternion_yaw_roundtrip():
    yaw = np.linspace(-3.1, 3.1, 13)
    assert np.allclose(quaternion_to_yaw(yaw_to_quaternion(yaw)), yaw)


def test_project_points_on_optical_axis_hits_principal_point():
    K = np.array([[601.80, 0, 328.17], [0, 600.12, 240.45], [0, 0, 1]])
    pts = np.array([[0.0, 0.0, 2.0], [0.5, -0.2, 2.0], [0.0, 0.0, -1.0]])
    uv, ok = project_points(K, np.zeros(5), pts, 640, 480)
    assert uv[0] == pytest.approx([328.17, 240.45])
    assert uv[1] == pytest.approx([328.17 + 601.80 * 0.25, 240.45 - 600.12 * 0.1])
    assert ok.tolist() == [True, True, False]  # behind the camera


def test_se3_inverse():
    t = se3_from_xyz_rpy([0.38, 0.23, 0.2], [0.1, -0.2, math.pi / 4])
    assert np.allclose(t @ se3_inverse(t), np.eye(4))
