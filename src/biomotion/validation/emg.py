"""EMG check: measured EMG on/off timing against predicted muscle activations, Rajagopal walk (subject 11).

`emg_check` returns the figure of the EMG bar ``emg_onoff_agreement`` (share of frames where EMG and predicted
activation agree on "on" or "off", pooled over the 10 recorded muscles; bar 0.80), per muscle, for two
predictions of the same trial:

- **static optimization** (primary, ``emg_source``): OpenSim's ScaleTool with the pipeline's two walk scale setups
  (``Scale/scale_setup_walk_scaleOnly.xml`` then ``Scale/scale_setup_walk.xml``, with ``generic_unscaled.osim`` =
  Rajagopal2016.osim, as `biomotion.validation.ik.rajagopal_case` does), `biomotion.ik.markers.solve_ik` of
  ``ExpData/motion_capture_walk.trc`` with ``IK/ik_setup_walk.xml``'s weights and time range, inverse dynamics
  with the measured ground reaction (`biomotion.analysis.chain.analyze`; ``ExpData/grf_walk.mot`` applied to
  ``calcn_r``/``calcn_l`` as ``ID/grf_walk.xml`` says; coordinates 6 Hz zero-lag low-pass and quintic-spline
  derivatives, as OpenSim's inverse-dynamics tool), then the surrogate labels' static optimization
  (`biomotion.analysis.activation_labels.Labeler`: squared activations, 10 balanced coordinates, reserves, shipped
  Rajagopal 2016 path functions, the model's Millard 2012 curves) on those torques;
- **surrogate** (secondary, keys ``*_surrogate``): `biomotion.muscles.surrogate.MuscleSurrogate` from
  ``checkpoints/surrogate.safetensors`` on the same IK coordinates, resampled to its 30 Hz and placed like its
  training clips (`biomotion.data.placement.place_clip`, subject height from the scale setup), interpolated back
  to the motion frames.

The muscle paths and parameters are those of the *generic* model (no path functions exist for the scaled one),
while the torques come from the scaled model (85.07 kg): moment arms and forces of a 1.70 m body balance the torques
of a 1.83 m one, so activations are somewhat high; on/off timing relative to each signal's own range is what is
compared, which a uniform scale does not change. Both right-foot stances of the trial are on plates (1 and 3),
the left foot only once (plate 2, 0.85-1.57 s), so left-side torques are incomplete elsewhere; no muscle spans both
legs, so the per-frame optimization separates by side and the right-side activations compared here do not depend
on them.

EMG processing (``ExpData/emg_walk_raw.anc``: Motion Analysis "Analog R/C ASCII", 28 channels at 2000 Hz, the
last 10 EMG in raw ADC counts), following the SENIAM / ISEK recommendations (Merletti 1999, "Standards for
reporting EMG data", J Electromyogr Kinesiol 9(1):III-IV; De Luca et al. 2010, J Biomech 43:1573, band edges
20 and 450 Hz against movement artefact and noise):

1. mean removed; band-pass 20-450 Hz, Butterworth designed as a 4th-order band-pass (2nd order per edge), run
   forward and backward (zero lag; ``scipy.signal.sosfiltfilt``);
2. full-wave rectified;
3. low-pass 6 Hz, 2nd-order Butterworth run forward and backward (a 4th-order zero-lag filter in Winter's sense:
   Winter 2009, "Biomechanics and Motor Control of Human Movement", 4th ed., sec. 3.4), ends padded by even
   reflection over 1 s; negative undershoot clipped to 0. 6 Hz is the cut-off the activations' kinematics were
   filtered at (the common linear-envelope range is 4-10 Hz);
4. sampled at the motion frames (linear interpolation) and normalised per muscle to its peak over the compared
   frames.

On/off rule, fixed before any agreement was computed and applied identically to every EMG envelope and every
predicted activation (multi-muscle channels: the mean of the mapped muscles' activations): a signal is **on** at a
frame where it is at or above ``min + 0.20 (max - min)`` of its own values over the compared frames (a fixed
fraction of its range, i.e. 20 % of peak after removing the trial minimum, which discards the EMG noise floor and
the activations' lower bound of 0.01). A baseline rule (Hodges & Bui 1996, Electroencephalogr Clin Neurophysiol
101:511: mean + k SD of a resting period) needs a period without activity, which continuous walking does not have.
No minimum burst duration is imposed.
`EMGSettings.threshold` holds the fraction; the result also lists the pooled agreement at other fractions
(``emg_threshold_sensitivity``) to show how much the figure depends on that choice, not to pick one.

Channel to model-muscle map (all right side: the pipeline's own comparison, ``scripts/validationPlots_emg_walk.m``
in opensim-org/opensim-models, plots eight of these channels, all but MH and VM, against ``*_r`` activations and
right-foot strikes; the soleus and gastrocnemius envelopes here peak in right stance):
SOL soleus_r; GAS mean(gasmed_r, gaslat_r) (the channel does not name the head; the upstream script plots gaslat_r);
TA tibant_r; MH (medial hamstrings) mean(semimem_r, semiten_r); BF bflh_r (the surface-accessible long head); VL
vaslat_r; VM vasmed_r; RF recfem_r; GMAX mean(glmax1-3_r); GMED mean(glmed1-3_r) (as the upstream script averages
the three gluteal bundles).

Time alignment: the .anc, ``grf_walk.mot`` and ``motion_capture_walk.trc`` are the same trial
(subject11_noload_free_trial03) and all start at t = 0 s (opensim-models/SOURCE.md); the .anc holds the force-plate
channels too, and their vertical sum is cross-correlated with the ``grf_walk.mot`` vertical force to verify the
clocks (``emg_alignment``: measured lag 0 samples, r = 0.999). No electromechanical delay is applied: the EMG and
the activation are compared at the same instant (``emg_lead_s`` in the detail reports, per muscle, by how much the
envelope leads the activation; it is not used for the figure).

Measured (``biomotion validate muscles``, ``emg_onoff_agreement`` and ``emg_onoff_agreement_surrogate``; 238
frames, 0-2.37 s): pooled agreement 0.766 with static optimization and 0.748 with the shipped surrogate
(`MuscleSurrogate.predict_symmetric`), both below the 0.80 bar; OpenSim's own static optimization scores 0.780 under
the same rule (docs/decisions/emg-bar.md); see ``tests/validation/test_emg.py``.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biomotion.errors import DataFormatError
from biomotion.io.xml import parse_tree
from biomotion.validation.ik import RAJAGOPAL_SCALE_STEPS, scale_rajagopal_walk

RAJAGOPAL = "opensim-models/Pipelines/Rajagopal"
EMG_FILE = f"{RAJAGOPAL}/ExpData/emg_walk_raw.anc"
MARKER_FILE = f"{RAJAGOPAL}/ExpData/motion_capture_walk.trc"
GRF_FILE = f"{RAJAGOPAL}/ExpData/grf_walk.mot"
GRF_LOADS = f"{RAJAGOPAL}/ID/grf_walk.xml"
IK_SETUP = f"{RAJAGOPAL}/IK/ik_setup_walk.xml"
GENERIC_MODEL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
SURROGATE = Path(__file__).resolve().parents[3] / "checkpoints" / "surrogate.safetensors"
BAR = 0.80

#: EMG channel of ``emg_walk_raw.anc`` -> the model muscles whose (mean) activation it is compared with.
EMG_MUSCLES: dict[str, tuple[str, ...]] = {
    "SOL": ("soleus_r",),
    "GAS": ("gasmed_r", "gaslat_r"),
    "TA": ("tibant_r",),
    "MH": ("semimem_r", "semiten_r"),
    "BF": ("bflh_r",),
    "VL": ("vaslat_r",),
    "VM": ("vasmed_r",),
    "RF": ("recfem_r",),
    "GMAX": ("glmax1_r", "glmax2_r", "glmax3_r"),
    "GMED": ("glmed1_r", "glmed2_r", "glmed3_r"),
}


# --- the .anc reader ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AnalogRecording:
    """An analog recording (.anc). ``counts`` [N, C] are the raw ADC values as written; ``ranges`` the per-channel
    ``Range`` row (Motion Analysis writes the full-scale input range there, in mV for +- full scale; not needed
    here, since every EMG envelope is normalised to its own peak)."""

    path: Path
    times: np.ndarray  # [N] s
    names: tuple[str, ...]  # [C]
    counts: np.ndarray  # [N, C]
    rate: float  # Hz
    ranges: np.ndarray  # [C]
    bit_depth: int
    duration: float  # s, as the header states
    header: dict[str, str]

    @property
    def n_samples(self) -> int:
        return int(self.counts.shape[0])

    @property
    def n_channels(self) -> int:
        return len(self.names)

    def channel(self, name: str) -> np.ndarray:
        """[N] the channel's values; a `DataFormatError` naming the channels there are when it is absent."""
        if name not in self.names:
            raise DataFormatError(self.path, f"no channel {name!r}; channels: {', '.join(self.names)}", field=name)
        return self.counts[:, self.names.index(name)]


