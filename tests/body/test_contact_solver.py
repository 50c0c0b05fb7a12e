"""The batched force solve of `infer_ground_reaction` (`_nonnegative_least_squares`, Newton on the 6-variable dual)
against SciPy's Lawson-Hanson NNLS frame by frame, on random problems shaped like the contact QP: 6 root rows, 40
cone-edge columns, prior weights d spanning 1e-9 (point on the ground) to 1e3 (point in the air)."""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import nnls

from biomotion.body.contact import _nonnegative_least_squares


def _problem(frames: int, seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    a = torch.randn(frames, 6, 40, generator=generator, dtype=torch.float64)
    r = 300.0 * torch.randn(frames, 6, generator=generator, dtype=torch.float64)
    d = 10.0 ** (12.0 * torch.rand(frames, 40, generator=generator, dtype=torch.float64) - 9.0)
    return a, r, d


def _cost(a, r, d, x):
    return 0.5 * ((np.einsum("mn,n->m", a, x) - r) ** 2).sum() + 0.5 * (d * x * x).sum()


def test_matches_lawson_hanson_and_meets_kkt():
    a, r, d = _problem(64)
    x = _nonnegative_least_squares(a, r, d, iterations=50)
    assert (x >= 0).all()
    gradient = (a.transpose(-1, -2) @ ((a @ x[..., None]).squeeze(-1) - r)[..., None]).squeeze(-1) + d * x
    scale = 1e-9 * (1.0 + r.abs().amax(-1, keepdim=True))  # N·(force units): rounding level
    assert (gradient[x > 0].abs() <= 1e3 * scale.expand_as(x)[x > 0]).all()  # stationary where free
    assert (gradient[x == 0] >= -1e3 * scale.expand_as(x)[x == 0]).all()  # no descent into x > 0
    for t in range(a.shape[0]):  # the same problem as a stacked least squares: [A; √D] x ≈ [r; 0]
        stacked = np.vstack([a[t].numpy(), np.diag(np.sqrt(d[t].numpy()))])
        reference, _ = nnls(stacked, np.concatenate([r[t].numpy(), np.zeros(40)]), maxiter=10_000)
        ours, theirs = (_cost(a[t].numpy(), r[t].numpy(), d[t].numpy(), v) for v in (x[t].numpy(), reference))
        assert ours <= theirs * (1 + 1e-9) + 1e-9


def test_frames_are_independent_and_edge_cases():
    a, r, d = _problem(16, seed=1)
    together = _nonnegative_least_squares(a, r, d, iterations=50)
    alone = torch.cat(
        [_nonnegative_least_squares(a[t : t + 1], r[t : t + 1], d[t : t + 1], iterations=50) for t in range(16)]
    )
    torch.testing.assert_close(together, alone, rtol=1e-9, atol=1e-9)
    assert _nonnegative_least_squares(a[:0], r[:0], d[:0], iterations=50).shape == (0, 40)
    zero = _nonnegative_least_squares(a[:2], torch.zeros_like(r[:2]), d[:2], iterations=50)
    assert (zero == 0).all()  # nothing to explain: no force
    a[3] = float("nan")
    assert _nonnegative_least_squares(a, r, d, iterations=50).isnan().any(-1).tolist() == [t == 3 for t in range(16)]
