"""The viewer in headless Chromium: loads with no console error and no network request, draws the frames asked
for (bone vertices posed as Python poses them), plays, switches compare modes, and the picture changes."""

import io

import numpy as np
import pytest

from biomotion.io.bvh import read_bvh
from biomotion.io.mot import write_storage
from biomotion.viz.browser import Page, find_chromium
from biomotion.viz.scene import bvh_scene
from biomotion.viz.viewer import view_command, write_viewer
from tests.conftest import data_path

pytestmark = pytest.mark.skipif(
    find_chromium() is None, reason="headless Chromium not installed (Debian package `chromium`)"
)

BVH = "bandai-namco/dataset-1/dataset-1_walk_normal_001.bvh.gz"
COMPARE_BVH = "bandai-namco/dataset-1/dataset-1_walk_tired_001.bvh.gz"


@pytest.fixture(scope="module")
def page():
    with Page(1000, 700) as browser:
        yield browser


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _load(page: Page, path) -> None:
    page.errors.clear()
    page.requests.clear()
    page.open(path)
    assert page.evaluate("window.viewer.ready") is True
    assert page.errors == []
    assert [url for url in page.requests if not url.startswith("file://")] == []  # offline: nothing fetched


def test_bvh_clip_frames_are_drawn_as_posed(page, tmp_path):
    clip = read_bvh(data_path(BVH))
    scene = bvh_scene(clip, name="walk")
    path = write_viewer(scene, tmp_path / "walk.html")
    _load(page, path)
    assert page.evaluate("window.viewer.nFrames") == clip.n_frames
    assert page.evaluate("window.viewer.frame") == 0
    first = _pixels(page.screenshot())
    middle = clip.n_frames // 2
    page.evaluate(f"window.viewer.setFrame({middle})")
    assert page.evaluate("[window.viewer.frame, window.viewer.drawnFrame]") == [middle, middle]
    assert page.evaluate("document.getElementById('clock').textContent").startswith(f"t = {middle / 30:.2f} s")
    second = _pixels(page.screenshot())
    changed = np.abs(first - second).max(axis=-1) > 30
    assert changed.mean() > 0.002  # the figure moved (and the followed view with it)
    # the mesh Plotly draws is the bone surface posed as R v + p with this frame's pose (float32: 1e-4 m)
    drawn = np.array(
        page.evaluate(
            "(() => { const t = document.querySelector('#views .js-plotly-plot').data.find(d => d.type === 'mesh3d' "
            "&& d.name === 'bones'); return [Array.from(t.x), Array.from(t.y), Array.from(t.z)]; })()"
        )
    ).T
    expected = np.concatenate(
        [body.surface().vertices @ body.rotations[middle].T + body.positions[middle] for body in scene.bodies]
    )
    np.testing.assert_allclose(drawn, expected, atol=1e-4)
    frame = page.evaluate(
        "new Promise(r => { window.viewer.play(); "
        "setTimeout(() => { window.viewer.pause(); r(window.viewer.frame); }, 1500); })"
    )
    assert frame != middle  # playback advanced
    assert page.errors == []


def test_markers_forces_activations_and_compare_modes(page, tmp_path):
    times = np.arange(0, 1.31, 0.01)
    activation = np.stack([0.5 + 0.4 * np.sin(2 * np.pi * times), 0.5 - 0.4 * np.sin(2 * np.pi * times)], axis=1)
    write_storage(tmp_path / "act.sto", ["soleus_r", "tibant_r"], times, activation)
    path = view_command(
        data_path("opencap/Subject4/MarkerData/walking1.trc"),
        grf=data_path("opencap/Subject4/ID/walking1_grf.mot"),
        activations=tmp_path / "act.sto",
        compare=data_path(COMPARE_BVH),
        compare_mode="side",
        out=tmp_path / "compare.html",
    )
    _load(page, path)
    assert page.evaluate("window.viewer.traceCount().length") == 2  # side by side: two 3D views
    bars = page.evaluate("Array.from(document.getElementById('activations').data[0].x)")
    assert bars == pytest.approx(activation[0], abs=1 / 254)
    page.evaluate("window.viewer.setFrame(50)")
    grf_tips = page.evaluate(
        "document.querySelector('#views .js-plotly-plot').data.find(d => d.name === 'GRF').y.length"
    )
    assert grf_tips == 6  # two plates: origin, tip, gap each
    eye = page.evaluate(  # turning one view turns the other
        "(async () => { const d = document.querySelectorAll('#views .js-plotly-plot'); await Plotly.relayout(d[0], "
        "{'scene.camera': {up: {x: 0, y: 1, z: 0}, eye: {x: 1.5, y: 0.2, z: 0.3}, center: {x: 0, y: 0, z: 0}}}); "
        "await new Promise(r => setTimeout(r, 300)); return d[1]._fullLayout.scene.camera.eye; })()"
    )
    assert eye == pytest.approx({"x": 1.5, "y": 0.2, "z": 0.3})
    page.evaluate("window.viewer.setMode('overlay')")
    assert page.evaluate("window.viewer.traceCount().length") == 1  # overlay: one view holds both
    assert page.evaluate("document.getElementById('mode').value") == "overlay"
    page.evaluate("window.viewer.setFrame(60)")
    assert page.errors == []
