"""`biomotion.body.spatial` against first principles: cross products, rotations (scipy's Euler angles), the
Plücker transform's composition and invariance of the cross operator (Featherstone 2008, RBDA ch. 2), kinetic
energy from the spatial inertia, and every frames-last formula against its frames-first twin."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from biomotion.body.spatial import (
    axis_angle,
    body_fixed_xyz,
    cross_frames_last,
    cross_motion,
    cross_motion_frames_last,
    matmul_frames_last,
    matvec_frames_last,
    motion_transform,
    skew,
    skew_frames_last,
    spatial_inertia,
    spatial_inertia_frames_last,
    tmatvec_frames_last,
    vee,
)

_F64 = torch.float64


def _random(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.randn(*shape, dtype=_F64, generator=torch.Generator().manual_seed(seed))


def _rotations(count: int, seed: int = 0) -> torch.Tensor:
    return torch.as_tensor(Rotation.random(count, random_state=seed).as_matrix())


def test_skew_is_the_cross_product_and_vee_its_inverse() -> None:
    v, u = _random(5, 3, seed=1), _random(5, 3, seed=2)
    assert torch.allclose((skew(v) @ u[..., None])[..., 0], torch.linalg.cross(v, u), atol=1e-15)
    assert torch.allclose(skew(v).transpose(-1, -2), -skew(v))
    assert torch.allclose(vee(skew(v)), v, atol=0)
    m = _random(5, 3, 3, seed=3)
    assert torch.allclose(vee(m), vee(0.5 * (m - m.transpose(-1, -2))), atol=1e-15)  # the skew part only


def test_axis_angle_is_the_matrix_exponential_and_body_fixed_xyz_is_intrinsic_xyz() -> None:
    axis = torch.nn.functional.normalize(_random(3, seed=4), dim=0)
    angle = torch.linspace(-4.0, 4.0, 9, dtype=_F64)
    rotation = axis_angle(axis, angle)
    expected = torch.linalg.matrix_exp(angle[:, None, None] * skew(axis))
    assert torch.allclose(rotation, expected, atol=1e-14)
    assert torch.allclose(rotation @ axis, axis.expand(9, 3), atol=1e-15)  # the axis stays put
    angles = _random(4, 3, seed=5)
    scipy = Rotation.from_euler("XYZ", angles.numpy()).as_matrix()  # upper case: body-fixed
    assert np.allclose(body_fixed_xyz(angles).numpy(), scipy, atol=1e-14)


def test_motion_transforms_compose_and_carry_the_cross_operator() -> None:
    """^C X_A = ^C X_B ^B X_A, and X (v x) X^-1 = (X v) x (RBDA ch. 2)."""
    r_ab, r_bc = _rotations(4, seed=6), _rotations(4, seed=7)
    p_ab, p_bc = _random(4, 3, seed=8), _random(4, 3, seed=9)
    x_ba, x_cb = motion_transform(r_ab, p_ab), motion_transform(r_bc, p_bc)
    r_ac = r_ab @ r_bc  # C in A
    p_ac = p_ab + (r_ab @ p_bc[..., None])[..., 0]
    assert torch.allclose(x_cb @ x_ba, motion_transform(r_ac, p_ac), atol=1e-13)
    v = _random(4, 6, seed=10)
    carried = (x_ba @ v[..., None])[..., 0]
    assert torch.allclose(x_ba @ cross_motion(v) @ torch.linalg.inv(x_ba), cross_motion(carried), atol=1e-12)


def test_spatial_inertia_gives_the_kinetic_energy() -> None:
    """1/2 v^T I v = 1/2 m |v_c|^2 + 1/2 w^T I_c w, with v_c = v_O + w x c the COM velocity."""
    mass = torch.tensor([2.5, 70.0], dtype=_F64)
    com = _random(2, 3, seed=11)
    root = _random(2, 3, 3, seed=12)
    inertia = root @ root.transpose(-1, -2) + torch.eye(3, dtype=_F64)
    v = _random(2, 6, seed=13)
    w, v_o = v[..., :3], v[..., 3:]
    energy = 0.5 * (v[..., None, :] @ spatial_inertia(mass, com, inertia) @ v[..., None])[..., 0, 0]
    v_c = v_o + torch.linalg.cross(w, com)
    expected = 0.5 * mass * (v_c * v_c).sum(-1) + 0.5 * (w * (inertia @ w[..., None])[..., 0]).sum(-1)
    assert torch.allclose(energy, expected, rtol=1e-13)


def test_frames_last_formulas_equal_the_frames_first_ones() -> None:
    a, b = _random(7, 3, 3, seed=14), _random(7, 3, 3, seed=15)
    u, v = _random(7, 3, seed=16), _random(7, 3, seed=17)
    m6, v6 = _random(7, 6, seed=18), _random(7, 6, seed=19)

    def last(x: torch.Tensor) -> torch.Tensor:
        return x.movedim(0, -1)

    assert torch.allclose(matmul_frames_last(last(a), last(b)), last(a @ b), atol=1e-14)
    assert torch.allclose(matvec_frames_last(last(a), last(u)), last((a @ u[..., None])[..., 0]), atol=1e-14)
    assert torch.allclose(
        tmatvec_frames_last(last(a), last(u)), last((a.transpose(-1, -2) @ u[..., None])[..., 0]), atol=1e-14
    )
    assert torch.allclose(cross_frames_last(last(u), last(v)), last(torch.linalg.cross(u, v)), atol=1e-14)
    assert torch.allclose(skew_frames_last(last(u)), last(skew(u)), atol=0)
    assert torch.allclose(
        cross_motion_frames_last(last(v6), last(m6)), last((cross_motion(v6) @ m6[..., None])[..., 0]), atol=1e-14
    )
    mass = torch.rand(7, dtype=_F64, generator=torch.Generator().manual_seed(20)) + 0.5
    inertia = a @ a.transpose(-1, -2)
    assert torch.allclose(
        spatial_inertia_frames_last(mass, last(u), last(inertia)), last(spatial_inertia(mass, u, inertia)), atol=1e-13
    )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_is_kept_and_gradients_flow(dtype: torch.dtype) -> None:
    angles = _random(2, 3, seed=21).to(dtype).requires_grad_()
    rotation = body_fixed_xyz(angles)
    assert rotation.dtype == dtype
    rotation.sum().backward()
    assert angles.grad is not None and torch.isfinite(angles.grad).all()
