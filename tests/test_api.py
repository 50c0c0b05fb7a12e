"""The top-level API named in the README: `import biomotion as bm`."""

import pytest

import biomotion as bm
from tests.conftest import data_path


def test_top_level_names_load_lazily_and_work():
    motion = bm.read(data_path("opencap/Subject4/IK/DJ1_ik.mot"))
    assert isinstance(motion, bm.Motion) and motion.n_frames == 269
    model = bm.BodyModel.from_osim(data_path("opencap/Subject4/Models/optimized_scale_and_markers.osim"))
    assert model.total_mass == pytest.approx(62.6)
    assert callable(bm.analyze) and callable(bm.solve_ik)
    with pytest.raises(AttributeError, match="no attribute 'generate'"):
        bm.generate
