"""EMG check (`biomotion.validation.emg`): the strict .anc reader, envelopes, the on/off rule, and the on/off
agreement of the Rajagopal walk's EMG with static optimization and the surrogate."""

import numpy as np
import pytest

from biomotion.errors import DataFormatError
from biomotion.validation import emg
from tests.conftest import data_path

# Measured with the a-priori settings (EMGSettings(): 20-450 Hz band-pass, 6 Hz envelope, on at 20 % of range):
# pooled share of (muscle, frame) pairs whose on/off agrees, 10 muscles x 238 frames. The issue bar is 0.80; it is
# NOT reached (static optimization 0.766 with the model's Millard 2012 curves, the shipped surrogate 0.748). The
# tolerance covers float and solver differences between machines (0.02 = 48 of the 2380 muscle-frames), not a change
# of method.
MEASURED_SO = 0.7664
MEASURED_SURROGATE = 0.7479  # the surrogate of 2026-12-07 (window cuts trimmed); before it 0.7681, 0.7845, 0.7588
MEASURED_SO_PER_MUSCLE = {
    "SOL": 0.8403,
    "GAS": 0.8361,
    "TA": 0.9538,
    "MH": 0.9496,
    "BF": 0.7899,
    "VL": 0.6387,
    "VM": 0.7437,
    "RF": 0.5924,
    "GMAX": 0.7605,
    "GMED": 0.5588,
}
TOLERANCE = 0.02


def _anc_text(samples=5, rate=1000.0, channels=("F1Z", "SOL", "TA"), duration=None, rates=None) -> str:
    duration = (samples - 1) / rate if duration is None else duration
    rates = rates or [rate] * len(channels)
    lines = [
        "File_Type:\tAnalog R/C ASCII\tGeneration#:\t2",
        "Board_Type:\tNI USB-6225\tPolarity:\tBipolar",
        f"Trial_Name:\tt\tTrial#:\t1\tDuration(Sec.):\t{duration:.6f}\t#Channels:\t{len(channels)}",
        f"BitDepth:\t16\tPreciseRate:\t{rate:.6f}",
        "",
        "",
        "Name\t" + "\t".join(channels) + "\t",
        "Rate\t" + "\t".join(f"{r:g}" for r in rates) + "\t",
        "Range\t" + "\t".join("2500" for _ in channels) + "\t",
    ]
    for k in range(samples):
        lines.append(f"{k / rate:.6f}\t" + "\t".join(str(k + j) for j in range(len(channels))) + "\t")
    return "\n".join(lines) + "\n\n"


def _write(tmp_path, text):
    path = tmp_path / "trial.anc"
    path.write_text(text)
    return path


# --- reader ---------------------------------------------------------------------------------------------------------


def test_reader_parses_a_small_file(tmp_path):
    recording = emg.read_anc(_write(tmp_path, _anc_text()))
    assert recording.names == ("F1Z", "SOL", "TA")
    assert recording.rate == 1000.0 and recording.n_samples == 5 and recording.bit_depth == 16
    np.testing.assert_allclose(recording.times, np.arange(5) / 1000.0)
    np.testing.assert_array_equal(recording.channel("TA"), np.arange(5) + 2)
    with pytest.raises(DataFormatError, match="no channel 'GMAX'"):
        recording.channel("GMAX")


@pytest.mark.parametrize(
    "mutate, message, line",
    [
        (lambda t: t.replace("Analog R/C ASCII", "Something else"), "not an 'Analog R/C ASCII' file", 1),
        (lambda t: t.replace("\tPreciseRate:\t1000.000000", ""), "lacks 'PreciseRate'", None),
        (lambda t: t.replace("Name\tF1Z\tSOL\tTA", "Name\tF1Z\tSOL"), "'Name' row has 2 fields for 3", 7),
        (lambda t: t.replace("Rate\t1000\t1000\t1000", "Rate\t1000\t2000\t1000"), "not sampled at PreciseRate", 8),
        (lambda t: t.replace("0.002000\t2\t3\t4", "0.002000\t2\t3"), "data row has 3 fields", 12),
        (lambda t: t.replace("0.002000\t2\t3\t4", "0.002000\t2\tx\t4"), "'x' is not a number", 12),
        (lambda t: t.replace("0.003000", "0.003500"), "does not follow", 13),
        (lambda t: t.replace("Duration(Sec.):\t0.004000", "Duration(Sec.):\t0.010000"), "header says Duration", None),
    ],
)
def test_reader_rejects_malformed_files_naming_file_and_line(tmp_path, mutate, message, line):
    text = _anc_text()
    changed = mutate(text)
    assert changed != text
    path = _write(tmp_path, changed)
    with pytest.raises(DataFormatError, match=message) as error:
        emg.read_anc(path)
    assert str(error.value).startswith(str(path))
    if line is not None:
        assert str(error.value).startswith(f"{path}:{line}:")


def test_reader_on_the_rajagopal_walk_emg():
    recording = emg.read_anc(data_path(emg.EMG_FILE))
    assert recording.n_channels == 28 and recording.rate == 2000.0 and recording.bit_depth == 16
    assert recording.names[-10:] == tuple(emg.EMG_MUSCLES)  # SOL GAS TA MH BF VL VM RF GMAX GMED
    assert recording.names[:3] == ("F1X", "F1Y", "F1Z")
    assert recording.n_samples == 4780 and recording.duration == pytest.approx(2.3895)
    assert recording.times[0] == 0.0 and recording.times[-1] == pytest.approx(2.3895)
    assert recording.ranges[recording.names.index("SOL")] == 2500
    assert recording.ranges[recording.names.index("GMAX")] == 1000
    assert np.all(recording.counts == np.round(recording.counts))  # raw integer ADC counts


