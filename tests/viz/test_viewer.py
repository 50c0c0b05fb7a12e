"""The viewer file without a browser: offline (no http(s) loads), the typed-array payload decodes back to the
scene, the `view` command's readers and errors."""

import base64
import json
import re
from html.parser import HTMLParser

import numpy as np
import pytest

from biomotion.errors import ConfigError, DataFormatError
from biomotion.io.mot import write_storage
from biomotion.io.trc import read_trc
from biomotion.viz.scene import markers_scene
from biomotion.viz.viewer import plotly_js, read_activations, read_com_zmp, view_command, viewer_html
from tests.conftest import data_path

TRC = "opencap/Subject4/MarkerData/walking1.trc"
GRF = "opencap/Subject4/ID/walking1_grf.mot"
BVH = "bandai-namco/dataset-1/dataset-1_walk_normal_001.bvh.gz"


class _Loads(HTMLParser):
    """Every URL the markup would load: src/href/data/poster/srcset attributes and CSS url(...)/@import."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.urls += [
            value for name, value in attrs if name in ("src", "href", "data", "poster", "srcset", "action") and value
        ]


def _payload(text: str) -> dict:
    match = re.search(r'<script type="application/json" id="scene-data">(.*?)</script>', text, re.S)
    return json.loads(match[1].replace("<\\/", "</"))


def _array(entry: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(entry["b64"]), dtype=np.dtype(entry["dtype"]).newbyteorder("<")).reshape(
        entry["shape"]
    )


def test_the_page_loads_nothing_from_the_network(tmp_path):
    out = view_command(data_path(BVH), compare=data_path(TRC), out=tmp_path / "viewer.html")
    text = out.read_text()
    parser = _Loads()
    parser.feed(text)
    assert parser.urls == []  # no <script src>, <link href>, <img src> ... at all: everything is inline
    css = "".join(re.findall(r"<style>(.*?)</style>", text, re.S))
    assert "url(" not in css and "@import" not in css
    assert plotly_js() in text  # plotly.js comes from the installed package, inline
    assert text.count("<script") == 3  # plotly.js, the data block, the control script


def test_payload_decodes_back_to_the_scene(tmp_path):
    markers = read_trc(data_path(TRC))
    scene = markers_scene(markers, name="walking1")
    text = viewer_html(scene, title="walk <1>")
    assert '<h1 id="title">walk &lt;1&gt;</h1>' in text and "<title>walk &lt;1&gt;</title>" in text
    data = _payload(text)
    xyz = _array(data["main"]["points"][0]["xyz"])  # [T, 3, K]
    np.testing.assert_array_equal(np.swapaxes(xyz, 1, 2), markers.positions.astype(np.float32))  # NaN kept
    np.testing.assert_allclose(_array(data["times"]), markers.times, atol=1e-6)
    assert data["main"]["points"][0]["labels"] == list(markers.names)
    lo, hi = np.array(data["bounds"]["lo"]), np.array(data["bounds"]["hi"])
    assert np.all(lo <= np.nanmin(markers.positions, axis=(0, 1)) + 1e-9)
    assert np.all(hi >= np.nanmax(markers.positions, axis=(0, 1)) - 1e-9)
    assert data["follow"] is False  # walking1 crosses 1.7 m of lab: it fits one view


def test_compare_frames_are_nearest_in_time(tmp_path):
    out = view_command(data_path(TRC), compare=data_path(BVH), out=tmp_path / "v.html", compare_mode="side")
    data = _payload(out.read_text())
    assert data["mode"] == "side" and data["compare"]["bodies"]["count"] == 16
    frame_map = _array(data["compare"]["frame_map"])
    times = _array(data["times"])
    assert frame_map.shape == times.shape
    compare_times = np.arange(data["compare"]["n"]) / 30.0  # BVH at 30 fps
    distance = np.abs(compare_times[None] - times[:, None])
    np.testing.assert_allclose(distance[np.arange(times.size), frame_map], distance.min(axis=1), atol=1e-6)


def test_activations_and_balance_files(tmp_path):
    grf = data_path(GRF)
    times = np.arange(0, 1.3, 0.01)
    activation = 0.5 + 0.4 * np.sin(2 * np.pi * times)
    write_storage(
        tmp_path / "so.sto",
        ["soleus_r", "tibant_r", "FX_reserve"],
        times,
        np.stack([activation, 1 - activation, 50 * activation], axis=1),
    )
    com = np.stack([times, np.full_like(times, 0.93), np.zeros_like(times)], axis=1)
    square = np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0, 0.1], [0, 0, 0.1]], dtype=float)
    support = np.broadcast_to(square, (len(times), 4, 3)) + com[:, None] * [1, 0, 0]
    labels = ["com_x", "com_y", "com_z", "zmp_x", "zmp_y", "zmp_z"] + [
        f"support_{k}_{a}" for k in range(4) for a in "xyz"
    ]
    write_storage(
        tmp_path / "balance.sto",
        labels,
        times,
        np.concatenate([com, com * [1, 0, 1], support.reshape(len(times), -1)], axis=1),
    )
    names = read_activations(tmp_path / "so.sto")[1]
    assert names == ("soleus_r", "tibant_r")  # the reserve actuator (N) is not an activation
    write_storage(
        tmp_path / "states.sto",
        ["/jointset/knee_r/knee_angle_r/value", "/forceset/soleus_r/activation", "gasmed_r.activation"],
        times,
        np.stack([0.5 * activation, activation, 1 - activation], axis=1),
    )
    _, names, values = read_activations(tmp_path / "states.sto")
    assert names == ("soleus_r", "gasmed_r") and values.shape == (len(times), 2)  # a knee angle in [0, 1] rad is not
    out = view_command(
        data_path(TRC),
        grf=grf,
        activations=tmp_path / "so.sto",
        com_zmp=tmp_path / "balance.sto",
        out=tmp_path / "v.html",
    )
    data = _payload(out.read_text())["main"]
    coded = _array(data["activations"]["values"])
    np.testing.assert_array_equal(coded[:130, 0], np.round(activation * 254).astype(np.uint8))
    assert data["support"]["count"] == 4 and _array(data["com"])[10, 1] == pytest.approx(0.93)
    assert len(data["arrows"]) == 1 and data["arrows"][0]["count"] == 2
    with pytest.raises(DataFormatError, match="no balance columns"):
        read_com_zmp(tmp_path / "so.sto")


def test_view_command_errors(tmp_path):
    ik = data_path("opencap/Subject4/IK/walking1_ik.mot")
    with pytest.raises(ConfigError, match="pass --model OSIM"):
        view_command(ik, out=tmp_path / "v.html")
    with pytest.raises(ConfigError, match="cannot view .csv"):
        view_command(tmp_path / "clip.csv", out=tmp_path / "v.html")
    with pytest.raises(ConfigError, match="compare mode"):
        view_command(data_path(TRC), out=tmp_path / "v.html", compare_mode="stacked")
    assert not (tmp_path / "v.html").exists()


def test_coordinates_through_a_model_with_forces(tmp_path):
    folder = "SchreiberMoissenet2019/2014001"
    out = view_command(
        data_path(f"{folder}/C4_05_ik.mot"),
        model=data_path(f"{folder}/2014001_scaledModelAdjusted.osim"),
        grf=data_path(f"{folder}/2014001_C4_05_grf.mot"),
        geometry=[data_path("opensim-models/Models/Rajagopal/Geometry"), data_path("opensim-models/Geometry")],
        out=tmp_path / "model.html",
    )
    data = _payload(out.read_text())["main"]
    assert data["bodies"]["count"] == 22 and data["n"] == 53
    assert _array(data["bodies"]["vertices"]).shape[0] > 20000  # Rajagopal's bone meshes, not only capsules
    origin = _array(data["arrows"][0]["origin"])  # [T, 3, plates]
    assert np.isfinite(origin[:, 1]).any(axis=0).all()  # both plates are loaded during the step


def test_c3d_markers_with_their_force_plate(tmp_path):
    out = view_command(data_path("fukuchi-running/c3d/RBDS002runT35.c3d"), out=tmp_path / "run.html")
    data = _payload(out.read_text())
    assert data["main"]["n"] == 4500 and data["main"]["points"][0]["count"] == 33  # 30 s at 150 Hz, 33 markers
    vector = _array(data["main"]["arrows"][0]["vector"])  # treadmill plate, both feet: [T, 3, 1], m
    assert 1.2 < np.nanmax(vector[:, 1]) < 2.5  # running peak vertical GRF ~2-3 body weights, drawn 1 mm/N
    assert data["follow"] is False  # treadmill: the runner stays in place
    assert out.stat().st_size < 20e6