def _numbers(path: Path, line_number: int, fields: Sequence[str], what: str) -> np.ndarray:
    try:
        values = np.array([float(f) for f in fields])
    except ValueError:
        bad = next(f for f in fields if not _is_number(f))
        raise DataFormatError(path, f"{what}: {bad!r} is not a number", line=line_number) from None
    if not np.all(np.isfinite(values)):
        raise DataFormatError(path, f"{what}: non-finite value", line=line_number)
    return values


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _fields(line: str) -> list[str]:
    """Tab-separated fields with surrounding blanks removed; trailing empty fields (a trailing tab) dropped."""
    fields = [f.strip() for f in line.split("\t")]
    while fields and fields[-1] == "":
        fields.pop()
    return fields


def read_anc(path: str | Path) -> AnalogRecording:
    """Read a Motion Analysis "Analog R/C ASCII" file (.anc), strictly.

    Layout (as ``emg_walk_raw.anc`` has it): ``key:<TAB>value`` header lines (``File_Type``, ``#Channels``,
    ``PreciseRate``, ``Duration(Sec.)``, ``BitDepth`` required), blank lines, then the rows ``Name``, ``Rate`` and
    ``Range`` (one field per channel) and one data row per sample: time, then one value per channel. Every channel
    must be sampled at ``PreciseRate``; times must start the clock at a uniform 1/rate step, and the sample count
    must match ``Duration(Sec.)``. Any departure is a `DataFormatError` naming the file and line.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="latin-1").splitlines()
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror or error}") from None
    if not lines:
        raise DataFormatError(path, "empty file")
    header: dict[str, str] = {}
    name_row = None
    for index, line in enumerate(lines):
        fields = _fields(line)
        if not fields:
            continue
        if fields[0] == "Name":
            name_row = index
            break
        if len(fields) % 2:
            raise DataFormatError(path, f"header line is not 'key:<TAB>value' pairs: {line.strip()!r}", line=index + 1)
        for key, value in zip(fields[0::2], fields[1::2]):
            if not key.endswith(":"):
                raise DataFormatError(path, f"header key {key!r} does not end with ':'", line=index + 1)
            header[key[:-1]] = value
    if not header.get("File_Type", "").startswith("Analog R/C ASCII"):
        raise DataFormatError(
            path, f"not an 'Analog R/C ASCII' file (File_Type {header.get('File_Type')!r})", line=1, field="File_Type"
        )
    if name_row is None:
        raise DataFormatError(path, "no 'Name' row (channel names) after the header", line=len(lines))
    for key in ("#Channels", "PreciseRate", "Duration(Sec.)", "BitDepth"):
        if key not in header:
            raise DataFormatError(path, f"header lacks {key!r}", line=name_row, field=key)
    numbers = _numbers(
        path,
        name_row,
        [header["#Channels"], header["PreciseRate"], header["Duration(Sec.)"], header["BitDepth"]],
        "header",
    )
    n_channels, rate, duration, bit_depth = int(numbers[0]), float(numbers[1]), float(numbers[2]), int(numbers[3])
    if n_channels != numbers[0] or n_channels < 1 or rate <= 0 or duration < 0 or bit_depth < 1:
        raise DataFormatError(
            path,
            f"header values out of range: #Channels {header['#Channels']}, PreciseRate "
            f"{header['PreciseRate']}, Duration {header['Duration(Sec.)']}, BitDepth "
            f"{header['BitDepth']}",
            line=name_row,
        )

    rows = {}
    for offset, label in enumerate(("Name", "Rate", "Range")):
        index = name_row + offset
        fields = _fields(lines[index]) if index < len(lines) else []
        if not fields or fields[0] != label:
            raise DataFormatError(path, f"expected the {label!r} row here", line=index + 1)
        if len(fields) - 1 != n_channels:
            raise DataFormatError(
                path,
                f"{label!r} row has {len(fields) - 1} fields for {n_channels} channels (#Channels)",
                line=index + 1,
            )
        rows[label] = (index + 1, fields[1:])
    names = tuple(rows["Name"][1])
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise DataFormatError(path, f"duplicate channel names {duplicates}", line=rows["Name"][0])
    rates = _numbers(path, rows["Rate"][0], rows["Rate"][1], "Rate row")
    mismatched = [n for n, r in zip(names, rates) if abs(r - rate) > 1e-6 * rate]
    if mismatched:
        raise DataFormatError(
            path,
            f"channels {mismatched} are not sampled at PreciseRate {rate:g} Hz (mixed rates are not supported)",
            line=rows["Rate"][0],
        )
    ranges = _numbers(path, rows["Range"][0], rows["Range"][1], "Range row")
    if np.any(ranges <= 0):
        raise DataFormatError(path, "Range row has non-positive values", line=rows["Range"][0])

    first = name_row + 3
    body = lines[first:]
    while body and not body[-1].strip():
        body.pop()
    data = np.empty((len(body), n_channels + 1))
    for k, line in enumerate(body):
        fields = _fields(line)
        if len(fields) != n_channels + 1:
            raise DataFormatError(
                path, f"data row has {len(fields)} fields, expected time + {n_channels} channels", line=first + k + 1
            )
        data[k] = _numbers(path, first + k + 1, fields, "data row")
    if len(data) < 2:
        raise DataFormatError(path, f"{len(data)} data rows: need at least 2", line=first + 1)
    times = data[:, 0]
    step = np.diff(times)
    tolerance = 1e-6 + 1e-3 / rate
    bad = np.flatnonzero(np.abs(step - 1.0 / rate) > tolerance)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataFormatError(
            path, f"time {times[k]:g} s does not follow {times[k - 1]:g} s by 1/{rate:g} s", line=first + k + 1
        )
    expected = round(duration * rate) + 1
    if len(data) != expected or abs(times[-1] - times[0] - duration) > 0.5 / rate:
        raise DataFormatError(
            path,
            f"{len(data)} samples spanning {times[-1] - times[0]:g} s, but the header "
            f"says Duration {duration:g} s at {rate:g} Hz ({expected} samples)",
            line=first + len(data),
        )
    return AnalogRecording(path, times, names, data[:, 1:], rate, ranges, bit_depth, duration, header)


# --- envelopes and on/off -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EMGSettings:
    """EMG processing and on/off rule (see the module docstring)."""

    band_hz: tuple[float, float] = (20.0, 450.0)
    band_order: int = 2  # per edge: a 4th-order band-pass, run forward and backward
    envelope_hz: float = 6.0
    envelope_order: int = 2  # run forward and backward: 4th-order zero-lag
    threshold: float = 0.20  # on: >= min + threshold (max - min) over the compared frames


def emg_envelope(raw: np.ndarray, rate: float, settings: EMGSettings = EMGSettings()) -> np.ndarray:
    """Linear envelope [N] (or [N, C]) of raw EMG sampled at ``rate`` Hz: mean removed, zero-lag band-pass,
    full-wave rectification, zero-lag low-pass, undershoot clipped at 0 (same units as ``raw``)."""
    import scipy.signal

    x = np.asarray(raw, dtype=float)
    low, high = settings.band_hz
    if not 0 < low < high < rate / 2:
        raise ValueError(f"band {low}-{high} Hz must lie in (0, {rate / 2}) Hz for EMG sampled at {rate} Hz")
    if not 0 < settings.envelope_hz < rate / 2:
        raise ValueError(f"envelope cut-off {settings.envelope_hz} Hz must lie in (0, {rate / 2}) Hz")
    band = scipy.signal.butter(settings.band_order, [low, high], btype="bandpass", fs=rate, output="sos")
    x = scipy.signal.sosfiltfilt(band, x - x.mean(axis=0), axis=0)
    lowpass = scipy.signal.butter(settings.envelope_order, settings.envelope_hz, btype="low", fs=rate, output="sos")
    pad = min(round(rate), x.shape[0] - 1)
    envelope = scipy.signal.sosfiltfilt(lowpass, np.abs(x), axis=0, padtype="even", padlen=pad)
    return np.clip(envelope, 0.0, None)


def on_off(signal: np.ndarray, fraction: float) -> np.ndarray:
    """[T] bool (or [T, K], per column): on where the signal is at or above ``min + fraction (max - min)`` of its
    own values. A constant signal is off throughout."""
    x = np.asarray(signal, dtype=float)
    low, high = x.min(axis=0), x.max(axis=0)
    span = high - low
    return (x >= low + fraction * span) & (span > 0)


def agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Share of frames where two on/off sequences agree."""
    return float(np.mean(np.asarray(a, dtype=bool) == np.asarray(b, dtype=bool)))


