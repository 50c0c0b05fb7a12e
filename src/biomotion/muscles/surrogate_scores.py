"""How well the muscle surrogate reproduces its static-optimization labels: per-muscle and pooled R², RMSE, key
muscles (PG-BIG Table 7), within-clip R², and the COM head's velocity and acceleration R² (PG-BIG A.8).

R² per muscle is 1 - SSE/SST over converged frames; the mean per muscle counts only muscles whose labels vary
(std above ``min_std``), since R² of a muscle that never switches on is undefined in practice.
"""

from __future__ import annotations

import numpy as np
import torch

from biomotion.muscles.surrogate import COM_COLUMNS, COM_OUTPUTS, MuscleSurrogate

#: PG-BIG Table 7's muscles of interest.
KEY_MUSCLES = ("soleus_l", "soleus_r", "vasint_l", "vasint_r", "vaslat_l", "vaslat_r", "vasmed_l", "vasmed_r")
WITHIN_CLIP_FRAMES = 30  # clips with at least this many converged frames get a within-clip R^2
#: Columns of the labels' COM array (`COM_COLUMNS`) that the COM head predicts (`COM_OUTPUTS`).
COM_LABEL_COLUMNS = [COM_COLUMNS.index(name) for name in COM_OUTPUTS]


def agreement(predicted: np.ndarray, reference: np.ndarray, names: tuple[str, ...], min_std: float = 0.02) -> dict:
    """R^2 / RMSE of activations [N, M] against reference labels [N, M] (see the module docstring)."""
    predicted, reference = predicted.astype(np.float64), reference.astype(np.float64)
    error = predicted - reference
    sse = (error**2).sum(0)
    sst = ((reference - reference.mean(0)) ** 2).sum(0)
    varying = reference.std(0) > min_std
    per_muscle = 1 - sse / np.maximum(sst, 1e-12)
    rmse_muscle = np.sqrt((error**2).mean(0))
    index = {n: j for j, n in enumerate(names)}
    return {
        "frames": len(reference),
        "r2_pooled": float(1 - sse.sum() / max(sst.sum(), 1e-12)),
        "rmse": float(np.sqrt((error**2).mean())),
        "mae": float(np.abs(error).mean()),
        "r2_mean_per_muscle": float(per_muscle[varying].mean()) if varying.any() else float("nan"),
        "r2_median_per_muscle": float(np.median(per_muscle[varying])) if varying.any() else float("nan"),
        "muscles_in_mean": int(varying.sum()),
        "key_muscles": {
            n: {"r2": float(per_muscle[index[n]]), "rmse": float(rmse_muscle[index[n]])}
            for n in KEY_MUSCLES
            if n in index
        },
        "per_muscle_r2": {n: float(per_muscle[j]) for j, n in enumerate(names) if varying[j]},
    }


def com_agreement(predicted: np.ndarray, reference: np.ndarray) -> dict:
    """R^2 and RMSE of COM velocity and acceleration [N, 6] (`COM_OUTPUTS`) against the labels: per component
    (SST around the component's mean), and their mean over the three axes as PG-BIG A.8 aggregates them
    ("COM velocity and acceleration ... mean R^2"); RMSE over all three components."""
    predicted, reference = predicted.astype(np.float64), reference.astype(np.float64)
    error = predicted - reference
    r2 = 1 - (error**2).sum(0) / np.maximum(((reference - reference.mean(0)) ** 2).sum(0), 1e-12)
    out = {f"{name}_r2": float(v) for name, v in zip(COM_OUTPUTS, r2)}
    for key, part in (("vel", slice(0, 3)), ("acc", slice(3, 6))):
        out[f"com_{key}_r2"] = float(r2[part].mean())
        out[f"com_{key}_rmse"] = float(np.sqrt((error[:, part] ** 2).mean()))
    return out


@torch.no_grad()
def evaluate(model: MuscleSurrogate, clips: list[tuple], min_std: float = 0.02, symmetric: bool = False) -> dict:
    """`agreement` of the surrogate run on each whole clip, over converged frames of all clips, and
    `com_agreement` of its COM head over all frames; ``symmetric``: of `MuscleSurrogate.predict_symmetric`."""
    was_training = model.training
    model.eval()
    predicted, reference, within, com_predicted, com_reference = [], [], [], [], []
    for q, mask, target, converged, com in clips:
        activations, com_hat = (model.predict_symmetric if symmetric else model.predict)(q, mask)
        predicted.append(activations[0][converged].numpy())
        reference.append(target[converged].numpy())
        com_predicted.append(com_hat[0].numpy())
        com_reference.append(np.asarray(com))
        if len(reference[-1]) >= WITHIN_CLIP_FRAMES:
            within.append(agreement(predicted[-1], reference[-1], model.names, min_std)["r2_pooled"])
    model.train(was_training)
    scores = agreement(np.concatenate(predicted), np.concatenate(reference), model.names, min_std)
    scores.update(
        {
            "r2_within_clip_mean": float(np.mean(within)) if within else float("nan"),
            "r2_within_clip_median": float(np.median(within)) if within else float("nan"),
            "clips_within": len(within),
        }
    )
    scores.update(com_agreement(np.concatenate(com_predicted), np.concatenate(com_reference)))
    return scores
