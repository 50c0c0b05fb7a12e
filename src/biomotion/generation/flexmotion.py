"""Generation with FlexMotion (`biomotion.models.flexmotion`; FlexMotion Sec. 3.2-3.3): DDIM samples of the
latent, conditioned on a text and a subject profile, decoded into coordinates together with the generalized
forces, ground reaction and muscle activations *as generated*, and their agreement with what the body model
recomputes from the generated coordinates (`consistency`).

A clip is one window of the model (64 frames at 30 Hz, 2.13 s, in the window's frame: mean heading and mean
horizontal pelvis position zero). Files (`write_flexmotion`): ``motion.mot`` (canonical Rajagopal coordinates,
degrees), ``torques_generated.sto`` (N·m and N, canonical body), ``grf_generated.mot`` (per foot, N),
``activations_generated.sto`` and ``metrics.json`` (request, consistency figures). The PG-BIG outputs' full
analysis (BVH, figures, viewer) is not written for FlexMotion clips.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.body.contact import infer_ground_reaction
from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.errors import ConfigError
from biomotion.models.flexmotion import FlexMotion, profile_vector
from biomotion.models.refiner import GRAVITY, Refiner, RefinerConfig, finite_rates

WEIGHTS = "flexmotion.safetensors"
SURROGATE = "surrogate.safetensors"


@dataclass
class FlexMotionGenerator:
    """Shipped FlexMotion weights, the canonical body (as a `Refiner` for its physics helpers) and the surrogate
    (muscle names; recomputed activations)."""

    model: FlexMotion
    refiner: Refiner
    surrogate: object

    @classmethod
    def load(cls, data_root: str | Path, checkpoints: str | Path = "checkpoints") -> FlexMotionGenerator:
        from biomotion.data.clips import body_model
        from biomotion.muscles.surrogate import MuscleSurrogate

        checkpoints = Path(checkpoints)
        if not (checkpoints / WEIGHTS).is_file():
            raise ConfigError(f"{checkpoints / WEIGHTS}: no FlexMotion weights (`biomotion train flexmotion`)")
        model = FlexMotion.load(checkpoints / WEIGHTS)
        body = body_model(data_root)
        surrogate = MuscleSurrogate.load(checkpoints / SURROGATE, body=body).eval()
        return cls(model, Refiner.new(RefinerConfig(rate=model.config.rate), body), surrogate)

    @property
    def weight(self) -> float:
        return float(self.refiner.body.total_mass) * GRAVITY

    def sample(
        self,
        texts: list[str],
        profiles: list,
        *,
        seed: int = 0,
        steps: int | None = None,
        guidance: float | None = None,
        sentences: torch.Tensor | None = None,
        control=None,
    ) -> dict[str, torch.Tensor]:
        """Decoded modalities (`biomotion.models.flexmotion.split`, torques and forces in body weights) of one
        clip per (text, profile); ``sentences`` their MiniLM embeddings when at hand; ``control`` the control
        module bound to its signal (`biomotion.models.control_net.ControlNet.bind`) or None."""
        from biomotion.models.motion_text_evaluator import embed_sentences

        if not texts or any(not isinstance(t, str) or not t.strip() for t in texts):
            raise ConfigError("flexmotion needs a non-empty action text for every clip")
        if len(profiles) != len(texts):
            raise ConfigError(f"{len(texts)} texts but {len(profiles)} profiles")
        try:
            vectors = torch.from_numpy(np.stack([profile_vector(p) for p in profiles]))
        except Exception as error:  # a profile value that is not a positive number
            raise ConfigError(f"profile: {error}") from None
        sentences = embed_sentences([t.strip() for t in texts]) if sentences is None else sentences
        return self.model.sample(sentences, vectors, seed=seed, steps=steps, guidance=guidance, control=control)


def foot_forces(forces: torch.Tensor, refiner: Refiner) -> torch.Tensor:
    """Per-foot sums [..., T, 2, 3] (right, left) of point forces [..., T, K, 3]."""
    feet = np.array(refiner.feet.feet)
    return torch.stack([forces[..., feet == side, :].sum(-2) for side in ("r", "l")], -2)


@torch.no_grad()
def consistency(refiner: Refiner, decoded: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """Per clip [B]: ``torque_rel_rmse``, the RMSE of the generated torques against inverse dynamics of the
    generated coordinates with the generated contact forces (at the contact points of the generated pose), over
    the interior frames and all 39 coordinates, relative to the RMS of the recomputed torques; ``grf_bw``, the
    RMSE (body weights, over frames, feet and axes) of the generated per-foot ground reaction against what the
    contact solve (`infer_ground_reaction`) finds the generated coordinates need; ``activation_rmse`` against the
    surrogate on the generated coordinates is added by `write_flexmotion`'s caller when wanted."""
    weight = float(refiner.body.total_mass) * GRAVITY
    every = torch.ones(len(CANONICAL_COORDINATES), dtype=torch.bool)
    body64 = refiner.body.to(torch.float64)
    torque, grf = [], []
    for b in range(len(decoded["q"])):
        full = refiner.full(decoded["q"][b].float(), every)
        qd, qdd = finite_rates(full, refiner.config.rate)
        _, feet = refiner.kinematics(full)
        loads = [
            ExternalLoad(
                refiner.body.body_names[int(refiner.feet.bodies[k])], decoded["forces"][b, :, k] * weight, feet[:, k]
            )
            for k in range(len(refiner.feet.names))
        ]
        inner = slice(1, len(full) - 1)
        recomputed = inverse_dynamics(refiner.body, full, qd, qdd, loads)[inner] / weight
        generated = decoded["torques"][b, inner]
        rms = recomputed.square().mean().sqrt().clamp(min=1e-9)
        torque.append(float((generated - recomputed).square().mean().sqrt() / rms))
        solved = infer_ground_reaction(body64, full.double(), qd.double(), qdd.double())
        needed = solved.foot_force.float() / weight
        grf.append(float((foot_forces(decoded["forces"][b], refiner) - needed)[inner].square().mean().sqrt()))
    return {"torque_rel_rmse": np.array(torque), "grf_bw": np.array(grf)}


