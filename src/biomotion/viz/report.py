"""The quality report of a batch: one self-contained HTML file that opens offline.

What it shows (from the outcomes `biomotion.analysis.batch` records, plain JSON-able dicts, so this module needs
nothing above `viz`): a summary (verdict counts, settings, the rules); one sortable table of every trial — verdict
and reasons, marker RMS and max error, worst markers, markers missing, residual force and moment at the pelvis (%
BW, % BW·height), suspicious force frames by reason, frames flagged, plate assignment, joint limits hit, the force
source, static optimization, time, and a link to the trial's viewer page; and per subject what scaling did (scale
factors per body, total and per-body mass, static-pose marker errors and verdict) with plots of joint angles,
torques and vertical ground reaction, the mean and ±1 SD over the subject's trials of each activity (trials
grouped by name without trailing digits: ``walking1``, ``walking2`` -> ``walking``), each trial first reduced to
its mean right-foot cycle.

Self-contained: plotly.js (from the installed ``plotly`` package, as the viewer embeds it), the data and a small
script are inline; nothing is fetched. Plots of a subject are drawn when its section is opened, so a study of
hundreds of trials opens at once. Column sorting is a click on a header (numbers sort as numbers).
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from biomotion.io.atomic import atomic_write

_STYLE = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
h1{font-size:1.4em} h2{font-size:1.2em;margin-top:1.6em} h3{font-size:1.05em}
table{border-collapse:collapse;font-size:12px;margin:.5em 0}
th,td{border:1px solid #ccc;padding:3px 6px;vertical-align:top}
th{background:#f0f0f0;cursor:pointer;position:sticky;top:0}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.ok{background:#e3f4e3}.warn{background:#fff3cd}.fail{background:#f8d7da}
.verdict{font-weight:bold;text-align:center}
.reasons{max-width:38em}
.plots{display:flex;flex-wrap:wrap;gap:8px}
.plot{width:420px;height:280px}
details{margin:.6em 0;border:1px solid #ddd;padding:.3em .6em}
summary{cursor:pointer;font-weight:bold}
.small{font-size:12px;color:#555}
"""

_SCRIPT = r"""
(function(){
  const data = JSON.parse(document.getElementById('report-data').textContent);
  function sortTable(th){
    const table = th.closest('table'), body = table.tBodies[0];
    const index = Array.prototype.indexOf.call(th.parentNode.children, th);
    const ascending = th.dataset.order !== 'asc';
    th.dataset.order = ascending ? 'asc' : 'desc';
    const rows = Array.from(body.rows);
    const key = r => {
      const c = r.cells[index];
      const v = c.dataset.sort !== undefined ? c.dataset.sort : c.textContent;
      const n = parseFloat(v);
      return isNaN(n) || !/^-?[0-9.eE+-]+$/.test(v.trim()) ? v.toLowerCase() : n;
    };
    rows.sort((a, b) => { const x = key(a), y = key(b);
      if (typeof x === 'number' && typeof y === 'number') return ascending ? x - y : y - x;
      return ascending ? String(x).localeCompare(String(y)) : String(y).localeCompare(String(x)); });
    rows.forEach(r => body.appendChild(r));
  }
  document.querySelectorAll('table.sortable th').forEach(th => th.addEventListener('click', () => sortTable(th)));
  const colors = ['#1f77b4','#d62728','#2ca02c','#9467bd','#ff7f0e','#8c564b','#17becf','#e377c2'];
  function band(x, mean, sd, color, name){
    const up = mean.map((m, i) => m + sd[i]), low = mean.map((m, i) => m - sd[i]);
    return [{x: x.concat(x.slice().reverse()), y: up.concat(low.reverse()), fill: 'toself', fillcolor: color + '33',
             line: {width: 0}, hoverinfo: 'skip', showlegend: false, type: 'scatter', mode: 'lines'},
            {x: x, y: mean, name: name, line: {color: color, width: 2}, type: 'scatter', mode: 'lines'}];
  }
  function draw(subject){
    const groups = data.curves[subject] || {};
    Object.keys(groups).forEach(group => {
      const g = groups[group];
      const x = g.x;
      [['angles', 'joint angle (deg)'], ['torques', 'joint moment (N·m/kg)'], ['grf', 'vertical GRF (BW)']].forEach(
        ([kind, label]) => {
          const div = document.getElementById('plot-' + g.id + '-' + kind);
          if (!div || div.dataset.drawn) return;
          const traces = [];
          Object.keys(g[kind]).forEach((name, k) => {
            traces.push(...band(x, g[kind][name].mean, g[kind][name].sd, colors[k % colors.length], name)); });
          Plotly.newPlot(div, traces, {title: {text: group + ': ' + label + ' (n = ' + g.n + ')', font: {size: 12}},
            margin: {l: 45, r: 10, t: 30, b: 35}, xaxis: {title: {text: '% of cycle'}}, legend: {font: {size: 9}}},
            {displayModeBar: false, responsive: true});
          div.dataset.drawn = '1';
        });
    });
  }
  document.querySelectorAll('details[data-subject]').forEach(d => d.addEventListener('toggle', () => {
    if (d.open) draw(d.dataset.subject); }));
  window.report = {data: data, draw: draw, ready: true};
})();
"""

