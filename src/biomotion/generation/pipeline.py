"""PG-BIG inference (Fig. 2): profile + action -> codes -> latents -> (guided) motion in canonical coordinates.

1. The condition: reference clips of the person are placed like the training clips (`biomotion.data.placement`)
   and encoded by the tokenizer; with the profile's biodata and the references' metadata they form the subject
   profiler's input (A.6); the action request becomes the action features (Sec. 3.2).
2. The prior samples code indices autoregressively (temperature, top-k), one sequence per requested sample.
3. Guidance refines the codebook latents through the decoder, body model and muscle surrogate (Sec. 3.3).

With reference clips, the prior's context is also primed with the last codes of the first reference (few-shot
prompting, as a language model continues a given text), which `biomotion eval generation` measures against the
profile alone (``no_priming``); and each decoded clip is centred on the person's own posture: the population's
for the request plus the references' deviation from the population (`biomotion.generation.posture`;
``no_posture`` in the evaluation).

``personalised=False`` drops the profile (biodata, references, metadata all masked): the w/o-personalization
ablation of Table 3. A bundle trained with ``--population`` ignores the profile by construction.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, KNEE_COORDINATES
from biomotion.body.kinematics import apply_couplers
from biomotion.data.placement import GENERIC_HEIGHT, place_clip
from biomotion.data.sources import to_canonical
from biomotion.errors import BiomotionWarning, ConfigError
from biomotion.generation.posture import amplitude_ratio, centring_shift, posture_offset
from biomotion.guidance.control import Control
from biomotion.guidance.refine import GuidanceConfig, Guide
from biomotion.guidance.tempo import warp, warp_factor
from biomotion.models.actions import ActionRequest
from biomotion.models.bundle import GeneratorBundle
from biomotion.models.conditioning import (
    METADATA_FIELDS,
    action_features,
    biodata_features,
    mean_features,
    metadata_features,
)
from biomotion.models.prior import Condition
from biomotion.models.vqvae import DOWNSAMPLE, MotionVQVAE
from biomotion.motion import Motion
from biomotion.profile import Profile

CHECKPOINTS = Path(__file__).resolve().parents[3] / "checkpoints"
TOKENIZER_FILE, GENERATOR_FILE, POPULATION_FILE, SURROGATE_FILE = (
    "tokenizer.safetensors",
    "generator.safetensors",
    "population.safetensors",
    "surrogate.safetensors",
)
MAX_LATENTS = 128
#: Fewest frames a clip may have: the physics metrics difference positions twice (`biomotion.metrics.base`).
MIN_FRAMES = 4
PRIME_TOKENS = 8  # codes of a reference that prime the prior: 32 frames, about one running stride
#: Sampling temperature: at 1.0 the example runner's stride frequency wandered (1.19 +- 0.28 Hz over 8 samples of
#: 4 s), at 0.7 it is a steady 1.42 +- 0.09 Hz (measured on examples/runner_52_acl.yaml only, never on evaluation
#: subjects); lower still repeats a few codes (0.3: 15 distinct codes per clip instead of 21).
TEMPERATURE = 0.7


@dataclass
class Generated:
    """K generated clips in canonical coordinates at the canonical size, on the floor: ``q`` [K, T, 39] (guided
    when guidance ran), ``unguided`` [K, T, 39], ``unplanted`` [K, T, 39] (after latent guidance, before foot
    planting; ``q`` when either did not run), the codes [K, N], guidance history, the request, the person's
    posture offset [39] the clips were centred with (`biomotion.generation.posture`; None when they were not) and
    the tempo [K] each guided clip was played at (`biomotion.guidance.tempo`; None without one)."""

    q: torch.Tensor
    unguided: torch.Tensor
    codes: torch.Tensor
    rate: float
    action: ActionRequest
    history: list[dict[str, float]] = field(default_factory=list)
    unplanted: torch.Tensor | None = None
    posture: torch.Tensor | None = None
    tempo: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.unplanted is None:
            self.unplanted = self.q

    def motions(self, height: float | None = None, guided: bool = True) -> list[Motion]:
        """Each clip as a canonical `Motion`; pelvis translations scaled to a person of ``height`` (m)."""
        q = (self.q if guided else self.unguided).detach().double().numpy().copy()
        if height is not None:
            q[..., 3:6] *= height / GENERIC_HEIGHT
        times = np.arange(q.shape[1]) / self.rate
        return [Motion(times=times, values=clip, names=CANONICAL_COORDINATES) for clip in q]


def knee_flexion_negative(motion: Motion) -> bool:
    """True when the clip's knee angles are mostly negative: flexion-negative models (Fukuchi ``_simple``, Hamner
    2010; `biomotion.body.canonical`) rather than the canonical flexion-positive convention."""
    knees = [motion[n] for n in KNEE_COORDINATES if n in motion.names and motion.mask[motion.index(n)]]
    return bool(knees) and float(np.median(np.concatenate(knees))) < 0.0


def reference_motion(motion: Motion, body, height: float | None) -> tuple[torch.Tensor, torch.Tensor]:
    """A person's reference clip -> canonical, placed, 30 Hz coordinates [T, 39] (T a multiple of 4) and mask.
    Knee angles of a flexion-negative model are flipped to the canonical sign, with a warning."""
    flipped = knee_flexion_negative(motion)
    if flipped:
        warnings.warn(
            "reference clip has mostly negative knee angles: read as a flexion-negative model "
            "(Fukuchi _simple, Hamner 2010) and flipped to flexion-positive",
            BiomotionWarning,
            stacklevel=2,
        )
    canonical = to_canonical(motion, knee_flipped=flipped)
    clip = canonical.resample(30.0) if abs(canonical.rate - 30.0) > 1e-6 else canonical
    clip = place_clip(clip, body, height=height, treadmill_speed=None)
    n = clip.n_frames // DOWNSAMPLE * DOWNSAMPLE
    if n < DOWNSAMPLE:
        raise ConfigError(f"reference clip too short: {clip.n_frames} frames at 30 Hz, need at least {DOWNSAMPLE}")
    values = np.where(clip.mask[None], clip.values[:n], 0.0)
    return torch.tensor(values, dtype=torch.float32), torch.from_numpy(clip.mask.copy())


class Generator:
    """Tokenizer + prior bundle + canonical body model (+ surrogate): everything `biomotion generate` runs."""

    def __init__(self, tokenizer: MotionVQVAE, bundle: GeneratorBundle, body, surrogate=None) -> None:
        self.tokenizer, self.bundle, self.body, self.surrogate = tokenizer, bundle, body, surrogate
        for model in (tokenizer, bundle.prior, surrogate):  # inference only: guidance needs gradients for the
            if model is not None:  # latents alone, not for any weight (15 % of its time)
                model.requires_grad_(False)
        self.rate = tokenizer.config.rate

    @classmethod
    def load(
        cls,
        data_root: str | Path,
        checkpoints: str | Path = CHECKPOINTS,
        *,
        population: bool = False,
        surrogate: bool = True,
    ) -> Generator:
        """Shipped weights from ``checkpoints`` and the canonical Rajagopal model from ``data_root``."""
        import torch._dynamo  # noqa: F401  (torch.optim's first optimizer imports it: ~1 s, a cost of loading)

        from biomotion.data.clips import body_model

        checkpoints = Path(checkpoints)
        tokenizer = MotionVQVAE.load(checkpoints / TOKENIZER_FILE)
        bundle = GeneratorBundle.load(checkpoints / (POPULATION_FILE if population else GENERATOR_FILE))
        body, muscles = body_model(data_root), None
        if surrogate:
            from biomotion.muscles.surrogate import MuscleSurrogate

            muscles = MuscleSurrogate.load(checkpoints / SURROGATE_FILE, body=body)
        return cls(tokenizer, bundle, body, muscles)

    @torch.no_grad()
    def condition(
        self,
        action: ActionRequest,
        profile: Profile | None = None,
        references: Sequence[Motion] = (),
        personalised: bool = True,
        reference_actions: Sequence[str | None] = (),
        reference_speeds: Sequence[float | None] = (),
        biodata: bool = True,
    ) -> tuple[Condition, torch.Tensor | None, torch.Tensor | None]:
        """The prior's input for one request (batch of 1), the priming codes [1, P] (the last `PRIME_TOKENS`
        codes of the first reference clip) and the person's posture offset [39] (`posture_offset`, with the
        references' action labels and speeds where known); both None without references. ``biodata`` False
        masks the profile's biodata (its height still places the references; `biomotion.generation.routing`)."""
        from biomotion.body.kinematics import center_of_mass

        code_dim = self.tokenizer.config.code_dim
        latents, metadata, prime, offset = torch.zeros(0, code_dim), None, None, None
        if personalised and references:
            height = profile.height if profile is not None else None
            encoded, features, placed = [], [], []
            for motion in references:
                q, mask = reference_motion(motion, self.body, height)
                placed.append((q, mask))
                encoded.append(self.tokenizer.encode_continuous(q[None], mask[None])[0])
                full = torch.where(mask, q.double(), self.body.defaults)
                features.append(metadata_features(q, mask, center_of_mass(self.body, full).float(), self.rate))
            latents = torch.cat(encoded)[:MAX_LATENTS]
            metadata = mean_features(features).cat()
            prime = self.tokenizer.quantiser.nearest(encoded[0][-PRIME_TOKENS:])[None]
            offset = posture_offset(placed, self.bundle, reference_actions, reference_speeds)
        bio = biodata_features(profile if personalised and biodata else None).cat()
        if metadata is None:
            metadata = torch.zeros(2 * len(METADATA_FIELDS))
        act = action_features(action, self.bundle.vocabulary).cat()
        valid = torch.ones(max(len(latents), 1), dtype=torch.bool)
        if len(latents) == 0:
            latents, valid = torch.zeros(1, code_dim), torch.zeros(1, dtype=torch.bool)
        return Condition(latents[None], valid[None], bio[None], metadata[None], act[None]), prime, offset

    def person_amplitude(
        self,
        action: ActionRequest,
        profile: Profile | None,
        references: Sequence[Motion],
        reference_actions: Sequence[str | None] = (),
        reference_speeds: Sequence[float | None] = (),
    ) -> torch.Tensor | None:
        """[39] the person's amplitude for the request: the population's (`GeneratorBundle.amplitude`) times the
        references' ratio to the population (`biomotion.generation.posture.amplitude_ratio`); NaN where unknown,
        None without references or population amplitudes."""
        population = self.bundle.amplitude(action.action, action.speed)
        if population is None or not references:
            return None
        height = profile.height if profile is not None else None
        with warnings.catch_warnings():  # `condition` warned about a flexion-negative reference already
            warnings.simplefilter("ignore", BiomotionWarning)
            placed = [reference_motion(motion, self.body, height) for motion in references]
        ratio = amplitude_ratio(placed, self.bundle, reference_actions, reference_speeds)
        return None if ratio is None else population * ratio

    def generate(
        self,
        action: ActionRequest,
        *,
        profile: Profile | None = None,
        references: Sequence[Motion] = (),
        reference_actions: Sequence[str | None] = (),
        reference_speeds: Sequence[float | None] = (),
        seconds: float = 3.0,
        samples: int = 1,
        seed: int = 0,
        guidance: bool = True,
        personalised: bool = True,
        prime: bool = True,
        posture: bool = True,
        temperature: float = TEMPERATURE,
        top_k: int | None = 20,
        guidance_config: GuidanceConfig | None = None,
        biodata: bool = True,
        control: Control | None = None,
    ) -> Generated:
        """Sample ``samples`` clips of ``seconds`` for the request; guided unless ``guidance`` is False. With
        reference clips and ``prime``, the prior's context starts with the end of the first reference (its
        codes), so the sample continues the person's own movement pattern under the requested action; with
        ``posture``, each decoded clip is centred on the person's posture (`biomotion.generation.posture`;
        ``reference_actions`` and ``reference_speeds``: the references' labels, inferred where not given);
        ``biodata`` False masks the profile's biodata in the prior's condition (`condition`). ``control``: targets
        met through one more guidance term (`biomotion.guidance.control`; FlexMotion Sec. 3.3's controls by
        PG-BIG Sec. 3.3's guidance); ignored without guidance."""
        if seconds <= 0:
            raise ConfigError(f"--seconds must be positive, got {seconds}")
        if round(seconds * self.rate) < MIN_FRAMES:
            raise ConfigError(
                f"--seconds {seconds} is {round(seconds * self.rate)} frames at {self.rate:g} Hz; the "
                f"physics metrics need {MIN_FRAMES} (velocities and accelerations by differences): "
                f"ask for at least {MIN_FRAMES / self.rate:.2f} s"
            )
        if samples < 1:
            raise ConfigError(f"--samples must be at least 1, got {samples}")
        if control is not None:
            control.check(seconds)
            control.check_muscles(self.surrogate.names if guidance and self.surrogate is not None else None)
        speed = None
        if action.speed is not None:  # the request's speed at the canonical size (biomotion.data.placement)
            height = profile.height if profile is not None and personalised and profile.height else GENERIC_HEIGHT
            speed = action.speed * GENERIC_HEIGHT / height
        config = guidance_config or GuidanceConfig()
        tempo_range = config.tempo if guidance and speed is not None else None
        n_plain = max(1, math.ceil(seconds * self.rate / DOWNSAMPLE))
        n_tokens = (
            n_plain if tempo_range is None else max(1, math.ceil(seconds * self.rate * tempo_range[1] / DOWNSAMPLE))
        )  # a faster tempo plays more
        cond, prefix, offset = self.condition(
            action, profile, references, personalised, reference_actions, reference_speeds, biodata
        )
        batch = Condition(
            *(
                x.expand(samples, *x.shape[1:])
                for x in (cond.latents, cond.latent_valid, cond.biodata, cond.metadata, cond.action)
            )
        )
        generator = torch.Generator().manual_seed(seed)
        if prefix is not None and prime:
            prefix = prefix.expand(samples, -1)
        else:
            prefix = None
        codes = self.bundle.prior.sample(
            batch, n_tokens, temperature=temperature, top_k=top_k, generator=generator, prefix=prefix
        )
        z0 = self.tokenizer.quantiser.codebook[codes]
        bundle = self.bundle
        frames = round(seconds * self.rate)
        shift, played_shift, target, offset = None, None, None, offset if posture else None
        amplitude = None
        if guidance and posture and personalised and config.w_amplitude > 0:
            amplitude = self.person_amplitude(action, profile, references, reference_actions, reference_speeds)
        z_plain = z0[:, :n_plain]  # the sample as the prior drew it for this length (what --no-guidance returns)
        tempo, played = None, None
        if tempo_range is not None:
            with torch.no_grad():
                decoded = self.tokenizer.decode_latents(z0)
            tempo = warp_factor(decoded, self.rate, torch.full((samples,), speed), tempo_range)
            played = warp(decoded, tempo, frames)
        if offset is not None:
            target = bundle.posture(action.action, action.speed) + offset
            with torch.no_grad():
                shift = centring_shift(self.tokenizer.decode_latents(z_plain)[:, :frames], target)
            played_shift = shift if played is None else centring_shift(played, target)

        def make_guide(posture_shift: torch.Tensor | None, factor: torch.Tensor | None) -> Guide:
            return Guide(
                self.tokenizer,
                self.body,
                bundle.bounds_for(action.action),
                bundle.high(action.action),
                bundle.high(action.action, "jerk_high"),
                self.surrogate,
                config,
                posture_shift,
                target,
                factor,
                frames,
                amplitude,
                bundle.energy(action.action, action.speed) if config.w_com_energy > 0 else None,
                control,
            )

        # coupled coordinates (the patella's knee _beta) set from their independent ones, as OpenSim's coupler
        # constraints set them, in every variant returned (foot planting sets them in q; the files' writer sets
        # them again): the decoder learnt _beta from sources that lack it or leave it free, near 0 at any knee angle
        coupled = partial(apply_couplers, self.body)
        with torch.no_grad():  # the sample before guidance, at its own tempo
            unguided = coupled(make_guide(shift, None).kinematics(z_plain).q[:, :frames])
        if not guidance:
            return Generated(unguided, unguided, codes, self.rate, action, posture=offset)
        result = make_guide(played_shift, tempo)(z0, speed)
        return Generated(
            result.q[:, :frames],
            unguided,
            codes,
            self.rate,
            action,
            result.history,
            coupled(result.unplanted[:, :frames]),
            offset,
            tempo,
        )
