// physdyn viewer: poses each scene's mesh at the step under the slider (plotly.js draws).
// Data: the JSON block #physdyn-data, written by physdyn/viz/viewer.py (its docstring gives the layout).
(function () {
  "use strict";
  const DATA = JSON.parse(document.getElementById("physdyn-data").textContent);
  const COLOURS = { predicted: "#4682b4", reference: "#d9732e", ground: "#c8c8c8", fan: "#7b68ee" };
  const view3d = document.getElementById("view3d");
  const plot2d = document.getElementById("plot2d");
  const slider = document.getElementById("slider");
  const playButton = document.getElementById("play");
  const readout = document.getElementById("readout");
  const select = document.getElementById("scene");
  let scene = null;
  let step = 0;
  let timer = null;

  function matrix(q) {
    const [x, y, z, w] = q;
    return [
      [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ];
  }

  // The last recorded step stands for any later time: a trajectory that stopped stays where it stopped.
  function at(traj, t) {
    return Math.min(t, traj.com_position.length - 1);
  }

  // A mesh vertex v is drawn at R (v - com_mesh) + com_position (docs/conventions.md).
  function posed(traj, t) {
    const k = at(traj, t);
    const R = matrix(traj.orientation_xyzw[k]);
    const p = traj.com_position[k];
    const c = scene.com_mesh;
    const xs = [], ys = [], zs = [];
    for (const v of scene.mesh.vertices) {
      const a = v[0] - c[0], b = v[1] - c[1], d = v[2] - c[2];
      xs.push(R[0][0] * a + R[0][1] * b + R[0][2] * d + p[0]);
      ys.push(R[1][0] * a + R[1][1] * b + R[1][2] * d + p[1]);
      zs.push(R[2][0] * a + R[2][1] * b + R[2][2] * d + p[2]);
    }
    return [xs, ys, zs];
  }

  function trail(traj, t) {
    const upto = traj.com_position.slice(0, at(traj, t) + 1);
    return [upto.map((p) => p[0]), upto.map((p) => p[1]), upto.map((p) => p[2])];
  }

  function steps() {
    const lengths = [scene.predicted.com_position.length];
    if (scene.reference) lengths.push(scene.reference.com_position.length);
    return Math.max(...lengths);
  }

  // Errors of the prediction against the reference at step t: centre-of-mass distance (m) and the angle
  // of R_pred R_ref^T (deg).
  function errors(t) {
    if (!scene.reference) return null;
    const a = scene.predicted, b = scene.reference;
    const p = a.com_position[at(a, t)], r = b.com_position[at(b, t)];
    const dist = Math.hypot(p[0] - r[0], p[1] - r[1], p[2] - r[2]);
    const q = a.orientation_xyzw[at(a, t)], s = b.orientation_xyzw[at(b, t)];
    const dot = Math.min(1, Math.abs(q[0] * s[0] + q[1] * s[1] + q[2] * s[2] + q[3] * s[3]));
    return { position: dist, angle: (2 * Math.acos(dot) * 180) / Math.PI };
  }

  // The plots' heights follow the window (share of its height, at least `least` pixels).
  function fit(div, share, least) {
    const h = Math.max(least, Math.round(window.innerHeight * share));
    div.style.height = h + "px";
    return h;
  }

  function meshTrace(name, colour, opacity, vertices) {
    const f = scene.mesh.faces;
    return {
      type: "mesh3d", name: name, x: vertices[0], y: vertices[1], z: vertices[2],
      i: f.map((x) => x[0]), j: f.map((x) => x[1]), k: f.map((x) => x[2]),
      color: colour, opacity: opacity, flatshading: true, hoverinfo: "name", showlegend: false,
      lighting: { ambient: 0.55, diffuse: 0.7, specular: 0.1 },
    };
  }

  function lineTrace(name, colour, dash, xyz) {
    return { type: "scatter3d", mode: "lines", name: name, x: xyz[0], y: xyz[1], z: xyz[2],
             line: { color: colour, width: 5, dash: dash }, hoverinfo: "name", showlegend: false };
  }

  // A distribution's fan: every sample's final pose as one translucent mesh (its vertices and faces repeated
  // per sample) and every sample's path as one line broken by gaps. Static: the slider moves the central sample.
  function fanTraces() {
    const fan = scene.fan;
    if (!fan) return [];
    const nv = scene.mesh.vertices.length;
    const xs = [], ys = [], zs = [], fi = [], fj = [], fk = [];
    const px = [], py = [], pz = [];
    fan.com_position.forEach((path, s) => {
      const pose = posed({ com_position: path, orientation_xyzw: fan.orientation_xyzw[s] }, path.length - 1);
      xs.push(...pose[0]); ys.push(...pose[1]); zs.push(...pose[2]);
      for (const f of scene.mesh.faces) { fi.push(f[0] + s * nv); fj.push(f[1] + s * nv); fk.push(f[2] + s * nv); }
      for (const p of path) { px.push(p[0]); py.push(p[1]); pz.push(p[2]); }
      px.push(null); py.push(null); pz.push(null);
    });
    return [
      { type: "mesh3d", name: "sampled final poses", x: xs, y: ys, z: zs, i: fi, j: fj, k: fk, color: COLOURS.fan,
        opacity: 0.15, flatshading: true, hoverinfo: "name", showlegend: false },
      { type: "scatter3d", mode: "lines", name: "sampled paths", x: px, y: py, z: pz,
        line: { color: COLOURS.fan, width: 2 }, opacity: 0.4, hoverinfo: "name", showlegend: false },
    ];
  }

  function draw3d() {
    const lo = scene.bounds.lo, hi = scene.bounds.hi;
    const ground = {
      type: "mesh3d", name: "ground", x: [lo[0], hi[0], hi[0], lo[0]], y: [lo[1], lo[1], hi[1], hi[1]],
      z: [0, 0, 0, 0], i: [0, 0], j: [1, 2], k: [2, 3], color: COLOURS.ground, opacity: 0.6,
      hoverinfo: "skip", showlegend: false,
    };
    const ref = scene.reference;
    const traces = [
      ground,
      meshTrace(ref ? ref.label : "reference", COLOURS.reference, ref ? 0.3 : 0, ref ? posed(ref, 0) : [[], [], []]),
      meshTrace(scene.predicted.label, COLOURS.predicted, 1.0, posed(scene.predicted, 0)),
      lineTrace((ref ? ref.label : "reference") + " path", COLOURS.reference, "dash", ref ? trail(ref, 0) : [[], [], []]),
      lineTrace(scene.predicted.label + " path", COLOURS.predicted, "solid", trail(scene.predicted, 0)),
      ...fanTraces(),  // after the four traces show() restyles
    ];
    const axis = (a, title) => ({ range: [lo[a], hi[a]], title: title, autorange: false });
    const layout = {
      margin: { l: 0, r: 0, t: 0, b: 0 },
      height: fit(view3d, 0.6, 320),
      uirevision: "keep",  // keep the user's camera when the pose changes
      scene: {
        xaxis: axis(0, "x (m)"), yaxis: axis(1, "y (m)"), zaxis: axis(2, "z (m)"),
        aspectmode: "cube", camera: { eye: { x: 1.5, y: -1.8, z: 1.0 } },
      },
    };
    return Plotly.react(view3d, traces, layout, { responsive: true, displaylogo: false });
  }

  function draw2d() {
    const n = steps();
    const time = Array.from({ length: n }, (_, t) => t / scene.rate_hz);
    const traces = [];
    const prob = scene.predicted.topple_probability;
    if (prob) {
      traces.push({ x: time.slice(0, prob.length), y: prob, name: scene.fan ? "topple probability (of the samples)" : "topple probability", mode: "lines",
                    line: { color: COLOURS.predicted } });
    }
    if (scene.reference) {
      traces.push({ x: time, y: time.map((_, t) => 100 * errors(t).position), name: "position error (cm)",
                    mode: "lines", yaxis: "y2", line: { color: "#b22222" } });
      traces.push({ x: time, y: time.map((_, t) => errors(t).angle), name: "rotation error (deg)",
                    mode: "lines", yaxis: "y3", line: { color: "#777", dash: "dot" } });
    }
    const layout = {
      margin: { l: 50, r: 110, t: 30, b: 35 },
      height: fit(plot2d, 0.25, 170),
      xaxis: { title: "time (s)", range: [0, time[n - 1] || 1], domain: [0, 0.9] },
      yaxis: { title: "topple p", range: [0, 1] },
      yaxis2: { title: "cm", overlaying: "y", side: "right", rangemode: "tozero" },
      yaxis3: { title: "deg", overlaying: "y", side: "right", anchor: "free", position: 0.97, rangemode: "tozero" },
      legend: { orientation: "h", x: 0, y: 1.02, yanchor: "bottom" },
      shapes: [{ type: "line", xref: "x", yref: "paper", x0: 0, x1: 0, y0: 0, y1: 1, line: { color: "#000", width: 1 } }],
      annotations: prob ? [] : [{ text: "this model has no topple head", xref: "paper", yref: "paper", x: 0.02, y: 0.9, showarrow: false }],
    };
    return Plotly.react(plot2d, traces, layout, { responsive: true, displaylogo: false }).then(() => {
      plot2d.removeAllListeners && plot2d.removeAllListeners("plotly_click");
      plot2d.on("plotly_click", (ev) => { if (ev.points.length) show(Math.round(ev.points[0].x * scene.rate_hz)); });
    });
  }

  function show(t) {
    step = Math.max(0, Math.min(t, steps() - 1));
    slider.value = String(step);
    const ref = scene.reference;
    const pred = posed(scene.predicted, step);
    const refPose = ref ? posed(ref, step) : [[], [], []];
    const predTrail = trail(scene.predicted, step);
    const refTrail = ref ? trail(ref, step) : [[], [], []];
    Plotly.restyle(view3d, {
      x: [refPose[0], pred[0], refTrail[0], predTrail[0]],
      y: [refPose[1], pred[1], refTrail[1], predTrail[1]],
      z: [refPose[2], pred[2], refTrail[2], predTrail[2]],
    }, [1, 2, 3, 4]);
    const time = step / scene.rate_hz;
    Plotly.relayout(plot2d, { "shapes[0].x0": time, "shapes[0].x1": time });
    const parts = [`t = ${time.toFixed(2)} s (step ${step})`];
    const prob = scene.predicted.topple_probability;
    if (prob) parts.push(`topple p ${prob[at(scene.predicted, step)].toFixed(2)}`);
    const e = errors(step);
    if (e) parts.push(`error: position ${(100 * e.position).toFixed(2)} cm, rotation ${e.angle.toFixed(1)}\u00b0`);
    readout.textContent = parts.join(" \u00b7 ");
  }

  function play() {
    if (timer) { stop(); return; }
    if (step >= steps() - 1) show(0);
    playButton.textContent = "Pause";
    timer = setInterval(() => {
      if (step >= steps() - 1) { stop(); return; }
      show(step + 1);
    }, 1000 / scene.rate_hz);
  }

  function stop() {
    clearInterval(timer);
    timer = null;
    playButton.textContent = "Play";
  }

  function load(index) {
    stop();
    scene = DATA.scenes[index];
    slider.max = String(steps() - 1);
    const ref = scene.reference;
    const topples = (traj) => (traj.toppled === null ? "" : traj.toppled ? " (topples)" : " (stays up)");
    document.getElementById("legend").innerHTML =
      `<span class="swatch" style="background:${COLOURS.predicted}"></span>${scene.predicted.label}${topples(scene.predicted)}` +
      (ref ? `<span class="swatch" style="background:${COLOURS.reference};opacity:0.5"></span>${ref.label}${topples(ref)}, ghosted` : "") +
      (scene.fan ? `<span class="swatch" style="background:${COLOURS.fan};opacity:0.4"></span>${scene.fan.com_position.length} sampled final poses` : "");
    document.getElementById("notes").textContent = scene.notes.join(" ");
    return Promise.all([draw3d(), draw2d()]).then(() => show(0));
  }

  DATA.scenes.forEach((s, i) => {
    const option = document.createElement("option");
    option.value = String(i);
    option.textContent = s.title;
    select.appendChild(option);
  });
  select.disabled = DATA.scenes.length < 2;
  select.addEventListener("change", () => load(Number(select.value)));
  slider.addEventListener("input", () => { stop(); show(Number(slider.value)); });
  playButton.addEventListener("click", play);
  document.addEventListener("keydown", (ev) => {
    if (ev.target.tagName === "SELECT") return;
    if (ev.key === " ") { ev.preventDefault(); play(); }
    if (ev.key === "ArrowRight") { stop(); show(step + 1); }
    if (ev.key === "ArrowLeft") { stop(); show(step - 1); }
  });
  // A link can open a scene at a step: viewer.html#scene=2&step=10 (both counted from 0).
  const wanted = new URLSearchParams(window.location.hash.slice(1));
  const first = Math.min(Math.max(0, Number(wanted.get("scene")) || 0), DATA.scenes.length - 1);
  select.value = String(first);
  load(first).then(() => {
    if (wanted.has("step")) show(Number(wanted.get("step")) || 0);
    document.body.setAttribute("data-ready", "1");
  });
})();