VERDICT_ORDER = {"ok": 0, "warn": 1, "fail": 2}


def _esc(value: Any) -> str:
    return html.escape("" if value is None else str(value))


def _num(value: Any, scale: float = 1.0, digits: int = 1) -> tuple[str, str]:
    """(text, sort key) of a number (blank and a low key when missing)."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "", "-1e300"
    return f"{scale * float(value):.{digits}f}", repr(scale * float(value))


def _reason(outcome: dict, rule: str) -> dict:
    return next((r for r in outcome.get("verdict", {}).get("reasons", []) if r.get("rule") == rule), {})


def activity(name: str) -> str:
    """A trial's activity: its name without trailing digits (``walking2`` -> ``walking``, ``runT35`` -> ``runT``)."""
    stripped = re.sub(r"\d+$", "", name)
    return stripped or name


def _plates(figures: dict) -> str:
    parts = []
    for channel, a in (figures.get("plates") or {}).items():
        if a.get("mode") == "given":
            parts.append(f"{channel}→{a.get('body')} (given)")
        elif a.get("frames"):
            shares = [f"{side} {100 * a[side]:.0f}%" for side in ("right", "left") if a.get(side, 0) >= 0.005]
            parts.append(f"{channel}→{' / '.join(shares)} (auto)")
        else:
            parts.append(f"{channel}: unloaded")
    return "; ".join(parts)


def _trial_row(outcome: dict, index: int) -> str:
    verdict = outcome.get("verdict", {}).get("verdict", "fail")
    figures = outcome.get("figures", {}) or {}
    markers = _reason(outcome, "markers").get("figures", {})
    missing = _reason(outcome, "markers_missing").get("figures", {})
    residual = _reason(outcome, "residuals").get("figures", {})
    force = _reason(outcome, "force_data")
    limits = _reason(outcome, "joint_limits").get("figures", {}).get("frames_per_coordinate", {})
    reasons = [
        r["message"] for r in outcome.get("verdict", {}).get("reasons", []) if r.get("verdict") in ("warn", "fail")
    ]
    if outcome.get("error"):
        reasons = [outcome["error"]]
    worst = ", ".join(f"{w['marker']} {100 * w['rms_m']:.1f}" for w in markers.get("worst_markers", []))
    occluded = missing.get("occluded_share", {}) or {}
    missing_text = ", ".join(missing.get("missing", []) or [])
    if occluded:
        gaps = sorted(occluded.items(), key=lambda kv: -kv[1])[:3]
        missing_text = "; ".join(filter(None, [missing_text, ", ".join(f"{n} {100 * v:.0f}% gaps" for n, v in gaps)]))
    force_figures = force.get("figures", {})
    force_text = ", ".join(
        f"{k.replace('_', ' ')} {force_figures[k]}"
        for k in ("foot_off_plate", "both_feet_on_one_plate", "cop_outside_foot")
        if force_figures.get(k)
    )
    frames = outcome.get("verdict", {}).get("frames", 0)
    flagged = outcome.get("verdict", {}).get("frames_flagged", 0)
    files = outcome.get("files", {}) or {}
    viewer = files.get("viewer")
    link = f'<a href="{_esc(outcome["subject"])}/{_esc(outcome["name"])}/{_esc(viewer)}">view</a>' if viewer else ""
    cells = [
        (f"{_esc(outcome['subject'])}", None, ""),
        (f"{_esc(outcome['name'])}", None, ""),
        (verdict, str(VERDICT_ORDER.get(verdict, 3)), f"verdict {verdict}"),
        ("<br>".join(_esc(r) for r in reasons), None, "reasons"),
        (*_num(markers.get("rms_m"), 100, 2), "num"),
        (*_num(markers.get("max_m"), 100, 1), "num"),
        (_esc(worst), None, ""),
        (_esc(missing_text), None, ""),
        (*_num(residual.get("force_rms_bw"), 100, 1), "num"),
        (*_num(residual.get("moment_rms_bw_height"), 100, 2), "num"),
        (_esc(force_text), str(force.get("flagged", 0)), ""),
        (f"{flagged}/{frames}", repr(flagged / frames if frames else 0.0), "num"),
        (_esc(_plates(figures)), None, ""),
        (_esc(", ".join(f"{k} ({v})" for k, v in limits.items())), str(len(limits)), ""),
        (_esc(figures.get("torques_from", "")), None, ""),
        (_esc(figures.get("static_optimization") or ""), None, "reasons"),
        (*_num((outcome.get("seconds") or {}).get("total"), 1, 1), "num"),
        (link, None, ""),
    ]
    tds = "".join(
        f'<td class="{cls}"' + (f' data-sort="{_esc(key)}"' if key is not None else "") + f">{text}</td>"
        for text, key, cls in cells
    )
    return f'<tr id="trial-{index}">{tds}</tr>'