# --- envelopes and on/off -------------------------------------------------------------------------------------------


def test_envelope_follows_the_amplitude_of_a_modulated_burst():
    rate = 2000.0
    t = np.arange(0, 2.0, 1 / rate)
    rng = np.random.default_rng(0)
    amplitude = np.where((t > 0.6) & (t < 1.2), 1.0, 0.05)
    raw = 300.0 + amplitude * rng.standard_normal(t.size) * 100  # DC offset, as raw ADC counts have
    envelope = emg.emg_envelope(raw, rate)
    assert envelope.min() >= 0
    burst, rest = envelope[(t > 0.75) & (t < 1.05)].mean(), envelope[(t < 0.4) | (t > 1.5)].mean()
    assert burst > 10 * rest  # the offset is gone and the burst stands out
    on = emg.on_off(envelope, 0.2)
    onset, offset = t[on][0], t[on][-1]
    assert abs(onset - 0.6) < 0.06 and abs(offset - 1.2) < 0.06  # zero lag: the burst edges stay in place
    spectrum = np.abs(np.fft.rfft(envelope - envelope.mean()))
    frequencies = np.fft.rfftfreq(t.size, 1 / rate)
    assert spectrum[frequencies > 20].max() < 0.01 * spectrum.max()


def test_on_off_rule_is_a_fraction_of_each_signals_range():
    x = np.array([0.1, 0.1, 0.3, 0.5, 1.1, 0.2])
    np.testing.assert_array_equal(emg.on_off(x, 0.2), x >= 0.1 + 0.2 * 1.0)
    assert not emg.on_off(np.full(5, 0.3), 0.2).any()
    assert emg.agreement([True, False, True, True], [True, True, True, False]) == 0.5
    assert emg.chance_agreement([True, False], [True, False]) == 0.5


def test_walk_envelopes_are_normalised_and_physiological():
    """Soleus and gastrocnemius fire in (late) right stance; tibialis anterior most around heel strike and in
    swing: the envelopes, on the motion frames, show the textbook pattern of the right leg."""
    from biomotion.io.mot import read_ground_reaction

    recording = emg.read_anc(data_path(emg.EMG_FILE))
    grf = read_ground_reaction(data_path(emg.GRF_FILE))
    times = np.round(np.arange(0, 2.3701, 0.01), 4)
    envelopes = emg.emg_envelopes(recording, times)
    assert set(envelopes) == set(emg.EMG_MUSCLES)
    for envelope in envelopes.values():
        assert envelope.max() == pytest.approx(1.0) and envelope.min() >= 0
    stance = np.interp(times, grf.times, grf.force[:, 0, 1]) > 50  # right foot on a plate
    for calf in ("SOL", "GAS"):
        assert envelopes[calf][stance].mean() > 2.5 * envelopes[calf][~stance].mean()
    assert envelopes["TA"][~stance].mean() > envelopes["TA"][stance].mean()


def test_plate_channels_share_the_grf_clock():
    recording = emg.read_anc(data_path(emg.EMG_FILE))
    alignment = emg.plate_alignment(recording, data_path(emg.GRF_FILE))
    assert alignment["lag_s"] == 0.0 and alignment["r_at_zero"] > 0.99


# --- the check ------------------------------------------------------------------------------------------------------


def test_emg_check_skips_cleanly_without_data(tmp_path):
    result = emg.emg_check(tmp_path)
    assert "emg_onoff_agreement" not in result
    assert result["skipped"] and "emg_walk_raw.anc" in result["skipped"][0]


@pytest.fixture(scope="module")
def check(data_root):
    pytest.importorskip("opensim")
    for relative in (emg.EMG_FILE, emg.MARKER_FILE, emg.GRF_FILE, emg.IK_SETUP, emg.GENERIC_MODEL):
        data_path(relative)
    return emg.emg_check(data_root)


@pytest.mark.slow
def test_emg_onoff_agreement_static_optimization(check):
    assert not check["skipped"] or "surrogate" in check["skipped"][0]
    assert check["emg_frames"] == 238 and check["emg_window_s"] == [0.0, 2.37]
    assert check["emg_onoff_agreement"] == pytest.approx(MEASURED_SO, abs=TOLERANCE)
    assert set(check["emg_per_muscle"]) == set(emg.EMG_MUSCLES)
    for channel, value in MEASURED_SO_PER_MUSCLE.items():
        assert check["emg_per_muscle"][channel] == pytest.approx(value, abs=0.06), channel
    assert check["emg_onoff_agreement"] == pytest.approx(np.mean(list(check["emg_per_muscle"].values())), abs=1e-3)
    assert check["emg_passes"] == (check["emg_onoff_agreement"] >= emg.BAR)
    assert check["emg_onoff_agreement"] > check["emg_chance_agreement"] + 0.1  # timing, not on-shares alone
    assert check["emg_predictions"]["so_converged_share"] == 1.0
    assert check["emg_alignment"]["lag_s"] == 0.0


@pytest.mark.slow
def test_emg_onoff_agreement_surrogate(check):
    if "emg_onoff_agreement_surrogate" not in check:
        pytest.skip("checkpoints/surrogate.safetensors absent")
    assert set(check["emg_per_muscle_surrogate"]) == set(emg.EMG_MUSCLES)
    assert check["emg_onoff_agreement_surrogate"] == pytest.approx(MEASURED_SURROGATE, abs=TOLERANCE)
