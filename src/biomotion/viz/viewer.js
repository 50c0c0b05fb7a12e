/* biomotion viewer: playback controls and per-frame updates of a Plotly 3D scene.
 *
 * The page holds plotly.js (drawing), a JSON block of typed arrays (see biomotion/viz/viewer.py for the layout)
 * and this script, which only decodes the arrays, poses the meshes of each frame (v' = R v + p from the body's
 * quaternion and origin) and hands new trace data to Plotly.react. window.viewer is the page's API:
 * ready (a promise), nFrames, frame, setFrame(n) (a promise resolved once frame n is drawn), setMode("overlay" |
 * "side") (a promise), play(), pause(),
 * and timings: ms since navigation when this script started (plotly.js parsed), the data were decoded, and the
 * first frame was drawn (ready).
 */
(function () {
  "use strict";

  const STARTED = performance.now();  // plotly.js has been parsed and run by now
  const DATA = JSON.parse(document.getElementById("scene-data").textContent);
  const TYPES = { float32: Float32Array, int32: Int32Array, uint8: Uint8Array };
  const COLORS = {
    main: { bone: "#d8c7a6", points: "#1f5fa8", arrow: "#2a9d3a", com: "#d62728", zmp: "#7b3fb5", support: "#e08a1e" },
    compare: { bone: "#7fa7d9", points: "#c0392b", arrow: "#8fce6a", com: "#ff8a8a", zmp: "#c39be6",
               support: "#f5c27a" },
  };

  function decode(entry) {
    if (entry === null || entry === undefined) return null;
    const text = atob(entry.b64);
    const bytes = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    return new TYPES[entry.dtype](bytes.buffer);
  }

  function decodeScene(raw) {
    if (!raw) return null;
    const scene = { name: raw.name, n: raw.n, centre: decode(raw.centre), frameMap: decode(raw.frame_map) };
    if (raw.bodies) {
      scene.bodies = {
        count: raw.bodies.count, quat: decode(raw.bodies.quat), pos: decode(raw.bodies.pos),
        vertices: decode(raw.bodies.vertices), starts: decode(raw.bodies.starts),
        i: decode(raw.bodies.i), j: decode(raw.bodies.j), k: decode(raw.bodies.k),
      };
    }
    scene.points = raw.points.map((p) => ({ name: p.name, labels: p.labels, count: p.count,
                                            xyz: decode(p.xyz), links: decode(p.links) }));
    scene.arrows = raw.arrows.map((a) => ({ name: a.name, count: a.count, origin: decode(a.origin),
                                            vector: decode(a.vector) }));
    scene.com = decode(raw.com);
    scene.zmp = decode(raw.zmp);
    scene.support = raw.support ? { count: raw.support.count, xyz: decode(raw.support.xyz) } : null;
    scene.activations = raw.activations ? { names: raw.activations.names, values: decode(raw.activations.values) }
                                        : null;
    return scene;
  }

  /* ---- one frame of one scene as Plotly traces ---------------------------------------------------------- */

  function posedMesh(b, f) {
    const nv = b.vertices.length / 3;
    const x = new Float32Array(nv), y = new Float32Array(nv), z = new Float32Array(nv);
    for (let body = 0; body < b.count; body++) {
      const q = 4 * (f * b.count + body), p = 3 * (f * b.count + body);
      const qx = b.quat[q], qy = b.quat[q + 1], qz = b.quat[q + 2], qw = b.quat[q + 3];
      const px = b.pos[p], py = b.pos[p + 1], pz = b.pos[p + 2];
      const r00 = 1 - 2 * (qy * qy + qz * qz), r01 = 2 * (qx * qy - qz * qw), r02 = 2 * (qx * qz + qy * qw);
      const r10 = 2 * (qx * qy + qz * qw), r11 = 1 - 2 * (qx * qx + qz * qz), r12 = 2 * (qy * qz - qx * qw);
      const r20 = 2 * (qx * qz - qy * qw), r21 = 2 * (qy * qz + qx * qw), r22 = 1 - 2 * (qx * qx + qy * qy);
      for (let v = b.starts[body]; v < b.starts[body + 1]; v++) {
        const vx = b.vertices[3 * v], vy = b.vertices[3 * v + 1], vz = b.vertices[3 * v + 2];
        x[v] = r00 * vx + r01 * vy + r02 * vz + px;
        y[v] = r10 * vx + r11 * vy + r12 * vz + py;
        z[v] = r20 * vx + r21 * vy + r22 * vz + pz;
      }
    }
    return { x: x, y: y, z: z };
  }

  // Planar per-frame blocks [T, 3, K]: x, y, z of frame f are three contiguous runs of K values.
  function planar(array, count, f) {
    const base = 3 * count * f;
    return { x: array.subarray(base, base + count), y: array.subarray(base + count, base + 2 * count),
             z: array.subarray(base + 2 * count, base + 3 * count) };
  }

  // Line segments a-b separated by gaps (NaN), as one scatter3d "lines" trace.
  function segments(count, ends) {
    const x = new Float32Array(3 * count), y = new Float32Array(3 * count), z = new Float32Array(3 * count);
    for (let s = 0; s < count; s++) {
      const [a, b] = ends(s);
      x[3 * s] = a[0]; y[3 * s] = a[1]; z[3 * s] = a[2];
      x[3 * s + 1] = b[0]; y[3 * s + 1] = b[1]; z[3 * s + 1] = b[2];
      x[3 * s + 2] = NaN; y[3 * s + 2] = NaN; z[3 * s + 2] = NaN;
    }
    return { x: x, y: y, z: z };
  }

  function frameTraces(scene, f, role, sceneId) {
    const c = COLORS[role], label = role === "compare" ? " (" + scene.name + ")" : "", traces = [];
    const common = { scene: sceneId, legendgroup: role, hoverinfo: "skip" };
    if (scene.bodies) {
      const m = posedMesh(scene.bodies, f);
      traces.push(Object.assign({ type: "mesh3d", name: "bones" + label, x: m.x, y: m.y, z: m.z,
        i: scene.bodies.i, j: scene.bodies.j, k: scene.bodies.k, color: c.bone, flatshading: false,
        opacity: role === "compare" && state.mode === "overlay" ? 0.55 : 1.0, showlegend: true,
        lighting: { ambient: 0.55, diffuse: 0.8, specular: 0.15, roughness: 0.6 } }, common));
    }
    for (const set of scene.points) {
      const p = planar(set.xyz, set.count, f);
      traces.push(Object.assign({ type: "scatter3d", mode: "markers", name: set.name + label, x: p.x, y: p.y,
        z: p.z, text: set.labels, marker: { size: scene.bodies ? 2.5 : 3.5, color: c.points } },
        common, { hoverinfo: "text" }));  // marker names on hover
      const links = set.links.length / 2;
      if (links) {
        const s = segments(links, (l) => {
          const a = set.links[2 * l], b = set.links[2 * l + 1];
          return [[p.x[a], p.y[a], p.z[a]], [p.x[b], p.y[b], p.z[b]]];
        });
        traces.push(Object.assign({ type: "scatter3d", mode: "lines", name: set.name + " links" + label,
          x: s.x, y: s.y, z: s.z, line: { color: c.points, width: 4 }, showlegend: false }, common));
      }
    }
    for (const arrows of scene.arrows) {
      const o = planar(arrows.origin, arrows.count, f), v = planar(arrows.vector, arrows.count, f);
      const s = segments(arrows.count, (a) => [[o.x[a], o.y[a], o.z[a]],
                                                [o.x[a] + v.x[a], o.y[a] + v.y[a], o.z[a] + v.z[a]]]);
      const heads = new Array(3 * arrows.count).fill(0).map((_, n) => (n % 3 === 1 ? 5 : 0));  // a mark at tips
      traces.push(Object.assign({ type: "scatter3d", mode: "lines+markers", name: arrows.name + label, x: s.x,
        y: s.y, z: s.z, line: { color: c.arrow, width: 7 },
        marker: { size: heads, symbol: "diamond", color: c.arrow, line: { width: 0 } } }, common));
    }
    if (scene.support) {
      const p = planar(scene.support.xyz, scene.support.count, f), loop = { x: [], y: [], z: [] };
      for (let v = 0; v < scene.support.count; v++) {
        if (isFinite(p.x[v])) { loop.x.push(p.x[v]); loop.y.push(p.y[v]); loop.z.push(p.z[v]); }
      }
      if (loop.x.length) { loop.x.push(loop.x[0]); loop.y.push(loop.y[0]); loop.z.push(loop.z[0]); }
      traces.push(Object.assign({ type: "scatter3d", mode: "lines", name: "support polygon" + label, x: loop.x,
        y: loop.y, z: loop.z, line: { color: c.support, width: 5 } }, common));
    }
    for (const [key, symbol, name] of [["com", "circle", "COM"], ["zmp", "x", "ZMP"]]) {
      const a = scene[key];
      if (!a) continue;
      const x = a[3 * f], y = a[3 * f + 1], z = a[3 * f + 2];
      const trace = { type: "scatter3d", mode: key === "com" ? "lines+markers" : "markers", name: name + label,
        x: key === "com" ? [x, x] : [x], y: key === "com" ? [y, 0] : [y], z: key === "com" ? [z, z] : [z],
        marker: { size: key === "com" ? [7, 3] : 6, symbol: symbol, color: c[key] },
        line: { color: c[key], width: 2, dash: "dash" } };
      traces.push(Object.assign(trace, common));
    }
    return traces;
  }

  /* ---- static parts: ground, axes, layout ---------------------------------------------------------------- */

  function groundTraces(sceneId) {  // a checkerboard of GRID_STEP tiles on y = 0, as one mesh
    const g = DATA.ground, nx = Math.round((g.x[1] - g.x[0]) / g.step), nz = Math.round((g.z[1] - g.z[0]) / g.step);
    const x = [], y = [], z = [], i = [], j = [], k = [], facecolor = [];
    for (let a = 0; a <= nx; a++) {
      for (let b = 0; b <= nz; b++) { x.push(g.x[0] + a * g.step); y.push(0); z.push(g.z[0] + b * g.step); }
    }
    for (let a = 0; a < nx; a++) {
      for (let b = 0; b < nz; b++) {
        const v = a * (nz + 1) + b, color = (a + b) % 2 ? "#e2e5e9" : "#eef0f3";
        i.push(v, v); j.push(v + nz + 1, v + nz + 2); k.push(v + nz + 2, v + 1); facecolor.push(color, color);
      }
    }
    return [{ type: "mesh3d", name: "ground", scene: sceneId, x: x, y: y, z: z, i: i, j: j, k: k,
              facecolor: facecolor, hoverinfo: "skip", showlegend: false,
              lighting: { ambient: 1, diffuse: 0, specular: 0, fresnel: 0 } }];
  }

  function axisRanges(scene, f) {
    const b = DATA.bounds, h = DATA.follow_half;
    if (!state.follow) return { x: [b.lo[0], b.hi[0]], y: [b.lo[1], b.hi[1]], z: [b.lo[2], b.hi[2]] };
    const cx = scene.centre[3 * f], cz = scene.centre[3 * f + 2];
    return { x: [cx - h, cx + h], y: [b.lo[1], b.hi[1]], z: [cz - h, cz + h] };
  }

  function sceneLayout(ranges) {
    const span = ["x", "y", "z"].map((a) => ranges[a][1] - ranges[a][0]), big = Math.max.apply(null, span);
    // axes hidden: the ground tiles (0.5 m) give the scale, and tick text would be rebuilt on every followed frame
    const axis = (a) => ({ range: ranges[a], visible: false, autorange: false, showspikes: false });
    return {
      xaxis: axis("x"), yaxis: axis("y"), zaxis: axis("z"), aspectmode: "manual",
      aspectratio: { x: span[0] / big, y: span[1] / big, z: span[2] / big },
      camera: state.camera || { up: { x: 0, y: 1, z: 0 }, eye: { x: 0.6, y: 0.4, z: 1.15 },
                                center: { x: 0, y: -0.05, z: 0 } },
    };
  }

  /* ---- views (one Plotly div each) ------------------------------------------------------------------------ */

  const state = { frame: 0, playing: false, speed: 1, follow: DATA.follow, mode: DATA.mode, camera: null,
                  views: [], drawing: null, wanted: 0, drawn: -1, syncing: false };
  const MAIN = decodeScene(DATA.main), COMPARE = decodeScene(DATA.compare);
  const DECODED = performance.now();
  const TIMES = decode(DATA.times);
  const N = TIMES.length;

  function viewTraces(view, f) {
    let traces = groundTraces("scene");
    for (const [scene, role] of view.scenes) {
      const g = role === "compare" ? scene.frameMap[f] : f;
      traces = traces.concat(frameTraces(scene, g, role, "scene"));
    }
    return traces;
  }

  function viewLayout(view, f) {
    const [scene, role] = view.scenes[0];
    const layout = { scene: sceneLayout(axisRanges(scene, role === "compare" ? scene.frameMap[f] : f)),
                     margin: { l: 0, r: 0, t: 0, b: 0 }, uirevision: "keep", showlegend: true,
                     legend: { x: 0.01, y: 0.02, bgcolor: "rgba(255,255,255,0.7)" }, paper_bgcolor: "#fafafa" };
    return layout;
  }

  const CONFIG = { displaylogo: false, responsive: true, showLink: false, showSendToCloud: false,
                   modeBarButtonsToRemove: ["sendDataToCloud"] };

  function buildViews() {
    const host = document.getElementById("views");
    for (const view of state.views) Plotly.purge(view.div);
    host.innerHTML = "";
    const groups = !COMPARE ? [[[MAIN, "main"]]]
      : state.mode === "side" ? [[[MAIN, "main"]], [[COMPARE, "compare"]]]
      : [[[MAIN, "main"], [COMPARE, "compare"]]];
    state.views = groups.map((scenes) => {
      const div = document.createElement("div");
      div.className = "view";
      const caption = document.createElement("div");
      caption.className = "caption";
      caption.textContent = scenes.map(([s]) => s.name).join(" vs ");
      const plot = document.createElement("div");
      plot.style.width = "100%";
      plot.style.height = "100%";
      div.appendChild(caption);
      div.appendChild(plot);
      host.appendChild(div);
      return { div: plot, scenes: scenes };
    });
    const f = state.frame;
    const work = state.views.map((view) =>
      Plotly.newPlot(view.div, viewTraces(view, f), viewLayout(view, f), CONFIG)
        .then(() => view.div.on("plotly_relayout", (event) => syncCamera(view, event))));
    if (ACT) work.push(Plotly.react("activations", activationTrace(f), ACT_LAYOUT, { displayModeBar: false }));
    return Promise.all(work).then(painted).then(() => {
      state.drawn = f;
      if (state.wanted !== f && !state.drawing) startDrawing();
    });
  }

  function painted() {  // resolves once the browser has painted what was just drawn
    return new Promise((resolve) => requestAnimationFrame(() => requestAnimationFrame(resolve)));
  }

  function syncCamera(source, event) {  // side by side: the other view follows the one the user turned
    const camera = event["scene.camera"];
    if (!camera || state.syncing) return;  // ignore the echo of our own relayout
    state.camera = camera;
    state.syncing = true;
    const others = state.views.filter((view) => view !== source);
    Promise.all(others.map((view) => Plotly.relayout(view.div, { "scene.camera": camera })))
      .finally(() => { state.syncing = false; });
  }

  /* ---- activation bars ------------------------------------------------------------------------------------ */

  const ACT = MAIN.activations;
  const ACTIVATION_SCALE = [[0, "#ffffcc"], [0.25, "#fed976"], [0.5, "#fd8d3c"], [0.75, "#e31a1c"], [1, "#800026"]];
  function activationTrace(f) {
    const m = ACT.names.length, y = new Array(m);
    for (let k = 0; k < m; k++) {
      const v = ACT.values[f * m + k];
      y[k] = v === 255 ? null : v / 254;
    }
    return [{ type: "bar", orientation: "h", x: y, y: ACT.names, hoverinfo: "x+y",
              marker: { color: y.map((v) => (v === null ? 0 : v)), colorscale: ACTIVATION_SCALE, cmin: 0, cmax: 1,
                        line: { width: 0 } } }];
  }
  const ACT_LAYOUT = { margin: { l: 110, r: 10, t: 30, b: 30 },
                       title: { text: "muscle activation", font: { size: 13 } },
                       xaxis: { range: [0, 1], fixedrange: true }, bargap: 0.15,
                       yaxis: { autorange: "reversed", fixedrange: true, tickfont: { size: 9 }, automargin: true },
                       paper_bgcolor: "#fff", plot_bgcolor: "#fff" };

  /* ---- frames and playback -------------------------------------------------------------------------------- */

  const scrubber = document.getElementById("scrubber"), clock = document.getElementById("clock");
  const playButton = document.getElementById("play");

  function drawFrame(f) {
    const work = state.views.map((view) => Plotly.react(view.div, viewTraces(view, f), viewLayout(view, f), CONFIG));
    if (ACT) work.push(Plotly.react("activations", activationTrace(f), ACT_LAYOUT, { displayModeBar: false }));
    return Promise.all(work).then(painted);
  }

  async function drawLoop() {
    while (state.drawn !== state.wanted) {
      const f = state.wanted;
      await drawFrame(f);
      state.drawn = f;
    }
  }

  function startDrawing() {
    state.drawing = drawLoop().finally(() => {
      state.drawing = null;
      if (state.drawn !== state.wanted) startDrawing();  // a frame asked for while the loop was closing
    });
  }

  function showFrame(f) {
    state.frame = state.wanted = f;
    scrubber.value = String(f);
    clock.textContent = "t = " + TIMES[f].toFixed(2) + " s  (" + (f + 1) + "/" + N + ")";
  }

  function setFrame(n) {
    showFrame(Math.max(0, Math.min(N - 1, Math.round(Number(n) || 0))));
    if (!state.drawing) startDrawing();
    return state.drawing;
  }

  function frameAt(t) {  // last frame at or before time t
    let lo = 0, hi = N - 1;
    while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (TIMES[mid] <= t) lo = mid; else hi = mid - 1; }
    return lo;
  }

  let origin = null;
  function tick(now) {
    if (!state.playing) return;
    if (origin === null) origin = { wall: now, time: TIMES[state.frame] };
    let t = origin.time + (now - origin.wall) / 1000 * state.speed;
    if (t > TIMES[N - 1]) { origin = { wall: now, time: TIMES[0] }; t = TIMES[0]; }
    if (!state.drawing) setFrame(frameAt(t));
    requestAnimationFrame(tick);
  }

  function play() {
    if (state.playing || N < 2) return;
    state.playing = true;
    origin = null;
    playButton.textContent = "Pause";
    requestAnimationFrame(tick);
  }

  function pause() {
    state.playing = false;
    playButton.textContent = "Play";
  }

  /* ---- start ---------------------------------------------------------------------------------------------- */

  scrubber.max = String(N - 1);
  playButton.addEventListener("click", () => (state.playing ? pause() : play()));
  scrubber.addEventListener("input", () => { pause(); setFrame(scrubber.value); });
  document.getElementById("speed").addEventListener("change", (e) => {
    state.speed = Number(e.target.value);
    origin = null;
  });
  const followBox = document.getElementById("follow");
  followBox.checked = state.follow;
  followBox.addEventListener("change", () => {
    state.follow = followBox.checked;
    state.drawn = -1;
    setFrame(state.frame);
  });
  const modeSelect = document.getElementById("mode");
  if (!COMPARE) document.getElementById("mode-label").style.display = "none";
  modeSelect.value = state.mode;
  function setMode(mode) {  // "overlay" or "side"; resolves once the views are rebuilt and drawn
    if (mode !== "overlay" && mode !== "side") throw new Error("compare mode must be overlay or side: " + mode);
    state.mode = modeSelect.value = mode;
    return buildViews();
  }
  modeSelect.addEventListener("change", () => setMode(modeSelect.value));
  document.addEventListener("keydown", (e) => {
    if (e.target.tagName === "SELECT" || e.target.tagName === "INPUT" && e.target.type !== "range") return;
    if (e.key === " ") { e.preventDefault(); state.playing ? pause() : play(); }
    if (e.key === "ArrowRight") { pause(); setFrame(state.frame + 1); }
    if (e.key === "ArrowLeft") { pause(); setFrame(state.frame - 1); }
  });
  if (ACT) document.getElementById("side").classList.add("shown");

  const timings = { script: STARTED, decoded: DECODED };
  showFrame(0);
  const ready = buildViews().then(() => {
    timings.ready = performance.now();
    return true;
  });

  window.viewer = {
    ready: ready, nFrames: N, times: TIMES, timings: timings,
    get frame() { return state.frame; },
    get drawnFrame() { return state.drawn; },
    setFrame: setFrame, setMode: setMode, play: play, pause: pause,
    traceCount: () => state.views.map((v) => v.div.data.length),
  };
})();
