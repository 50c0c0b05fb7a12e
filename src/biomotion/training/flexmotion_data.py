"""The multimodal training set of FlexMotion (Sec. 3.1): fixed-length windows of the dataset cache's training-split
clips with every modality the model reads (`biomotion.models.flexmotion`).

Per window of a clip (canonical coordinates at the cache rate, which is FlexMotion's rate), in the window's own
frame (`biomotion.models.refiner.to_local`: mean heading and mean horizontal pelvis position zero), so that every
modality below describes the very motion the model reads and generates:

- coordinates q and velocities q̇ (central differences, `biomotion.models.refiner.finite_rates`);
- the contact solve on the window (`biomotion.training.train_refiner.qp_targets`, i.e.
  `biomotion.body.contact.infer_ground_reaction` on the canonical body): point forces at the ten foot points and
  the generalized forces τ of inverse dynamics with those loads. No clip of the cache carries a measured force
  plate, so the ground reaction is the physics solve's for every clip (FlexMotion uses plates where measured);
- muscle activations of the shipped surrogate (`biomotion.muscles.surrogate`) on the whole clip (heading does not
  enter its features), cut to the window.

Masks: the clip's coordinate mask (absent coordinates, e.g. the Fukuchi runners' arms) covers q, q̇ and τ; the
force and activation modalities are present for every clip here (``force_present``, ``activation_present`` are
kept so a source with a missing modality can be added). Texts are the clips' label texts
(`biomotion.models.motion_text_evaluator.clip_text`); profiles the clips' subject profiles.

Windows of ``window`` frames start every ``stride`` frames; clips shorter than a window are left out. ``max_clips``
keeps every n-th clip of the split (0: all). The set is cached under ``~/.cache/biomotion/flexmotion/`` keyed by
the cache's arrays, the surrogate's weights and the settings.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from biomotion.data.registry import DatasetCache
from biomotion.errors import BiomotionError
from biomotion.models.flexmotion import N_MUSCLES, N_POINTS, profile_vector
from biomotion.models.motion_text_evaluator import clip_text
from biomotion.models.refiner import GRAVITY, Refiner, RefinerConfig, finite_rates, to_local, window_frame

DATA_FORMAT = "biomotion-flexmotion-data/1"


@dataclass(frozen=True)
class MultimodalSettings:
    window: int = 64
    stride: int = 32
    max_clips: int = 0
    split: str = "train"


@dataclass
class MultimodalSet:
    """Windows [N, W, ·]: q, qd (SI), torques [N, W, 39] and forces [N, W, K, 3] in body weights of the canonical
    body, activations [N, W, M]; per window: coordinate mask [N, 39], force_present / activation_present [N],
    text index [N] into ``texts``, profile vector [N, PROFILE_DIM], subject [N]."""

    q: torch.Tensor
    qd: torch.Tensor
    torques: torch.Tensor
    forces: torch.Tensor
    activations: torch.Tensor
    mask: torch.Tensor
    force_present: torch.Tensor
    activation_present: torch.Tensor
    text_ids: torch.Tensor
    profiles: torch.Tensor
    texts: list[str]
    subjects: list[str]
    clips: int
    body_weight: float

    def __len__(self) -> int:
        return len(self.q)


def cache_folder() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "biomotion" / "flexmotion"


def _key(cache: DatasetCache, surrogate_path: Path, settings: MultimodalSettings, ids: list[int]) -> str:
    digest = hashlib.sha256((cache.folder / "clips.safetensors").read_bytes())
    digest.update(Path(surrogate_path).read_bytes())
    digest.update(repr((DATA_FORMAT, asdict(settings), [cache.records[i]["clip_id"] for i in ids])).encode())
    return digest.hexdigest()[:20]


def build(
    cache: DatasetCache,
    body,
    surrogate_path: str | Path,
    settings: MultimodalSettings = MultimodalSettings(),
    *,
    progress: bool = True,
) -> MultimodalSet:
    """The windows of the cache's ``settings.split`` (module docstring), read from or written to `cache_folder`."""
    from safetensors.torch import load_file, save_file

    from biomotion.muscles.surrogate import MuscleSurrogate

    ids = [i for i in cache.indices(split=settings.split) if cache.records[i]["n_frames"] >= settings.window]
    if settings.max_clips:
        ids = ids[:: max(1, len(ids) // settings.max_clips)][: settings.max_clips]
    if not ids:
        raise BiomotionError(f"{cache.folder}: no {settings.split} clip of {settings.window} frames or more")
    path = cache_folder() / f"data-{_key(cache, Path(surrogate_path), settings, ids)}"
    if (path / "windows.safetensors").exists():
        arrays = load_file(str(path / "windows.safetensors"))
        info = json.loads((path / "windows.json").read_text())
        return MultimodalSet(**arrays, **info)
    refiner = Refiner.new(RefinerConfig(rate=cache.rate), body)
    surrogate = MuscleSurrogate.load(surrogate_path, body=body).eval()
    weight = float(refiner.body.total_mass) * GRAVITY
    from biomotion.training.train_refiner import qp_targets

    texts = sorted({clip_text(cache.records[i]["labels"]) for i in ids})
    parts: dict[str, list] = {k: [] for k in ("q", "qd", "torques", "forces", "activations", "mask")}
    parts.update(text_ids=[], profiles=[])
    subjects: list[str] = []
    for n, i in enumerate(ids):
        record = cache.records[i]
        q = torch.from_numpy(cache.motion(i).values).float()
        mask = torch.from_numpy(cache.masks[i])
        with torch.no_grad():
            activations = surrogate(q[None], mask[None])[0]
        starts = range(0, len(q) - settings.window + 1, settings.stride)
        for s in starts:
            cut = slice(s, s + settings.window)
            window = q[cut][None]
            local = to_local(window, window_frame(window, torch.ones(window.shape[:2], dtype=torch.bool)))[0]
            labels = qp_targets(refiner, local, mask, cache.rate)
            qd, _ = finite_rates(refiner.full(local, mask), cache.rate)
            parts["q"].append(local)
            parts["qd"].append(qd * mask)
            parts["torques"].append(labels["torques"] / weight * mask)
            parts["forces"].append(labels["forces"] / weight)
            parts["activations"].append(activations[cut])
            parts["mask"].append(mask)
            parts["text_ids"].append(texts.index(clip_text(record["labels"])))
            parts["profiles"].append(torch.from_numpy(profile_vector(record.get("profile"))))
            subjects.append(f"{record['source']}/{record['subject']}")
        if progress and (n + 1) % 50 == 0:
            print(f"flexmotion data: {n + 1}/{len(ids)} clips", flush=True)
    arrays = {k: torch.stack(v) if k != "text_ids" else torch.tensor(v) for k, v in parts.items()}
    arrays["force_present"] = torch.ones(len(subjects), dtype=torch.bool)
    arrays["activation_present"] = torch.ones(len(subjects), dtype=torch.bool)
    assert arrays["forces"].shape[2] == N_POINTS and arrays["activations"].shape[-1] == N_MUSCLES
    info = {"texts": texts, "subjects": subjects, "clips": len(ids), "body_weight": weight}
    path.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in arrays.items()}, str(path / "windows.safetensors"))
    (path / "windows.json").write_text(json.dumps(info))
    return MultimodalSet(**arrays, **info)
