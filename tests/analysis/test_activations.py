"""`biomotion analyze --muscles`: activations of a trial on its own model, against OpenSim 4.6's StaticOptimization."""

import numpy as np
import pytest

from biomotion.analysis.activations import check_paths, load_paths
from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.errors import ModelError
from biomotion.io.mot import read_storage
from tests.conftest import data_path

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"


def test_analyze_with_muscles_matches_opensim_static_optimization(tmp_path, capsys):
    """The gait2392 walk (its IK and plates) through `biomotion analyze --muscles gait2392_subject01`, against
    OpenSim's StaticOptimization run fresh on the same IK file and loads (0.9-1.15 s). Measured: mean R² 0.997 over
    the 27 muscles whose activation varies (std > 0.02), max |difference| 0.011; bars 0.99 and 0.03. The rest of
    the walk: `python benchmarks/analysis_chain.py`."""
    pytest.importorskip("opensim")
    from biomotion.validation.muscles import opensim_gait_static_optimization, r_squared

    folder = data_path(GAIT)
    root = folder.parents[2]
    code = main(
        [
            "analyze",
            str(folder / "subject01_walk1_ik.mot"),
            "--model",
            str(folder / "OutputReference/subject01_simbody.osim"),
            "--grf",
            str(folder / "subject01_walk1_grf.mot"),
            "--forces-trim",  # the plates stop at 2.5 s, the IK at 4 s: only the frames with forces
            "--muscles",
            "gait2392_subject01",
            "--out",
            str(tmp_path),
            "--no-figures",
        ]
    )
    assert code == 0
    assert "92 muscles balance 17 coordinates on 121 of 121 frames" in capsys.readouterr().out
    table = read_storage(tmp_path / "activations.sto")
    assert len(table.labels) == 92 + 17 and table.labels[-1] == "lumbar_rotation_reserve"
    reference = opensim_gait_static_optimization(root, 0.9, 1.15)
    ours = np.stack(
        [np.interp(reference.times, table.times, table.data[:, table.labels.index(m)]) for m in reference.muscle_names],
        1,
    )
    varying = reference.activations.std(0) > 0.02
    assert varying.sum() >= 20
    assert r_squared(ours[:, varying], reference.activations[:, varying]).mean() >= 0.99
    assert np.abs(ours - reference.activations).max() <= 0.03


def test_paths_say_which_model_they_were_fitted_on():
    source = data_path(f"{GAIT}/OutputReference/subject01_simbody.osim")
    other = data_path("opensim-models/Models/Gait2392_Simbody/subject01.osim")
    paths, label = load_paths("gait2392_subject01")
    assert check_paths(paths, label, source, BodyModel.from_osim(source).coordinate_names).verified
    check = check_paths(paths, label, other, BodyModel.from_osim(other).coordinate_names)
    assert not check.verified and "fitted on another model file (subject01_simbody.osim)" in check.warning
    rajagopal, label = load_paths("rajagopal2016")
    with pytest.raises(ModelError, match="its coordinates are not those of"):
        check_paths(rajagopal, label, source, BodyModel.from_osim(source).coordinate_names)
    with pytest.raises(ModelError, match="no shipped muscle paths named 'gait2354'"):
        load_paths("gait2354")
    with pytest.raises(ModelError, match="muscle path file not found"):
        load_paths("missing.safetensors")
