"""Reconstruction error of joint centres: PhysPT's MJE and P-MJE, and the global-trajectory error G-MPJPE.

Inputs are joint centres ``pred`` and ``target`` [..., T, J, 3] in metres, an optional joint mask ``joints``
([..., J] per sequence or [..., T, J] per frame, recognised by having one dim less than the positions) and the
per-frame mask ``valid`` [..., T]. Errors are in metres (the papers print mm or cm).
"""

from __future__ import annotations

import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import Metric, Tensor, as_tensor, column_mask, frame_mask, masked_mean

GLOBAL_WINDOW = 10.0
"""s: window of the global-trajectory error; the root is re-aligned at each window's first frame (PhysPT Supp. E)."""


def _pair(pred, target) -> tuple[Tensor, Tensor]:
    pred = as_tensor(pred, "pred", min_dims=3, last=3)
    target = as_tensor(target, "target", min_dims=3, last=3).to(pred.dtype)
    if pred.shape[-3:] != target.shape[-3:]:
        raise DataFormatError(
            None, f"pred {tuple(pred.shape)} and target {tuple(target.shape)} differ in [T, J, 3]", field="target"
        )
    return pred, target


def _joint_mask(joints, pred: Tensor, valid) -> Tensor:
    """[..., T, J] entries to score: valid frame and joint present."""
    frames = frame_mask(valid, pred.shape[:-2], pred.device)[..., None]
    return frames & column_mask(joints, pred.shape[:-1], 0, "joints", pred.device)


def joint_error(pred, target, valid=None, *, joints=None, root: int | None = None) -> Tensor:
    """PhysPT Sec. 4 "MJE" (mean per-joint position error): mean over frames and joints of
    ``||p_pred - p_target||`` (m). With ``root``, both are first expressed relative to that joint (the Human3.6M
    protocol); without, in the ground frame (PG-BIG's fidelity)."""
    pred, target = _pair(pred, target)
    if root is not None:
        pred = pred - pred[..., root : root + 1, :]
        target = target - target[..., root : root + 1, :]
    error = torch.linalg.vector_norm(pred - target, dim=-1)
    return masked_mean(error, _joint_mask(joints, pred, valid), (-2, -1))


def procrustes_align(pred, target, weights=None) -> Tensor:
    """``pred`` [..., J, 3] mapped onto ``target`` by the similarity transform (scale, rotation, translation) that
    minimises the weighted squared error (Umeyama 1991, closed form by SVD; reflections excluded).
    ``weights`` [..., J] (e.g. a joint mask) default to 1."""
    pred = as_tensor(pred, "pred", min_dims=2, last=3)
    target = as_tensor(target, "target", min_dims=2, last=3).to(pred.dtype)
    w = (
        torch.ones(pred.shape[:-1], dtype=pred.dtype, device=pred.device)
        if weights is None
        else torch.broadcast_to(torch.as_tensor(weights, device=pred.device).to(pred.dtype), pred.shape[:-1])
    )
    total = w.sum(-1, keepdim=True).clamp(min=torch.finfo(pred.dtype).tiny)[..., None]
    mu_p = (w[..., None] * pred).sum(-2, keepdim=True) / total
    mu_t = (w[..., None] * target).sum(-2, keepdim=True) / total
    x, y = pred - mu_p, target - mu_t
    cov = (w[..., None] * y).transpose(-1, -2) @ x  # [..., 3, 3] = sum_i w_i y_i x_i^T
    u, s, vh = torch.linalg.svd(cov)
    d = torch.sign(torch.linalg.det(u @ vh))
    d = torch.where(d == 0, torch.ones_like(d), d)
    fix = torch.ones_like(s)
    fix[..., -1] = d
    rotation = u @ torch.diag_embed(fix) @ vh  # maps x onto y
    spread = (w * x.square().sum(-1)).sum(-1).clamp(min=torch.finfo(pred.dtype).tiny)
    scale = (s * fix).sum(-1) / spread
    return scale[..., None, None] * x @ rotation.transpose(-1, -2) + mu_t