def write_flexmotion(
    out: Path, generator: FlexMotionGenerator, decoded: dict[str, torch.Tensor], request: dict
) -> list[dict[str, Path]]:
    """Write each sample's files (module docstring) into ``out`` (one sample) or ``out/sample_N``; returns them."""
    from biomotion.io.mot import write_motion, write_storage
    from biomotion.motion import Motion

    rate, weight = generator.model.config.rate, generator.weight
    n = len(decoded["q"])
    figures = consistency(generator.refiner, decoded)
    every = torch.ones(n, len(CANONICAL_COORDINATES), dtype=torch.bool)
    with torch.no_grad():
        recomputed = generator.surrogate(decoded["q"].float(), every)
    names = list(getattr(generator.surrogate, "names", [f"muscle_{k}" for k in range(recomputed.shape[-1])]))
    files = []
    for b in range(n):
        folder = out if n == 1 else out / f"sample_{b}"
        folder.mkdir(parents=True, exist_ok=True)
        q = decoded["q"][b].double().numpy()
        times = np.arange(len(q)) / rate
        motion = Motion(times=times, names=CANONICAL_COORDINATES, values=q, mask=np.ones(q.shape[1], bool))
        written = {"motion": write_motion(folder / "motion.mot", motion, name="flexmotion")}
        written["torques"] = write_storage(
            folder / "torques_generated.sto",
            [f"{c}_force" for c in CANONICAL_COORDINATES],
            times,
            decoded["torques"][b].double().numpy() * weight,
            name="Generalized forces as generated (FlexMotion)",
        )
        grf = foot_forces(decoded["forces"][b], generator.refiner).double().numpy() * weight
        written["grf"] = write_storage(
            folder / "grf_generated.mot",
            [f"ground_force_{side}_v{a}" for side in ("r", "l") for a in "xyz"],
            times,
            grf.reshape(len(q), 6),
            name="Ground reaction as generated (FlexMotion)",
        )
        written["activations"] = write_storage(
            folder / "activations_generated.sto",
            names,
            times,
            decoded["activations"][b].double().numpy().clip(0, 1),
            name="Muscle activations as generated (FlexMotion)",
        )
        act_rmse = float((decoded["activations"][b].clamp(0, 1) - recomputed[b]).square().mean().sqrt())
        metrics = {
            "generator": "flexmotion",
            "request": request,
            "consistency": {
                "torque_rel_rmse": float(figures["torque_rel_rmse"][b]),
                "grf_rmse_bw": float(figures["grf_bw"][b]),
                "activation_rmse_vs_surrogate": act_rmse,
                "definitions": " ".join(
                    consistency.__doc__.split("Per clip [B]: ")[1].split(" ``activation_rmse``")[0].split()
                ),
            },
        }
        (folder / "metrics.json").write_text(json.dumps(metrics, indent=1))
        written["metrics"] = folder / "metrics.json"
        files.append(written)
    return files