def chance_agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Agreement expected from the two on-shares alone (independent timing): p q + (1 - p)(1 - q)."""
    p, q = float(np.mean(a)), float(np.mean(b))
    return p * q + (1 - p) * (1 - q)


def channel_activations(
    activations: np.ndarray, muscle_names: Sequence[str], mapping: Mapping[str, Sequence[str]] = EMG_MUSCLES
) -> dict[str, np.ndarray]:
    """Per EMG channel the mean activation [T] of its model muscles (see `EMG_MUSCLES`)."""
    names = list(muscle_names)
    missing = sorted({m for muscles in mapping.values() for m in muscles if m not in names})
    if missing:
        raise DataFormatError(None, f"predicted activations lack muscles {missing}", field="muscles")
    return {
        channel: activations[:, [names.index(m) for m in muscles]].mean(axis=1) for channel, muscles in mapping.items()
    }


def emg_lead(envelope: np.ndarray, activation: np.ndarray, rate: float, max_lag_s: float = 0.2) -> float:
    """Time (s) by which the EMG envelope leads the activation: the shift of the activation, within
    +-``max_lag_s``, that maximises their correlation (positive: EMG earlier). A description of the
    electromechanical delay the static optimization does not model; it is not applied to the agreement."""
    best, best_r, reach = 0, -np.inf, round(max_lag_s * rate)
    for lag in range(-reach, reach + 1):
        a, b = (envelope[: len(envelope) - lag], activation[lag:]) if lag >= 0 else (envelope[-lag:], activation[:lag])
        if np.std(a) > 0 and np.std(b) > 0:
            r = float(np.corrcoef(a, b)[0, 1])
            if r > best_r:
                best, best_r = lag, r
    return best / rate


def compare_on_off(
    envelopes: Mapping[str, np.ndarray], predicted: Mapping[str, np.ndarray], fraction: float, rate: float | None = None
) -> dict:
    """Per channel and pooled on/off agreement of EMG ``envelopes`` and ``predicted`` activations (same frames,
    sampled at ``rate`` Hz: given, the detail also holds `emg_lead`)."""
    per, detail = {}, {}
    total, chance_total, count = 0.0, 0.0, 0
    for channel, envelope in envelopes.items():
        emg_on, predicted_on = on_off(envelope, fraction), on_off(predicted[channel], fraction)
        share = agreement(emg_on, predicted_on)
        chance = chance_agreement(emg_on, predicted_on)
        per[channel] = round(share, 4)
        r = np.corrcoef(envelope, predicted[channel])[0, 1] if np.std(predicted[channel]) > 0 else float("nan")
        detail[channel] = {
            "agreement": round(share, 4),
            "emg_on_share": round(float(emg_on.mean()), 4),
            "predicted_on_share": round(float(predicted_on.mean()), 4),
            "chance_agreement": round(chance, 4),
            "envelope_r": round(float(r), 4),
        }
        if rate:
            detail[channel]["emg_lead_s"] = round(emg_lead(envelope, predicted[channel], rate), 3)
        total += share * len(emg_on)
        chance_total += chance * len(emg_on)
        count += len(emg_on)
    return {"pooled": total / count, "per_muscle": per, "chance": chance_total / count, "detail": detail}


# --- the predicted activations ---------------------------------------------------------------------------------------


def external_load_bodies(path: Path, channels: Sequence[str]) -> tuple[str, ...]:
    """The body each GRF channel (``ground_force_r`` ...) is applied to, from an OpenSim ExternalLoads XML whose
    forces are expressed in ground; a `DataFormatError` when a channel has no ExternalForce."""
    root = parse_tree(path).getroot()
    bodies = {}
    for force in root.iter("ExternalForce"):
        identifier = (force.findtext("force_identifier") or "").strip()
        expressed = (force.findtext("force_expressed_in_body") or "ground").strip()
        if expressed != "ground":
            raise DataFormatError(
                path,
                f"ExternalForce {force.get('name')!r} is expressed in {expressed!r}; only ground is supported",
                field="force_expressed_in_body",
            )
        bodies[identifier.removesuffix("_v")] = (force.findtext("applied_to_body") or "").strip()
    missing = [c for c in channels if not bodies.get(c)]
    if missing:
        raise DataFormatError(
            path, f"no ExternalForce (with a body) for GRF channels {missing}", field="force_identifier"
        )
    return tuple(bodies[c] for c in channels)


@dataclass(frozen=True)
class Predictions:
    """Activations of the 80 Rajagopal muscles on the IK frames."""

    times: np.ndarray  # [T] s, the IK (marker) frames
    muscle_names: tuple[str, ...]
    static_optimization: np.ndarray  # [T, M]
    surrogate: np.ndarray | None  # [T, M] or None when the checkpoint is absent
    info: dict


def predict_walk_activations(data_root: Path, surrogate: Path | None = SURROGATE) -> Predictions:
    """Scale, IK, inverse dynamics with measured GRF and static optimization of the Rajagopal walk, plus the
    surrogate's activations on the same coordinates (see the module docstring). Needs ``opensim`` (ScaleTool)."""
    import torch

    from biomotion.analysis.activation_labels import Labeler
    from biomotion.analysis.chain import analyze, model_motion, unwrapped
    from biomotion.body.model import BodyModel
    from biomotion.ik.markers import solve_ik
    from biomotion.io.mot import read_ground_reaction
    from biomotion.io.setup import read_ik_setup
    from biomotion.io.trc import read_trc

    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = round(now - clock, 3)
        clock = now

    with tempfile.TemporaryDirectory(prefix="biomotion-emg-") as folder:
        model = BodyModel.from_osim(scale_rajagopal_walk(data_root, Path(folder)))
    lap("scale_opensim")
    setup = read_ik_setup(data_root / IK_SETUP)
    ik = solve_ik(
        model,
        read_trc(data_root / MARKER_FILE),
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
    )
    lap("ik")
    forces = read_ground_reaction(data_root / GRF_FILE)
    forces = forces.assign(external_load_bodies(data_root / GRF_LOADS, forces.names))
    labeler = Labeler.from_data_root(data_root)
    result = analyze(ik.motion, model, forces, cutoff_hz=labeler.settings.cutoff_hz)
    coordinates = unwrapped(model_motion(ik.motion, model), model)
    _, qd, _ = coordinates.smoothed(labeler.settings.cutoff_hz)  # analyze's own preparation, for qdot
    lap("inverse_dynamics")
    order = [list(model.coordinate_names).index(n) for n in labeler.paths.coordinate_names]
    q = torch.tensor(result.motion.values[:, order], dtype=torch.float64)
    qd = torch.tensor(np.ascontiguousarray(qd[:, order]), dtype=torch.float64)
    torques = torch.tensor(result.torques[:, order], dtype=torch.float64)[:, labeler.paths.select(labeler.coordinates)]
    so = labeler.solve(q, qd, torques)
    lap("static_optimization")
    right = [j for j, n in enumerate(labeler.coordinates) if n.endswith("_r")]
    reserve = so.reserve_torques.numpy()[:, right]
    info = {
        "model": "OpenSim ScaleTool: Scale/scale_setup_walk_scaleOnly.xml then Scale/scale_setup_walk.xml "
        f"(mass {float(model.total_mass):.2f} kg)",
        "ik_frames": int(ik.motion.n_frames),
        "ik_marker_rmse_m": round(ik.rmse, 5),
        "ground_reaction": f"measured ({GRF_FILE}, bodies from {GRF_LOADS})",
        "muscle_paths": "shipped Rajagopal 2016 path functions (generic model)",
        "muscle_curves": labeler.curves,
        "balanced_coordinates": list(labeler.coordinates),
        "so_converged_share": round(float(so.converged.double().mean()), 4),
        "so_reserve_rms_right_nm": round(float(np.sqrt(np.mean(reserve**2))), 3),
        "so_reserve_max_right_nm": round(float(np.abs(reserve).max()), 3),
    }
    predicted_surrogate = None
    if surrogate is not None and Path(surrogate).exists():
        predicted_surrogate = _surrogate_activations(Path(surrogate), ik.motion, labeler, data_root)
        info["surrogate"] = f"checkpoints/{surrogate.name}"
        lap("surrogate")
    info["seconds"] = seconds
    return Predictions(ik.motion.times, labeler.muscle_names, so.activations.numpy(), predicted_surrogate, info)


