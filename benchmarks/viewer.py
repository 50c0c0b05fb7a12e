"""Viewer benchmark: HTML size and load time in headless Chromium for 30 s trials at 100 Hz, on real data.

Scenes:
  bvh       Bandai-Namco `dataset-1_dance-short_normal_001` (63 s at 30 fps): its first 30 s, the BVH channels
            resampled to 100 Hz (cubic spline through the unwrapped Euler angles and the positions) -> 3001 frames,
            16 bodies drawn as capsules, 21 joints as points.
  markers   Fukuchi et al. 2017 runner RBDS002 at 3.5 m/s (C3D, 30 s): 33 markers at 150 Hz resampled to 100 Hz
            with `Markers.resample` (anti-alias low-pass first) -> 3000 frames, and the treadmill plate (300 Hz)
            as a GRF arrow on the same clock.
  compare   the `bvh` scene overlaid with seconds 30-60 of the same clip, resampled the same way.

For each scene: the time to build and write the file, its size, and, in a fresh headless Chromium (new profile,
nothing cached), the time from navigation to the first frame drawn (``window.viewer.ready``), over five loads,
and when plotly.js was ready; then the median time to draw one frame (``window.viewer.setFrame``, including the
browser paint) over 20 frames.
Writes a Markdown table (default ``docs/results/viewer.md``) and a screenshot of the BVH viewer
(``docs/images/viewer_bvh.png``).

    python benchmarks/viewer.py [--data-root ../shared/data] [--out docs/results/viewer.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.interpolate

from biomotion.io.atomic import atomic_write
from biomotion.io.bvh import BVHMotion, read_bvh
from biomotion.io.c3d import read_c3d
from biomotion.viz.browser import Page, find_chromium
from biomotion.viz.scene import Scene, bvh_scene, markers_scene
from biomotion.viz.viewer import write_viewer

RATE = 100.0
SPAN = 30.0
CLIP = "bandai-namco/dataset-1/dataset-1_dance-short_normal_001.bvh.gz"
RUN = "fukuchi-running/c3d/RBDS002runT35.c3d"
LOADS = 5
FRAMES = 20


def resampled_bvh(clip: BVHMotion, start: float, stop: float, rate: float) -> BVHMotion:
    """Seconds [start, stop] of ``clip`` at ``rate`` Hz: each channel through a cubic spline (angles unwrapped)."""
    rotation = np.array([c.endswith("rotation") for chans in clip.skeleton.channels for c in chans])
    values = clip.values.copy()
    values[:, rotation] = np.unwrap(values[:, rotation], period=360.0, axis=0)
    times = start + np.arange(int(round((stop - start) * rate)) + 1) / rate
    spline = scipy.interpolate.CubicSpline(clip.times, values, axis=0)
    return BVHMotion(clip.skeleton, spline(times), 1.0 / rate, units=clip.units)


def scenes(root: Path) -> dict[str, tuple[Scene, Scene | None]]:
    clip = read_bvh(root / CLIP)
    first = bvh_scene(resampled_bvh(clip, 0.0, SPAN, RATE), name="dance 0-30 s")
    second = bvh_scene(resampled_bvh(clip, SPAN, 2 * SPAN, RATE), name="dance 30-60 s")
    trial = read_c3d(root / RUN)
    markers = trial.markers.resample(RATE)
    run = markers_scene(markers, name="markers").with_ground_reaction(trial.forces)
    return {"bvh": (first, None), "markers": (run, None), "compare": (first, second)}


def _describe(scene: Scene) -> str:
    parts = [f"{scene.n_frames} frames"]
    if scene.bodies:
        parts.append(f"{len(scene.bodies)} bodies ({sum(len(b.surface().vertices) for b in scene.bodies)} vertices)")
    parts += [f"{p.positions.shape[1]} points ({p.name})" for p in scene.points]
    parts += [f"{a.origins.shape[1]} {a.name} arrow(s)" for a in scene.arrows]
    return ", ".join(parts)


def measure(path: Path, screenshot: Path | None = None) -> dict:
    loads, plotly_ready, frames = [], [], []
    for run in range(LOADS):
        with Page(1200, 800) as page:
            start = time.monotonic()
            page.open(path)
            page.evaluate("window.viewer.ready")
            loads.append(time.monotonic() - start)
            plotly_ready.append(page.evaluate("window.viewer.timings.script") / 1000.0)
            if page.errors:
                raise RuntimeError(f"{path}: page errors {page.errors}")
            if run == 0:
                frames = page.evaluate(
                    f"(async () => {{ const v = window.viewer, out = []; for (let k = 1; k <= {FRAMES}; k++) {{ "
                    f"const t0 = performance.now(); await v.setFrame(Math.floor(k * (v.nFrames - 1) / {FRAMES})); "
                    "out.push(performance.now() - t0); } return out; })()"
                )
                if screenshot is not None:
                    page.evaluate("window.viewer.setFrame(Math.floor(window.viewer.nFrames * 0.37))")
                    screenshot.parent.mkdir(parents=True, exist_ok=True)
                    with atomic_write(screenshot, "wb") as handle:
                        handle.write(page.screenshot())
    return {
        "load_median": statistics.median(loads),
        "load_max": max(loads),
        "plotly": statistics.median(plotly_ready),
        "frame_ms": statistics.median(frames),
    }


def chromium_version() -> str:
    return subprocess.run([find_chromium(), "--version"], capture_output=True, text=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, default=Path("docs/results/viewer.md"))
    parser.add_argument("--screenshot", type=Path, default=Path("docs/images/viewer_bvh.png"))
    args = parser.parse_args()
    if find_chromium() is None:
        raise SystemExit("headless Chromium is needed (Debian package `chromium`)")
    import plotly

    rows = []
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as folder:
        for name, (scene, compare) in scenes(args.data_root).items():
            start = time.monotonic()
            path = write_viewer(scene, Path(folder) / f"{name}.html", compare=compare)
            build = time.monotonic() - start
            result = measure(path, args.screenshot if name == "bvh" else None)
            what = _describe(scene) + ("" if compare is None else f"; compare: {_describe(compare)}")
            rows.append((name, what, path.stat().st_size / 1e6, build, result))
            print(
                f"{name}: {rows[-1][2]:.2f} MB, built in {build:.2f} s, loads in {result['load_median']:.2f} s "
                f"(max {result['load_max']:.2f}; plotly.js ready at {result['plotly']:.2f} s), "
                f"frame {result['frame_ms']:.0f} ms",
                flush=True,
            )
    lines = [
        "# Viewer: file size and load time",
        "",
        "Produced by `python benchmarks/viewer.py` (see its docstring for how each 30 s, 100 Hz scene is built",
        "from real data). Load = navigation to the first frame drawn (`window.viewer.ready`) in a fresh headless",
        f"Chromium, median (max) of {LOADS} loads; plotly.js = when the page's own script starts, i.e. the file is",
        "read and plotly.js parsed and run (median); the rest of the load builds the 3D views and draws frame 0;",
        f"frame = median time of `setFrame` (draw + paint) over {FRAMES} frames.",
        "Goals: load under 3 s, file under 20 MB.",
        "",
        "| scene | content | HTML (MB) | build (s) | load median (s) | load max (s) | plotly.js (s) | frame (ms) |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, what, size, build, result in rows:
        lines.append(
            f"| {name} | {what} | {size:.2f} | {build:.2f} | {result['load_median']:.2f} | "
            f"{result['load_max']:.2f} | {result['plotly']:.2f} | {result['frame_ms']:.0f} |"
        )
    lines += [
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, load average {load_before:.2f} at the "
        f"start (other work shares the cores); {chromium_version()} with software WebGL (SwiftShader); "
        f"plotly.js from plotly {plotly.__version__}.",
        "",
    ]
    with atomic_write(args.out) as handle:
        handle.write("\n".join(lines))
    print(f"wrote {args.out} and {args.screenshot}")


if __name__ == "__main__":
    main()
