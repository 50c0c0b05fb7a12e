"""`biomotion validate ik` on a data root holding an OpenCap subject the project has never seen: every subject under
``opencap/`` in Subject4's layout is solved and compared with OpenSim, not only Subject4."""

import shutil

import pytest

from biomotion.io.trc import read_trc, write_trc
from tests.conftest import data_path

pytest.importorskip("opensim", reason="validation needs the opensim package (validate extra)")


def test_another_opencap_subject_is_validated(tmp_path):
    from biomotion.validation.ik import opencap_subjects, validate_ik

    subject4 = data_path("opencap/Subject4")
    folder = tmp_path / "root" / "opencap" / "Subject9"  # Subject4's walking1 (0.3 s of it) under a new name
    for relative in ("Models/optimized_scale_and_markers.osim", "IK/walking1_ik_setup.xml"):
        (folder / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(subject4 / relative, folder / relative)
    (folder / "MarkerData").mkdir()
    write_trc(folder / "MarkerData/walking1.trc", read_trc(subject4 / "MarkerData/walking1.trc").slice(0.3, 0.6))
    root = tmp_path / "root"
    assert opencap_subjects(root) == ["Subject9"]
    report = validate_ik(root, opencap_trials=("all",), runners=0, rajagopal=False, bvh=False)
    assert list(report["cases"]) == ["opencap_subject9_walking1"]
    case = report["cases"]["opencap_subject9_walking1"]
    assert case["frames"] == 31 and case["ik_marker_rmse_m"] <= case["opensim_marker_rmse_m"] + 1e-6