TRIAL_COLUMNS = (
    "subject",
    "trial",
    "verdict",
    "reasons (warn / fail)",
    "marker RMS (cm)",
    "marker max (cm)",
    "worst markers (RMS cm)",
    "markers missing / gaps",
    "residual F RMS (% BW)",
    "residual M RMS (% BW·h)",
    "suspicious force frames",
    "frames flagged",
    "plate assignment",
    "joint limits hit (frames)",
    "torques from",
    "static optimization",
    "time (s)",
    "viewer",
)


def _static_row(subject: dict) -> str:
    verdict = subject.get("verdict", {}).get("verdict", "fail")
    reasons = subject.get("error") or "; ".join(r["message"] for r in subject.get("verdict", {}).get("reasons", []))
    mass = (subject.get("figures") or {}).get("mass_kg") or 0.0
    return (
        f"<tr><td>{_esc(subject['subject'])}</td><td>{_esc(subject['name'])}</td>"
        f'<td class="verdict {verdict}" data-sort="{VERDICT_ORDER.get(verdict, 3)}">{verdict}</td>'
        f'<td class="reasons">{_esc(reasons)}</td><td class="num">{mass:.2f}</td></tr>'
    )


def _subject_section(subject: dict, curves: dict, ids: dict) -> str:
    name = subject["subject"]
    figures = subject.get("figures", {}) or {}
    verdict = subject.get("verdict", {}).get("verdict", "fail")
    lines = [
        f'<details data-subject="{_esc(name)}"><summary>{_esc(name)} — scaling <span class="{verdict}">'
        f"{verdict}</span></summary>"
    ]
    if subject.get("error"):
        lines.append(f'<p class="fail">scaling failed: {_esc(subject["error"])}</p>')
    else:
        messages = [r["message"] for r in subject.get("verdict", {}).get("reasons", [])]
        lines.append(
            f"<p>generic model <code>{_esc(figures.get('generic_model'))}</code>; total mass "
            f"{figures.get('mass_kg', float('nan')):.2f} kg"
            + (f", height {figures['height_m']:.2f} m" if figures.get("height_m") else "")
            + (f"; {figures['markers_placed']} markers placed" if figures.get("markers_placed") is not None else "")
            + "</p>"
        )
        if messages:
            lines.append("<p class='small'>static pose: " + "<br>".join(_esc(m) for m in messages) + "</p>")
        factors = figures.get("scale_factors") or {}
        masses = figures.get("body_mass_kg") or {}
        rows = "".join(
            f"<tr><td>{_esc(body)}</td>"
            + "".join(f'<td class="num">{v:.4f}</td>' for v in factors.get(body, [1.0, 1.0, 1.0]))
            + f'<td class="num">{masses.get(body, 0.0):.3f}</td></tr>'
            for body in (masses or factors)
        )
        note = "" if factors else "<p class='small'>no scaling: the model was used as given</p>"
        lines.append(
            note + '<table class="sortable"><thead><tr><th>body</th><th>scale x</th><th>scale y</th><th>scale z</th>'
            f"<th>mass (kg)</th></tr></thead><tbody>{rows}</tbody></table>"
        )
    for group, entry in curves.items():
        gid = ids[(name, group)]
        lines.append(f"<h3>{_esc(group)}: {entry['n']} trial(s)</h3><div class='plots'>")
        for kind in ("angles", "torques", "grf"):
            lines.append(f'<div class="plot" id="plot-{gid}-{kind}"></div>')
        lines.append("</div>")
    lines.append("</details>")
    return "\n".join(lines)