def _surrogate_activations(checkpoint: Path, motion, labeler, data_root: Path) -> np.ndarray:
    """The surrogate's activations [T, M] (``labeler.muscle_names`` order) on ``motion``'s frames."""
    import torch

    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.data.placement import place_clip
    from biomotion.errors import ModelError
    from biomotion.io.setup import read_scale_setup
    from biomotion.muscles.surrogate import MuscleSurrogate

    network = MuscleSurrogate.load(checkpoint, body=labeler.model)
    if set(network.names) != set(labeler.muscle_names):
        raise ModelError(f"{checkpoint}: the surrogate's muscles are not the Rajagopal model's")
    height = read_scale_setup(data_root / RAJAGOPAL / "Scale" / RAJAGOPAL_SCALE_STEPS[-1]).height / 1000.0
    clip = motion.select(CANONICAL_COORDINATES).resample(network.config.rate)
    clip = place_clip(clip, labeler.model, height=height if height > 0 else None, treadmill_speed=None)
    with torch.no_grad():
        out = (
            network.predict_symmetric(
                torch.as_tensor(clip.values, dtype=network.mean.dtype)[None], torch.as_tensor(clip.mask)[None]
            )[0][0]
            .double()
            .numpy()
        )
    columns = [network.names.index(n) for n in labeler.muscle_names]
    return np.stack([np.interp(motion.times, clip.times, out[:, c]) for c in columns], axis=1)