def procrustes_joint_error(pred, target, valid=None, *, joints=None) -> Tensor:
    """PhysPT Sec. 4 "P-MJE": MJE after per-frame Procrustes alignment (`procrustes_align`) of the predicted joints
    onto the target ones, using the present joints only (m)."""
    pred, target = _pair(pred, target)
    mask = _joint_mask(joints, pred, valid)
    aligned = procrustes_align(pred, target, mask)
    error = torch.linalg.vector_norm(aligned - target, dim=-1)
    return masked_mean(error, mask, (-2, -1))


def global_trajectory_error(
    pred, target, rate: float, valid=None, *, joints=None, root: int = 0, window: float = GLOBAL_WINDOW
) -> Tensor:
    """PhysPT Supp. E "G-MPJPE": world-frame MJE (m) where, in consecutive windows of ``window`` seconds, the
    predicted motion is translated so that its ``root`` joint matches the target's at the window's first frame.
    Pass the root trajectory alone as [..., T, 1, 3] for a pure trajectory error."""
    pred, target = _pair(pred, target)
    if rate <= 0 or window <= 0:
        raise DataFormatError(None, f"rate and window must be positive, got {rate}, {window}", field="rate")
    frames = pred.shape[-3]
    size = max(1, int(round(window * rate)))
    start = (torch.arange(frames, device=pred.device) // size) * size
    offset = (target[..., root, :] - pred[..., root, :]).index_select(-2, start)  # [..., T, 3]
    error = torch.linalg.vector_norm(pred + offset[..., None, :] - target, dim=-1)
    return masked_mean(error, _joint_mask(joints, pred, valid), (-2, -1))


class JointError(Metric):
    """`joint_error` per sequence (PhysPT Table 1 "MJE", printed in mm)."""

    name, label, unit, display_unit, display_scale = "mje", "MJE", "m", "mm", 1000.0
    higher_is_better = False
    paper = 'PhysPT Sec. 4 "MJE", Table 1'
    equation = "mean over frames and joints of ||p_pred - p_target|| (relative to the root joint when given)"

    def __init__(self, root: int | None = None) -> None:
        super().__init__()
        self.root = root

    def score(self, pred, target, valid=None, joints=None) -> Tensor:
        return joint_error(pred, target, valid, joints=joints, root=self.root)


class ProcrustesJointError(Metric):
    """`procrustes_joint_error` per sequence (PhysPT Table 1 "P-MJE", printed in mm)."""

    name, label, unit, display_unit, display_scale = "p_mje", "P-MJE", "m", "mm", 1000.0
    higher_is_better = False
    paper = 'PhysPT Sec. 4 "P-MJE", Table 1'
    equation = "MJE after the per-frame similarity transform that best maps pred onto target (Umeyama 1991)"

    def score(self, pred, target, valid=None, joints=None) -> Tensor:
        return procrustes_joint_error(pred, target, valid, joints=joints)


class GlobalTrajectoryError(Metric):
    """`global_trajectory_error` per sequence (PhysPT Supp. E Table 6 "G-MPJPE", printed in mm)."""

    name, label, unit, display_unit, display_scale = "g_mpjpe", "G-MPJPE", "m", "mm", 1000.0
    higher_is_better = False
    paper = 'PhysPT Supp. E, Table 6 "G-MPJPE"'
    equation = "world-frame MJE with the root re-aligned to the target's at the first frame of each window (10 s)"

    def __init__(self, root: int = 0, window: float = GLOBAL_WINDOW) -> None:
        super().__init__()
        self.root, self.window = root, window

    def score(self, pred, target, rate: float, valid=None, joints=None) -> Tensor:
        return global_trajectory_error(pred, target, rate, valid, joints=joints, root=self.root, window=self.window)