def subject_curves(trials: Sequence[dict]) -> dict[str, dict[str, dict]]:
    """Per subject and activity: the mean and SD over trials of each trial's mean-cycle curve."""
    grouped: dict[str, dict[str, list[dict]]] = {}
    for outcome in trials:
        curves = outcome.get("curves") or {}
        if outcome.get("status") != "done" or not curves.get("angles_deg"):
            continue
        grouped.setdefault(outcome["subject"], {}).setdefault(activity(outcome["name"]), []).append(curves)
    out: dict[str, dict[str, dict]] = {}
    for subject, groups in grouped.items():
        for group, members in groups.items():
            entry: dict[str, Any] = {"n": len(members)}
            points = len(next(iter(members[0]["angles_deg"].values())))
            entry["x"] = np.linspace(0, 100, points).round(2).tolist()
            for kind, key in (("angles", "angles_deg"), ("torques", "torques_nm_kg"), ("grf", "grf_bw")):
                names = [n for n in members[0][key] if all(n in m[key] for m in members)]
                entry[kind] = {}
                for n in names:
                    stack = np.array([m[key][n] for m in members], dtype=float)
                    entry[kind][n] = {
                        "mean": np.nanmean(stack, 0).round(4).tolist(),
                        "sd": (np.nanstd(stack, 0) if len(members) > 1 else np.zeros(points)).round(4).tolist(),
                    }
            out.setdefault(subject, {})[group] = entry
    return out


RULES = (
    "Per-frame rules from published practice; a rule fails when at least 50 % of its frames break it (the median "
    "frame) and warns from 5 % (the 95th-percentile frame). Markers: max error 4 cm, RMS 2 cm (OpenSim IK best "
    "practice); static pose: landmark max 2 cm, RMS 1 cm (OpenSim scaling best practice). Swapped labels and fewer "
    "than half the tracked markers found fail. Residuals: 5 % of peak external force, 1 % of COM height × peak "
    "external force (Hicks et al. 2015), warn only. Force frames: foot off the plate, both feet on one plate, CoP "
    "outside the foot (0.1 × foot length + 2 cm). Joint limits: clamped coordinates at their bounds. Velocity: "
    "160 rad/s, 12.5 m/s. Details: biomotion.analysis.check."
)


def report_html(
    *,
    title: str,
    subjects: Sequence[dict],
    trials: Sequence[dict],
    settings: dict | None = None,
    source: str = "",
) -> str:
    """The report page as a string (see the module docstring); ``subjects`` are the static outcomes, ``trials``
    the trial outcomes, both as `biomotion.analysis.batch.Outcome.as_dict` gives them."""
    from biomotion.viz.viewer import plotly_js

    counts = {"ok": 0, "warn": 0, "fail": 0}
    for t in trials:
        counts[t.get("verdict", {}).get("verdict", "fail")] += 1
    curves = subject_curves(trials)
    ids, data_curves = {}, {}
    for subject, groups in curves.items():
        for group, entry in groups.items():
            ids[(subject, group)] = f"g{len(ids)}"
            data_curves.setdefault(subject, {})[group] = {**entry, "id": ids[(subject, group)]}
    header = "".join(f"<th>{_esc(c)}</th>" for c in TRIAL_COLUMNS)
    rows = "\n".join(_trial_row(t, k) for k, t in enumerate(trials))
    static_rows = "\n".join(_static_row(s) for s in subjects)
    sections = "\n".join(_subject_section(s, curves.get(s["subject"], {}), ids) for s in subjects)
    settings_text = _esc(json.dumps(settings or {}, sort_keys=True))
    blob = json.dumps({"curves": data_curves}, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{_esc(title)}</title><style>{_STYLE}</style></head>
<body>
<h1>{_esc(title)}</h1>
<p>Study <code>{_esc(source)}</code>: {len(subjects)} subjects, {len(trials)} trials —
<span class="ok">{counts["ok"]} ok</span>, <span class="warn">{counts["warn"]} warn</span>,
<span class="fail">{counts["fail"]} fail</span>.</p>
<p class="small">{_esc(RULES)}</p>
<p class="small">Settings: <code>{settings_text}</code></p>
<h2>Trials</h2>
<table class="sortable" id="trials"><thead><tr>{header}</tr></thead><tbody>
{rows}
</tbody></table>
<h2>Static trials (scaling)</h2>
<table class="sortable" id="statics"><thead><tr><th>subject</th><th>static trial</th><th>verdict</th><th>reasons</th>
<th>mass (kg)</th></tr></thead><tbody>
{static_rows}
</tbody></table>
<h2>Subjects</h2>
<p class="small">Open a subject for its scaling and its plots (mean ± 1 SD over its trials of each activity).</p>
{sections}
<script>{plotly_js()}</script>
<script type="application/json" id="report-data">{blob}</script>
<script>{_SCRIPT}</script>
</body></html>
"""


def write_report(
    path: str | Path,
    *,
    title: str,
    subjects: Sequence[dict],
    trials: Sequence[dict],
    settings: dict | None = None,
    source: str = "",
) -> Path:
    """Write `report_html` to ``path`` atomically; returns the path."""
    path = Path(path)
    with atomic_write(path) as handle:
        handle.write(report_html(title=title, subjects=subjects, trials=trials, settings=settings, source=source))
    return path