# --- the check -------------------------------------------------------------------------------------------------------


def emg_envelopes(
    recording: AnalogRecording,
    times: np.ndarray,
    settings: EMGSettings = EMGSettings(),
    channels: Sequence[str] = tuple(EMG_MUSCLES),
) -> dict[str, np.ndarray]:
    """Per channel the envelope at ``times`` (inside the recording), normalised to its peak there."""
    if times[0] < recording.times[0] - 1e-9 or times[-1] > recording.times[-1] + 1e-9:
        raise DataFormatError(
            recording.path,
            f"frames {times[0]:g}-{times[-1]:g} s fall outside the recording "
            f"({recording.times[0]:g}-{recording.times[-1]:g} s)",
            field="time",
        )
    raw = np.stack([recording.channel(c) for c in channels], axis=1)
    envelope = emg_envelope(raw, recording.rate, settings)
    out = {}
    for k, channel in enumerate(channels):
        sampled = np.interp(times, recording.times, envelope[:, k])
        peak = sampled.max()
        out[channel] = sampled / peak if peak > 0 else sampled
    return out


def plate_alignment(recording: AnalogRecording, grf_path: Path, max_lag_s: float = 0.1) -> dict:
    """Lag (s) maximising the correlation between the .anc force-plate vertical channels (``F<n>Z``, summed) and
    the GRF file's total vertical force, and that correlation: 0 lag means the two share a clock."""
    from biomotion.io.mot import read_ground_reaction

    plates = [n for n in recording.names if len(n) == 3 and n[0] == "F" and n[1].isdigit() and n[2] == "Z"]
    if not plates:
        return {"checked": False, "reason": "no F<n>Z plate channel in the .anc"}
    grf = read_ground_reaction(grf_path)
    vertical = np.interp(recording.times, grf.times, grf.force[:, :, 1].sum(axis=1), left=np.nan, right=np.nan)
    x = sum(recording.channel(n) for n in plates)
    lags = range(-int(max_lag_s * recording.rate), int(max_lag_s * recording.rate) + 1)

    def correlation(lag: int) -> float:
        a, b = (x[lag:], vertical[: len(vertical) - lag]) if lag >= 0 else (x[:lag], vertical[-lag:])
        keep = np.isfinite(b)
        return float(np.corrcoef(a[keep], b[keep])[0, 1])

    values = {lag: correlation(lag) for lag in lags}
    best = max(values, key=lambda lag: abs(values[lag]))
    return {
        "checked": True,
        "plate_channels": plates,
        "lag_s": best / recording.rate,
        "r_at_lag": round(values[best], 5),
        "r_at_zero": round(values[0], 5),
    }