def generate(
    *,
    action: str,
    out: Path,
    data_root: Path,
    checkpoints: Path | None = None,
    profile=None,
    seed: int = 0,
    samples: int = 1,
    seconds: float | None = None,
    command: str = "",
    control=None,
) -> dict:
    """One request with FlexMotion (``biomotion generate --generator flexmotion``): ``samples`` clips of the
    ``action`` text for ``profile`` (a `Profile` or None), seeded; returns files and timings.

    ``control``: a `biomotion.guidance.control.Control` met with the control module
    (`biomotion.generation.flexmotion_control.generate_controlled`; sample k uses seed ``seed + k``); the
    written motion is then the controlled, placed and fitted one, and metrics.json records the bounds."""
    if samples < 1:
        raise ConfigError(f"--samples must be at least 1, got {samples}")
    started = time.perf_counter()
    generator = FlexMotionGenerator.load(data_root, checkpoints or "checkpoints")
    length = generator.model.config.window / generator.model.config.rate
    notes = []
    if seconds is not None and (not math.isfinite(seconds) or seconds <= 0):
        raise ConfigError(f"--seconds {seconds:g}: must be a positive number")
    if seconds is not None and seconds > length:
        notes.append(f"FlexMotion generates one window of {length:.2f} s; --seconds {seconds:g} gives the whole window")
        seconds = None
    request = {"command": command, "text": action, "seed": seed, "samples": samples, "notes": notes}
    keep = None if seconds is None else max(2, round(seconds * generator.model.config.rate))
    if control is None:
        decoded = generator.sample([action] * samples, [profile] * samples, seed=seed)
        if keep is not None:
            decoded = {k: v[:, :keep] for k, v in decoded.items()}
    else:
        from biomotion.generation.flexmotion_control import check_spec, generate_controlled, load_control_net

        frames = keep or generator.model.config.window
        check_spec(control, frames / generator.model.config.rate, getattr(generator.surrogate, "names", ()))
        net = load_control_net(checkpoints or "checkpoints", generator.model)
        clips = [
            generate_controlled(generator, net, action, profile, control, seed=seed + k, frames=keep)
            for k in range(samples)
        ]
        decoded = {k: torch.cat([c.decoded[k] for c in clips]) for k in clips[0].decoded}
        request["control"] = {
            "source": control.source,
            "placement_heading_x_z_vx_vz": [c.frame.tolist() for c in clips],
            "sampling_rounds": [c.rounds for c in clips],
            "bounds": [c.bounds for c in clips],
        }
    done = time.perf_counter()
    files = write_flexmotion(Path(out), generator, decoded, request)
    return {
        "files": files,
        "notes": notes,
        "generate_seconds": done - started,
        "write_seconds": time.perf_counter() - done,
    }
