"""Inference-time biomechanical guidance: optimise the latent sequence through decoder, body model and surrogate.

PG-BIG Sec. 3.3 and A.1: the sampled latents Z* are refined by gradient descent (Adam) on
L = w_prox L_prox + alpha(k) L_guide, L_guide = l_omega L_omega + l_foot L_foot + l_v L_v + l_a L_a + l_act L_act
+ l_ground L_ground + l_jerk L_jerk + l_speed L_speed + l_skim L_skim (`biomotion.guidance.losses`; the last four
are ours), with
the staged schedule of A.1: proximity only for the first ``physics_start`` iterations, then the physics terms
ramped in linearly over ``ramp`` iterations, and from ``quantize_at`` on (if set) the latents are re-quantised
(straight-through nearest-code lookup, the T2M-GPT quantiser's gradient), so the final motion is again a sequence
of codebook entries. Last, the feet are planted in coordinate space (`biomotion.guidance.planting`: stance feet
held still on the floor by inverse kinematics of the legs), which latent guidance alone cannot do exactly.

Defaults, and where they leave Table 5 (chosen on the example profile, ``python benchmarks/guidance_weights.py``,
or on the generator's dev subjects, ``python benchmarks/dev_subjects.py``; never on evaluation subjects; the
evidence is in docs/decisions/guidance-weights.md and the pages it links):
- 40 iterations, physics from the first one: guidance starts from the sample itself, where the proximity gradient is
  exactly zero, so A.1's proximity-only warm-up would not move anything; 40 fits the 1 s CPU budget
  (``benchmarks/generation.py``).
- l_v 0.1, l_a 1, l_act 10 as Table 5; l_omega 1 instead of 10 and l_foot 100 (Table 5 gives none): with Table 5's
  weights guidance slows the legs while the pelvis keeps its speed, and sliding rises.
- l_speed 1000 holds the requested speed (`losses.locomotion_speed`); lighter, runs come out slow.
- l_posture 3000 (ours, with a person's reference clips only: `losses.posture`) holds each clip's mean posture at
  the person's (`biomotion.generation.posture`): the largest identity gain for the least muscle and jerk cost.
- tempo on (``tempo``, ours: `biomotion.guidance.tempo`): when a speed is asked for, the sample is first played
  faster or slower (0.8-1.25 times) to reach it, and guidance refines the latents through that playback, so the
  speed term starts near its target instead of dragging the pelvis ahead of planted feet
  (docs/decisions/tempo.md).
- no re-quantisation (``quantize_at=None``): snapping the refined latents back to codes returns much of the gains,
  so the decoder reads the refined latents.
- foot planting on (``planting``, `biomotion.guidance.planting`; docs/decisions/foot-planting.md).
- the foot and ground terms act on stance points (`stance_mask`: below 5 cm and slower than 1.5 times the body),
  so a slow walk's low swing foot is not stopped (docs/decisions/stance-mask.md). With a tokenizer that decodes
  foot contact (`configs/tokenizer_foot_contact.yaml`; not the shipped one) the mask is read from its channels
  instead (``decoded_contact``).
- no ZMP term (``w_zmp`` 0; ours, after HUMOS Sec. 3.4: `losses.zmp_support`, the ZMP of body motion differenced
  from the poses guidance already computes, `biomotion.body.balance.sampled_body_motion`): it raises ZMP in
  support a little at a cost in foot contact and time; the API turns it on (``GuidanceConfig(w_zmp=300)``).
- l_skim 10 (ours: `losses.foot_skim`, the horizontal speed of foot points near the floor whether or not the stance
  mask holds them): feet that reach and leave the floor at swing speed are in no stance, so neither L_foot nor
  planting holds them (docs/decisions/foot-skim.md).
- no low-pass (``smooth_hz`` None; ours): the guided coordinates may be low-passed before planting (zero-lag
  Butterworth, `biomotion.motion.lowpass`, the filter the real clips went through at their source), ``biomotion
  generate --smooth HZ``: less jerk and fewer muscle-limit violations, a little more foot sliding.
- user targets (``control``, ours after FlexMotion Sec. 3.3's controls: `biomotion.guidance.control`): with a
  control spec one more term, ``control``, joins the sum with weight 1 (the spec weighs its own targets; muscle
  activation targets act on the surrogate's activations of the same step), and after planting the coordinates
  themselves are corrected until the path and value targets are met (``control_fit``,
  `biomotion.guidance.control_fit`: what latents alone cannot reach). Bounds on the vertical GRF and joint moments
  are then measured as the analysis measures the written files; a missed one is moved inwards by what it missed
  and guidance runs again from the same sample (``bound_rounds``, `biomotion.guidance.measured_bounds`). Without a
  spec nothing changes.

Kinematics come from the canonical body model (generic size; clips are placed in that frame, see
`biomotion.data.placement`), so guidance is independent of the person's size: a uniformly scaled model moves the
same, scaled. A posture shift per clip (`biomotion.generation.posture.centring_shift`), when given, is added to
every decoded frame, so guidance works on the person's posture rather than the prior's. Decoded rotations are
clamped to the model's coordinate ranges (the decoder has no notion of joint limits: unclamped, pro_sup sat
outside its range in every generated frame). Before the losses, each clip is put on the floor (pelvis height
lowered so that the 5th percentile of its lowest foot point is at y = 0, as for the training clips); that offset
is not optimised.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from biomotion.errors import ModelError
from biomotion.guidance import losses
from biomotion.guidance.bound_fit import BoundFitConfig, fit_bounds
from biomotion.guidance.control_fit import ControlFitConfig, fit_control
from biomotion.guidance.planting import PlantingConfig, plant_feet
from biomotion.guidance.tempo import WARP_RANGE, warp
from biomotion.models.bundle import GuidanceBounds
from biomotion.models.foot_contact import group_members, mean_horizontal_speed, points_in_contact, stance_mask
from biomotion.models.vqvae import MotionVQVAE

PELVIS_TY = 4
TERMS = (
    "angular_velocity",
    "foot_contact",
    "com_velocity",
    "com_acceleration",
    "activation",
    "ground",
    "angular_jerk",
    "locomotion_speed",
    "posture",
    "amplitude",
    "com_energy",
    "zmp",
    "foot_skim",
)


@dataclass(frozen=True)
class GuidanceConfig:
    """Schedule and weights (PG-BIG Table 5 where it gives them)."""

    iterations: int = 40
    physics_start: int = 0
    ramp: int = 10
    quantize_at: int | None = None
    lr: float = 0.1
    w_proximity: float = 1.0
    w_angular_velocity: float = 1.0
    w_foot_contact: float = 100.0
    w_com_velocity: float = 0.1
    w_com_acceleration: float = 1.0
    w_activation: float = 10.0
    w_ground: float = 100.0
    w_angular_jerk: float = 0.01
    w_locomotion_speed: float = 1000.0
    pace_window: float | None = 1.0  # s: a requested speed held in every window this long (`losses.locomotion_pace`)
    w_posture: float = 3000.0
    w_amplitude: float = 1000.0  # each coordinate's std over the clip held at the person's (`losses.amplitude`)
    w_com_energy: float = 100.0  # COM energy fluctuation above the population's (`losses.com_energy`); 0 skips it
    w_zmp: float = 0.0  # ZMP outside the stance support (`losses.zmp_support`, HUMOS Sec. 3.4); 0 skips the term
    w_foot_skim: float = 10.0  # horizontal speed of foot points near the floor (`losses.foot_skim`); 0 skips it
    contact_height: float = 0.05  # m: a foot point of the unguided sample this low and ... (`stance_mask`)
    stance_speed_ratio: float | None = 1.5  # ... slower than this x the clip's speed is in stance (None: height only)
    stance_speed_floor: float = 0.5  # m/s: ... or slower than this (the metrics' skate speed)
    decoded_contact: bool = True  # m_t from the tokenizer's contact channels when it has them (`Guide.contact`)
    tempo: tuple[float, float] | None = WARP_RANGE  # playback factors that may bring a sample to the asked speed
    smooth_hz: float | None = None  # zero-lag Butterworth cutoff on the guided coordinates before planting; None: off
    planting: PlantingConfig | None = PlantingConfig()  # after guidance (immutable settings); None skips it
    control_fit: ControlFitConfig | None = ControlFitConfig()  # with control targets, the last stage; None skips it
    bound_rounds: int = 2  # more rounds where the analysis finds a GRF/moment bound missed (`measured_bounds`)
    bound_margin: float = 0.03  # each round moves a missed bound by what it missed plus this share of the bound
    bound_fit: BoundFitConfig | None = BoundFitConfig()  # caps still missed after the rounds (`bound_fit`); None: off

    def alpha(self, k: int) -> float:
        """Weight of the physics terms at iteration k (0 before ``physics_start``, linear ramp to 1)."""
        if k < self.physics_start:
            return 0.0
        return min(1.0, (k - self.physics_start + 1) / max(self.ramp, 1))


@dataclass
class Kinematics:
    """Decoded clips placed on the floor: q [B, T, 39], feet [B, T, K, 3], COM [B, T, 3] (canonical size), and
    the decoded contact probabilities [B, T, 4] when the tokenizer has contact channels."""

    q: torch.Tensor
    feet: torch.Tensor
    com: torch.Tensor
    contact: torch.Tensor | None = None
    zmp: torch.Tensor | None = None  # [B, T, 3], with ``loaded`` [B, T], when the ZMP term is on
    loaded: torch.Tensor | None = None


@dataclass
class GuidanceResult:
    """Guided coordinates [B, T, 39] (canonical, on the floor; feet planted unless planting is off), the same
    before planting (``unplanted``: the decoded final latents), final latents, per-iteration batch means: the total
    loss, ``guidance`` (the weighted physics sum, without the schedule's alpha) and each term."""

    q: torch.Tensor
    unplanted: torch.Tensor
    latents: torch.Tensor
    history: list[dict[str, float]] = field(default_factory=list)


class Guide:
    """Guidance for one action: tokenizer decoder + canonical body model + optional muscle surrogate."""

    def __init__(
        self,
        tokenizer: MotionVQVAE,
        body,
        bounds: GuidanceBounds,
        speed_high: torch.Tensor,
        jerk_high: torch.Tensor,
        surrogate=None,
        config: GuidanceConfig | None = None,
        posture_shift: torch.Tensor | None = None,
        posture_target: torch.Tensor | None = None,
        tempo: torch.Tensor | None = None,
        frames: int | None = None,
        amplitude_target: torch.Tensor | None = None,
        energy_high: float | None = None,
        control=None,
    ) -> None:
        from biomotion.body.contact import foot_points

        self.tokenizer, self.bounds, self.surrogate = tokenizer, bounds, surrogate
        self.config = config or GuidanceConfig()
        self.body = body.to(torch.float32)
        feet = foot_points(body)
        self.feet_bodies, self.feet_offsets = feet.bodies, feet.offsets.to(torch.float32)
        self.feet_sides = feet.feet
        self.contact_members = group_members(feet.names)  # [4, K]: the foot points of each contact channel
        self.surrogate_reads_feet = getattr(surrogate, "points", None) is not None
        if self.surrogate_reads_feet and surrogate.points.names != feet.names:
            raise ModelError(
                f"the muscle surrogate's foot points {surrogate.points.names} are not the guidance body's {feet.names}"
            )
        self.speed_high, self.jerk_high = speed_high.to(torch.float32), jerk_high.to(torch.float32)
        self.rate = tokenizer.config.rate
        ranges = self.body.ranges.to(torch.float32)
        self.lower, self.upper = ranges[:, 0] + 1e-6, ranges[:, 1] - 1e-6  # inside after float32 rounding
        self.rotational = torch.tensor([not n.startswith("pelvis_t") for n in self.body.coordinate_names])
        self.posture_shift = None if posture_shift is None else posture_shift.to(torch.float32)  # [B, 39]
        self.posture_target = None if posture_target is None else posture_target.to(torch.float32)  # [39]
        self.amplitude_target = None if amplitude_target is None else amplitude_target.to(torch.float32)  # [39]
        self.energy_high = energy_high  # J/kg: the population's COM energy fluctuation (`losses.com_energy`)
        if tempo is not None and frames is None:
            raise ValueError("a tempo needs the number of frames to play")
        self.tempo, self.frames = tempo, frames  # [B] playback factors (`biomotion.guidance.tempo`), output frames
        self.control = control  # `biomotion.guidance.control.Control`: user targets, one more term (weights inside)
        self.control_reads_muscles = control is not None and any(
            t.quantity == "muscle_activation" for t in control.targets
        )

    def kinematics(self, z: torch.Tensor) -> Kinematics:
        """Decode latents [B, N, D], play them at the tempo when one is set, add the posture shift and put each
        clip on the floor (differentiable except for the floor offset)."""
        from biomotion.body.balance import loaded_zero_moment_point, sampled_body_motion
        from biomotion.body.kinematics import (
            body_coms,
            center_of_mass,
            forward_kinematics,
            points_in_ground,
        )

        q, contact = self.tokenizer.decode_with_contact(z)
        if self.tempo is not None:
            q = warp(q, self.tempo, self.frames)
            contact = None if contact is None else warp(contact, self.tempo, self.frames)
        if self.posture_shift is not None:
            q = q + self.posture_shift[:, None]
        q = torch.where(self.rotational, torch.minimum(torch.maximum(q, self.lower), self.upper), q)
        flat = q.reshape(-1, q.shape[-1])
        poses = forward_kinematics(self.body, flat)
        feet = points_in_ground(poses, self.feet_bodies, self.feet_offsets).view(*q.shape[:2], -1, 3)
        com = center_of_mass(self.body, flat, poses).view(*q.shape[:2], 3)
        offset = torch.quantile(feet[..., 1].amin(-1).detach(), 0.05, dim=-1)  # [B]
        lift = torch.zeros(q.shape[-1], dtype=q.dtype)
        lift[PELVIS_TY] = 1.0
        down = offset[:, None, None]
        up = torch.tensor([0.0, 1.0, 0.0], dtype=q.dtype)
        zmp = loaded = None
        if self.config.w_zmp > 0:  # body motion by differences of the poses at hand (`sampled_body_motion`)
            coms = body_coms(self.body, flat, poses).view(*q.shape[:2], -1, 3) - down[..., None] * up
            bodies = sampled_body_motion(coms, poses.rotations.view(*q.shape[:2], -1, 3, 3), self.rate)
            zmp, loaded = loaded_zero_moment_point(self.body, bodies)
        return Kinematics(q - down * lift, feet - down[..., None] * up, com - down * up, contact, zmp, loaded)

    def contact(self, k: Kinematics) -> torch.Tensor:
        """[B, T, K] contact mask m_t of the foot points of decoded clips: the points of every contact channel the
        decoder puts above 0.5 when it has channels (and ``decoded_contact`` is on), else the kinematic rule
        (`stance_mask` with the config's thresholds)."""
        c = self.config
        if c.decoded_contact and k.contact is not None:
            return points_in_contact(k.contact.detach() > 0.5, self.contact_members)
        return stance_mask(k.feet, k.q, self.rate, c.contact_height, c.stance_speed_ratio, c.stance_speed_floor)

    def terms(
        self, k: Kinematics, contact: torch.Tensor, speed: torch.Tensor, paced: bool = False
    ) -> dict[str, torch.Tensor]:
        """Each guidance term [B] (PG-BIG Table 1 + ground, jerk and speed); ``speed`` [B] the target locomotion
        speed (m/s, canonical size), held over every window of ``pace_window`` when ``paced`` (a requested speed),
        else on the clip's mean."""
        b = self.bounds
        window = None if not paced or self.config.pace_window is None else round(self.config.pace_window * self.rate)
        out = {
            "angular_velocity": losses.angular_velocity(k.q, self.rate, self.speed_high),
            "foot_contact": losses.foot_contact(k.feet, self.rate, contact),
            "com_velocity": losses.com_velocity(k.com, self.rate, *b.com_speed),
            "com_acceleration": losses.com_acceleration(k.com, self.rate, *b.com_acceleration),
            "ground": losses.ground(k.feet, contact),
            "angular_jerk": losses.angular_jerk(k.q, self.rate, self.jerk_high),
            "locomotion_speed": (
                losses.locomotion_speed(k.q, self.rate, speed)
                if window is None
                else losses.locomotion_pace(k.q, self.rate, speed, window)
            ),
        }
        if self.posture_target is not None:
            out["posture"] = losses.posture(k.q, self.posture_target)
        if self.amplitude_target is not None and self.config.w_amplitude > 0:
            out["amplitude"] = losses.amplitude(k.q, self.amplitude_target)
        if self.energy_high is not None and self.config.w_com_energy > 0:
            out["com_energy"] = losses.com_energy(k.com, self.rate, self.energy_high)
        if k.zmp is not None:
            out["zmp"] = losses.zmp_support(k.zmp, k.loaded, k.feet, contact)
        if self.config.w_foot_skim > 0:
            out["foot_skim"] = losses.foot_skim(k.feet, self.rate, self.config.contact_height)
        activations = muscles = None
        if self.surrogate is not None:
            # a surrogate with contact features reads the foot heights computed above (the same points)
            heights = {"heights": k.feet[..., 1]} if self.surrogate_reads_feet else {}
            if self.control_reads_muscles:  # the outputs' estimate (`predict_symmetric`), not one pass's error
                activations = self.surrogate.predict_symmetric(k.q, **heights)[0]
            else:
                activations = self.surrogate(k.q, **heights)
            muscles = self.surrogate.names
            out["activation"] = losses.activation(activations, self.surrogate.low, self.surrogate.high)
        if self.control is not None:  # muscle_activation targets read the same activations
            out["control"] = self.control.loss(
                k.q, k.com, self.rate, self.frames, self.body, activations=activations, muscles=muscles
            )
        return out

    def smoothed(self, q: torch.Tensor, cutoff_hz: float) -> torch.Tensor:
        """Coordinates q [B, T, n] low-passed along T (`biomotion.motion.lowpass`, zero lag), rotations clamped
        to their ranges again and coupled coordinates (knee ``_beta``) recomputed from their independent ones."""
        from biomotion.body.kinematics import apply_couplers
        from biomotion.motion import lowpass

        filtered = torch.as_tensor(
            np.ascontiguousarray(lowpass(q.numpy(), self.rate, cutoff_hz, axis=1)), dtype=q.dtype
        )
        filtered = torch.where(
            self.rotational, torch.minimum(torch.maximum(filtered, self.lower), self.upper), filtered
        )
        return apply_couplers(self.body, filtered.reshape(-1, q.shape[-1])).view_as(q)

    def _quantised(self, z: torch.Tensor) -> torch.Tensor:
        codebook = self.tokenizer.quantiser.codebook
        nearest = codebook[self.tokenizer.quantiser.nearest(z.reshape(-1, z.shape[-1]))].view_as(z)
        return z + (nearest - z).detach()

    def __call__(self, z0: torch.Tensor, speed: float | None = None) -> GuidanceResult:
        """Refine latents z0 [B, N, D] (the unguided sample's codebook entries) towards locomotion at ``speed``
        (m/s at the canonical size; None keeps each sample's own mean speed).

        With control bounds on the vertical GRF or a joint moment, the result is measured as the analysis measures
        the outputs (`biomotion.guidance.measured_bounds`); where a bound is missed in any clip, guidance runs
        again from z0 with that bound moved inwards by the worst miss plus ``bound_margin`` of it, up to
        ``bound_rounds`` more times. The round whose clips miss their bounds least (summed) is kept; caps it still
        misses go to the coordinate-space stage (`biomotion.guidance.bound_fit`, ``bound_fit``), then paths and
        values are met again."""
        from biomotion.guidance.measured_bounds import measured_bounds, measured_excess, tightened

        c = self.config
        spec = self.control
        indices = [] if spec is None or c.bound_rounds <= 0 else measured_bounds(spec)
        result = self._guide(z0, speed)
        if not indices:
            return result
        frames = self.frames or result.q.shape[1]
        offsets = np.zeros(len(indices))
        best, best_miss = result, None
        try:
            for round_ in range(c.bound_rounds + 1):
                excess = measured_excess(self.body, result.q[:, :frames], self.rate, spec, indices).max(0)
                miss = float(np.clip(excess, 0, None).sum())
                if best_miss is None or miss < best_miss:
                    best, best_miss = result, miss
                if miss == 0 or round_ == c.bound_rounds:
                    break
                values = np.array([abs(spec.targets[i].value) for i in indices])
                offsets = offsets + np.where(excess > 0, excess + c.bound_margin * values, 0.0)
                self.control = tightened(spec, indices, offsets)
                result = self._guide(z0, speed)
        finally:
            self.control = spec
        if best_miss == 0 or c.bound_fit is None:
            return best
        q, _ = fit_bounds(
            self.body,
            best.q,
            spec,
            self.rate,
            self.feet_bodies,
            self.feet_offsets,
            self.feet_sides,
            self.lower,
            self.upper,
            frames,
            c.bound_fit,
        )
        return GuidanceResult(self._fit_control(q), best.unplanted, best.latents, best.history)

    def _fit_control(self, q: torch.Tensor) -> torch.Tensor:
        """The path and value targets met on the coordinates (`biomotion.guidance.control_fit`), when set."""
        c = self.config
        if self.control is None or c.control_fit is None:
            return q
        return fit_control(
            self.body,
            q,
            self.control,
            self.rate,
            self.feet_bodies,
            self.feet_offsets,
            self.lower,
            self.upper,
            self.rotational,
            self.frames,
            c.control_fit,
        )

    def _guide(self, z0: torch.Tensor, speed: float | None) -> GuidanceResult:
        """One run of latent guidance, foot planting and the coordinate-space control fit (`__call__`)."""
        c = self.config
        z0 = z0.detach()
        z = z0.clone().requires_grad_(True)
        optimiser = torch.optim.Adam([z], lr=c.lr)
        start = self.kinematics(z0)
        contact = self.contact(start)
        target = (
            mean_horizontal_speed(start.q.detach(), self.rate)
            if speed is None
            else torch.full((len(z0),), float(speed))
        )
        weights = {t: getattr(c, f"w_{t}") for t in TERMS} | {"control": 1.0}  # the control weighs its targets
        history = []
        for k in range(c.iterations):
            used = self._quantised(z) if c.quantize_at is not None and k >= c.quantize_at else z
            terms = self.terms(self.kinematics(used), contact, target, paced=speed is not None)
            guide = sum(weights[t] * v for t, v in terms.items())
            loss = (c.w_proximity * losses.proximity(used, z0) + c.alpha(k) * guide).sum()
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            history.append(
                {
                    "iteration": k,
                    "alpha": c.alpha(k),
                    "loss": loss.item() / len(z0),
                    "guidance": guide.mean().item(),
                    **{t: v.mean().item() for t, v in terms.items()},
                }
            )
        with torch.no_grad():
            final = self._quantised(z) if c.quantize_at is not None else z
            q = self.kinematics(final).q
            if c.smooth_hz is not None:
                q = self.smoothed(q, c.smooth_hz)
        planted = (
            q
            if c.planting is None
            else plant_feet(
                self.body, q, self.feet_bodies, self.feet_offsets, self.feet_sides, self.lower, self.upper, c.planting
            )
        )
        return GuidanceResult(self._fit_control(planted), q, final.detach(), history)