def emg_check(
    data_root: Path,
    *,
    settings: EMGSettings = EMGSettings(),
    surrogate: Path | None = SURROGATE,
    sensitivity: Sequence[float] = (0.10, 0.15, 0.25, 0.30),
) -> dict:
    """The EMG on/off check of the Rajagopal walk (module docstring). Returns ``emg_onoff_agreement`` (pooled,
    static optimization), ``emg_per_muscle``, ``emg_source``, ``emg_onoff_agreement_surrogate`` and
    ``emg_per_muscle_surrogate``, with details; when a needed file (or OpenSim) is absent, only ``skipped``
    (a list of reasons) and no figure."""
    data_root = Path(data_root)
    started = time.perf_counter()
    needed = [
        EMG_FILE,
        MARKER_FILE,
        GRF_FILE,
        GRF_LOADS,
        IK_SETUP,
        GENERIC_MODEL,
        *(f"{RAJAGOPAL}/Scale/{s}" for s in RAJAGOPAL_SCALE_STEPS),
    ]
    absent = [n for n in needed if not (data_root / n).exists()]
    if absent:
        return {"skipped": [f"EMG check: {', '.join(absent)} not under {data_root}"]}
    try:
        from biomotion.settings import opensim_oracle

        opensim_oracle()  # ScaleTool makes the subject model: fail early without opensim
    except ImportError:
        return {"skipped": ["EMG check: opensim is not installed (its ScaleTool makes the subject model)"]}

    recording = read_anc(data_root / EMG_FILE)
    predictions = predict_walk_activations(data_root, surrogate)
    times = predictions.times
    inside = (times >= recording.times[0] - 1e-9) & (times <= recording.times[-1] + 1e-9)
    times = times[inside]
    envelopes = emg_envelopes(recording, times, settings)
    sources = {"static_optimization": predictions.static_optimization[inside]}
    if predictions.surrogate is not None:
        sources["surrogate"] = predictions.surrogate[inside]
    rate = (len(times) - 1) / (times[-1] - times[0])
    comparisons = {
        name: compare_on_off(envelopes, channel_activations(a, predictions.muscle_names), settings.threshold, rate)
        for name, a in sources.items()
    }
    so = comparisons["static_optimization"]
    out: dict = {
        "emg_onoff_agreement": round(so["pooled"], 4),
        "emg_per_muscle": so["per_muscle"],
        "emg_source": "static optimization (squared activations, reserves) of inverse dynamics with measured GRF "
        "after IK of motion_capture_walk.trc on the OpenSim-scaled Rajagopal 2016 model",
        "emg_bar": BAR,
        "emg_passes": bool(so["pooled"] >= BAR),
        "emg_chance_agreement": round(so["chance"], 4),
        "skipped": [],
    }
    if "surrogate" in comparisons:
        sur = comparisons["surrogate"]
        out.update(
            emg_onoff_agreement_surrogate=round(sur["pooled"], 4),
            emg_per_muscle_surrogate=sur["per_muscle"],
            emg_chance_agreement_surrogate=round(sur["chance"], 4),
            emg_source_surrogate=f"MuscleSurrogate checkpoints/{surrogate.name} on the same IK coordinates (30 Hz)",
        )
    else:
        out["skipped"].append(f"surrogate variant: checkpoint {surrogate} absent")
    out["emg_detail"] = {name: c["detail"] for name, c in comparisons.items()}
    out["emg_threshold_sensitivity"] = {
        name: {
            f"{f:.2f}": round(
                compare_on_off(envelopes, channel_activations(a, predictions.muscle_names), f)["pooled"], 4
            )
            for f in sorted({*sensitivity, settings.threshold})
        }
        for name, a in sources.items()
    }
    out["emg_muscle_map"] = {c: list(m) for c, m in EMG_MUSCLES.items()}
    out["emg_frames"] = len(times)
    out["emg_window_s"] = [round(float(times[0]), 4), round(float(times[-1]), 4)]
    out["emg_recording"] = {
        "file": EMG_FILE,
        "channels": recording.n_channels,
        "rate_hz": recording.rate,
        "samples": recording.n_samples,
        "duration_s": recording.duration,
    }
    out["emg_alignment"] = plate_alignment(recording, data_root / GRF_FILE)
    out["emg_method"] = {
        "band_hz": list(settings.band_hz),
        "band_order_per_edge": settings.band_order,
        "envelope_hz": settings.envelope_hz,
        "envelope_order_per_pass": settings.envelope_order,
        "zero_lag": True,
        "normalisation": "per muscle, peak over the compared frames",
        "on_rule": f"value >= min + {settings.threshold:g} (max - min) over the compared frames, "
        "same rule for EMG and predicted activation",
        "electromechanical_delay_s": 0.0,
    }
    out["emg_predictions"] = predictions.info
    out["emg_seconds"] = round(time.perf_counter() - started, 2)
    return out
