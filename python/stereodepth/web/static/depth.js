// The depth-map view: a stereo pair to disparity, depth and a point cloud via /api/depthmap.
// Every number comes from the library: the disparity, depth and confidence maps arrive as the
// raw float32 arrays, the 3-D points of pinned pixels from /api/depthmap/{id}/point.
"use strict";

(function () {
  const $ = (id) => document.getElementById(id);
  const FIELDS = ["left", "right", "calib", "method", "num_disparities", "block_size"];
  let limits = null;       // /api/depthmap/limits
  let result = null;       // the last answer, with its arrays decoded
  let pins = [];           // pinned pixels, with the server's numbers
  let busy = false;
  let centre = null;       // the principal point of an uploaded calib.txt
  let calibSize = null;    // [width, height] of the images that calib.txt describes
  let calibName = null;    // that file's name; null: no calibration in use
  let calibLoads = 0;      // answers for an earlier choice of file are dropped
  const CALIB_NOTE = "Middlebury calib.txt";

  // --- numbers -----------------------------------------------------------------------------
  // The shortest decimal that reads back as the same float32: numpy's repr of a float32. Of
  // two equally near (the value exactly halfway), the even one, as numpy (233.015625:
  // 233.01562), else the one that reads back.
  function f32(v) {
    if (v === null || v === undefined || Number.isNaN(v)) return "—";
    if (!Number.isFinite(v)) return v > 0 ? "∞" : "−∞";
    for (let p = 1; p <= 9; p++) {
      for (const s of [window.stereodepth.toExponentialEven(v, p - 1), v.toExponential(p - 1)]) {
        if (Math.fround(Number(s)) === v) return String(Number(s));
      }
    }
    return String(v);
  }
  const g = (v, digits) => window.stereodepth.formatG(v, digits);

  function decode(b64) {
    if (!b64) return null;
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Float32Array(bytes.buffer);  // little-endian, as every browser's CPU
  }

  // --- tabs --------------------------------------------------------------------------------
  function showTab(which) {
    for (const [tab, view] of [["tab-calc", "view-calc"], ["tab-depth", "view-depth"]]) {
      const on = view === `view-${which}`;
      $(tab).setAttribute("aria-selected", String(on));
      $(view).hidden = !on;
    }
    if (which === "depth" && result && window.Plotly) window.Plotly.Plots.resize("cloud");
  }

  // --- messages at the fields ----------------------------------------------------------------
  function clearFieldErrors() {
    for (const name of FIELDS) {
      const box = $(`${name}-error`);
      if (box) { box.hidden = true; box.textContent = ""; }
      const field = document.querySelector(`.field[data-field="${name}"]`);
      if (field) field.classList.remove("invalid");
    }
  }

  function fieldError(name, msg) {
    const box = $(`${name}-error`);
    if (!box) return false;
    box.textContent = box.textContent ? `${box.textContent} ${msg}` : msg;
    box.hidden = false;
    document.querySelector(`.field[data-field="${name}"]`).classList.add("invalid");
    return true;
  }

  function setStatus(kind, text) {
    const s = $("depth-status");
    s.className = `status ${kind}`;
    s.textContent = text;
  }

  // An answer's errors: at the pair's fields, at the rig's inputs, else in the status line.
  function showDetail(detail) {
    const rig = [];
    const general = [];
    for (const item of detail) {
      const loc = Array.isArray(item.loc) ? item.loc : [];
      if (loc[1] === "rig" && loc.length > 2) rig.push({ loc: ["query", loc[2]], msg: item.msg, type: item.type });
      else if (loc[1] === "rig") general.push(`The rig: ${item.msg}`);
      else if (!(loc.length > 1 && fieldError(loc[1], item.msg))) general.push(item.msg);
    }
    if (rig.length) general.push(...window.stereodepth.showRigErrors(rig));
    const where = rig.length ? " Check the marked inputs (the rig is on the left)." : " Check the marked inputs.";
    setStatus("stale", `Not computed.${where}${general.length ? " " + general.join(" ") : ""}`);
  }

  // --- files -------------------------------------------------------------------------------
  function readAs(file, how) {
    return new Promise((resolve, reject) => {
      const reader = new FileReader();
      reader.onload = () => resolve(reader.result);
      reader.onerror = () => reject(reader.error);
      if (how === "text") reader.readAsText(file); else reader.readAsDataURL(file);
    });
  }

  function checkSize(name) {
    const file = $(`${name}-file`).files[0];
    const box = $(`${name}-error`);
    box.hidden = true;
    box.textContent = "";
    document.querySelector(`.field[data-field="${name}"]`).classList.remove("invalid");
    if (file && limits && file.size > limits.max_upload_bytes) {
      fieldError(name, `${name}: the file is ${g(file.size / 1e6, 3)} MB, more than the limit of ${g(limits.max_upload_bytes / 1e6, 3)} MB`);
      return false;
    }
    return true;
  }

  // Forgets the calib.txt in use: its principal point and image size are sent no more (the
  // rig inputs stay as they are, as if typed). `note`: what the note says instead.
  function dropCalib(note) {
    centre = null;
    calibSize = null;
    calibName = null;
    $("calib-note").textContent = note;
  }

  // A new choice of file drops the calibration in use first: a file removed (the chooser's
  // Cancel empties it), or one that fails to load, left the earlier file's principal point
  // and image size in every request, and its note.
  async function loadCalib() {
    const mine = ++calibLoads;
    const file = $("calib-file").files[0];
    $("calib-error").hidden = true;
    $("calib-error").textContent = "";
    document.querySelector('.field[data-field="calib"]').classList.remove("invalid");
    const before = calibName;
    const unused = before ? `${before} is no longer used (the rig inputs stay as they are)` : "";
    if (!file) {
      dropCalib(before ? `No calibration: ${before} removed; its principal point and image size are no longer used (the rig inputs stay as they are).` : CALIB_NOTE);
      return;
    }
    dropCalib(`Reading ${file.name}…`);
    const failed = (msgs) => {
      if (mine !== calibLoads) return;
      dropCalib(`No calibration: ${file.name} was not loaded${unused ? `; ${unused}` : ""}.`);
      for (const msg of msgs) fieldError("calib", msg);
    };
    let text;
    try {
      text = await readAs(file, "text");
    } catch (err) {
      failed([`calib: ${file.name} could not be read (${err && err.name ? err.name : err})`]);
      return;
    }
    let response;
    let body = null;
    try {
      response = await fetch("/api/calib", {
        method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ calib: text }),
      });
      try { body = await response.json(); } catch (err) { body = null; }
    } catch (err) {
      failed([`calib: ${file.name} could not be sent: the server does not answer`]);
      return;
    }
    if (mine !== calibLoads) return;  // another file was chosen meanwhile
    if (!response.ok || !body) {
      const detail = body && Array.isArray(body.detail) ? body.detail.map((item) => item.msg) : [];
      failed(detail.length ? detail : [`calib: the server answered ${response.status} for ${file.name}`]);
      return;
    }
    window.stereodepth.setRig({
      baseline_mm: body.baseline_mm, focal_px: body.focal_px, doffs_px: body.doffs_px,
      width_px: body.width_px === null ? undefined : body.width_px,
    });
    if (body.ndisp) $("num_disparities").value = String(body.ndisp);
    centre = { cx_px: body.cx_px, cy_px: body.cy_px };
    calibSize = body.width_px && body.height_px ? [body.width_px, body.height_px] : null;
    calibName = file.name;
    $("calib-note").textContent = `Rig from ${file.name}: f = ${g(body.focal_px)} px, B = ${g(body.baseline_mm)} mm, doffs = ${g(body.doffs_px)} px` +
      (body.ndisp ? `, ndisp = ${body.ndisp}` : "");
  }

  // --- running -----------------------------------------------------------------------------
  async function run(sample) {
    if (busy) return;
    clearFieldErrors();
    const method = $("method").value;
    const request = {
      rig: window.stereodepth.rigValues(),
      method,
      num_disparities: $("num_disparities").value.trim() || null,
      block_size: $("block_size").value.trim() || null,
      // Block matching's cost only: semi-global matching takes none (and refuses one).
      cost: method === "bm" ? $("cost").value : null,
      disparity_step_px: $("disparity_step_px").value.trim() || null,
    };
    if (centre && !sample) Object.assign(request, centre);
    if (calibSize && !sample) request.calib_size = calibSize;
    if (sample) {
      request.sample = true;
    } else {
      const missing = ["left", "right"].filter((n) => !$(`${n}-file`).files[0]);
      for (const n of missing) fieldError(n, `${n}: choose an image file`);
      const tooBig = ["left", "right"].filter((n) => !missing.includes(n) && !checkSize(n));
      if (missing.length || tooBig.length) { setStatus("stale", "Not computed. Check the marked inputs."); return; }
      try {
        request.left = await readAs($("left-file").files[0], "url");
        request.right = await readAs($("right-file").files[0], "url");
      } catch (err) {
        setStatus("stale", "The files could not be read.");
        return;
      }
    }
    busy = true;
    $("run-depth").disabled = true;
    $("use-sample").disabled = true;
    setStatus("busy", sample ? "Matching the sample pair…" : "Uploading and matching…");
    let response;
    let body = null;
    try {
      response = await fetch("/api/depthmap", {
        method: "POST", headers: { "Content-Type": "application/json", Accept: "application/json" },
        body: JSON.stringify(request),
      });
      try { body = await response.json(); } catch (err) { body = null; }
    } catch (err) {
      setStatus("stale", "The server does not answer.");
      return;
    } finally {
      busy = false;
      $("run-depth").disabled = false;
      $("use-sample").disabled = false;
    }
    if (response.ok && body) {
      render(body);
      setStatus("ok", `Done: ${body.width}×${body.height} px matched in ${g(body.time_s * 1000, 3)} ms; ` +
        `${g(100 * body.density, 3)} % of the pixels have a disparity.`);
    } else if (body && Array.isArray(body.detail)) {
      showDetail(body.detail);
    } else {
      setStatus("stale", `The server answered ${response.status}.`);
    }
  }

  async function useSample() {
    if (!limits) await loadLimits();
    const s = limits.sample;
    window.stereodepth.setRig({ baseline_mm: s.baseline_mm, focal_px: s.focal_px, doffs_px: s.doffs_px, width_px: s.width_px });
    $("num_disparities").value = "";
    calibLoads++;  // a calib.txt still loading is not applied
    $("calib-file").value = "";
    dropCalib(CALIB_NOTE);
    await run(true);
  }

  // --- drawing -----------------------------------------------------------------------------
  function colorbar(id, cb) {
    const box = $(id);
    const bar = document.createElement("div");
    bar.className = "bar";
    bar.style.background = `linear-gradient(to right, ${cb.colors.join(", ")})`;
    const ticks = document.createElement("div");
    ticks.className = "ticks";
    const mid = (cb.vmin + cb.vmax) / 2;
    for (const v of [cb.vmin, mid, cb.vmax]) {
      const t = document.createElement("span");
      t.textContent = `${g(v, 4)}`;
      ticks.appendChild(t);
    }
    const unit = document.createElement("span");
    unit.textContent = cb.unit;
    ticks.appendChild(unit);
    box.replaceChildren(bar, ticks);
    box.title = `colour limits: the 1st and 99th percentile, ${g(cb.vmin)} to ${g(cb.vmax)} ${cb.unit}; black: no value`;
  }

  function stat(label, value) {
    const div = document.createElement("div");
    const dt = document.createElement("dt");
    dt.textContent = label;
    const dd = document.createElement("dd");
    dd.textContent = value;
    div.append(dt, dd);
    return div;
  }

  function render(body) {
    result = body;
    result.disparity = decode(body.arrays.disparity);
    result.depth = decode(body.arrays.depth);
    result.confidence = decode(body.arrays.confidence);
    pins = [];
    renderPins();
    $("depth-results").hidden = false;
    $("cloud-card").hidden = false;
    $("img-left").src = body.images.left;
    $("img-disparity").src = body.images.disparity;
    $("img-depth").src = body.images.depth;
    colorbar("cb-disparity", body.colorbars.disparity);
    colorbar("cb-depth", body.colorbars.depth);
    const p = body.params;
    const zr = body.depth_range_m;
    $("depth-stats").replaceChildren(
      stat("Size", `${body.width} × ${body.height} px`),
      stat("Matcher", `${body.method}${p.cost ? `, ${p.cost}` : ""}${p.block_size ? `, block ${p.block_size}` : ""}`),
      stat("Disparities", `${p.min_disparity} to ${p.min_disparity + p.num_disparities - 1} px`),
      stat("Density", `${g(100 * body.density, 3)} %`),
      stat("Depth range", zr ? `${g(zr[0], 4)} to ${g(zr[1], 4)} m` : "—"),
      stat("Time", `${g(body.time_s * 1000, 3)} ms`),
    );
    if (body.truth && body.truth.mean_abs_error_px !== null) {
      $("depth-stats").append(stat("Against the true disparity",
        `mean error ${g(body.truth.mean_abs_error_px, 3)} px, ${g(100 * body.truth.bad_1, 3)} % off by > 1 px`));
    }
    $("ro-step-label").textContent = `${g(body.rig.disparity_step_px)} px`;
    for (const id of ["ro-x", "ro-y", "ro-disparity", "ro-depth", "ro-res1", "ro-resstep", "ro-confidence"]) $(id).textContent = "—";
    const links = Object.entries(body.downloads).map(([name, url]) => {
      const a = document.createElement("a");
      a.href = url;
      a.download = name;
      a.textContent = name;
      return a;
    });
    const label = document.createElement("span");
    label.textContent = "Download: ";
    $("downloads").replaceChildren(label, ...links);
    drawCloud();
  }

  function cloudColours(pts) {
    if (!pts.color) {
      const bin = atob(pts.rgb);
      pts.color = new Array(pts.count);
      for (let i = 0; i < pts.count; i++) {
        pts.color[i] = `rgb(${bin.charCodeAt(3 * i)},${bin.charCodeAt(3 * i + 1)},${bin.charCodeAt(3 * i + 2)})`;
      }
    }
    return pts.color;
  }

  function drawCloud() {
    const pts = result.points;
    cloudColours(pts);
    const every = pts.step === 1 ? "every pixel" : `one pixel in ${pts.step} along each axis`;
    $("cloud-note").textContent = `${pts.count.toLocaleString("en-US")} points (${every}), coloured by the left image; ` +
      "the left camera at the origin, Z forward, −Y up. Drag to turn, scroll to zoom.";
    const draw = () => {
      const traces = [{
        type: "scatter3d", mode: "markers", name: "points",
        x: pts.x, y: pts.z, z: pts.y.map((v) => -v),
        marker: { size: 1.6, color: pts.color },
        hovertemplate: "X %{x:.3f} m<br>Z %{y:.3f} m<br>Y %{z:.3f} m<extra></extra>",
      }];
      const picked = pins.filter((p) => p.point_m);
      if (picked.length) {
        traces.push({
          type: "scatter3d", mode: "markers+text", name: "pins",
          x: picked.map((p) => p.point_m[0]), y: picked.map((p) => p.point_m[2]), z: picked.map((p) => -p.point_m[1]),
          text: picked.map((p) => String(p.n)), textposition: "top center",
          marker: { size: 5, color: "#ff2d55" },
        });
      }
      const axis = (t) => ({ title: { text: t }, backgroundcolor: "#fafafb", gridcolor: "#e4e4e7" });
      window.Plotly.react("cloud", traces, {
        margin: { l: 0, r: 0, t: 0, b: 0 },
        showlegend: false,
        scene: {
          aspectmode: "data",
          xaxis: axis("X (m)"), yaxis: axis("Z (m)"), zaxis: axis("−Y (m)"),
          camera: { eye: { x: -0.45, y: -1.25, z: 0.45 }, up: { x: 0, y: 0, z: 1 } },
        },
        paper_bgcolor: "#fff",
      }, { displaylogo: false, responsive: true });
    };
    if (window.Plotly) draw();
    else $("plotly-js").addEventListener("load", draw, { once: true });
  }

  // --- reading and pinning pixels -----------------------------------------------------------
  function pixelOf(img, event) {
    const rect = img.getBoundingClientRect();
    const x = Math.floor(((event.clientX - rect.left) * result.width) / rect.width);
    const y = Math.floor(((event.clientY - rect.top) * result.height) / rect.height);
    if (x < 0 || y < 0 || x >= result.width || y >= result.height) return null;
    return { x, y };
  }

  function placeMarks(cls, list) {
    for (const frame of document.querySelectorAll(".map-frame")) {
      for (const old of frame.querySelectorAll(`.mark.${cls}`)) old.remove();
      for (const p of list) {
        const m = document.createElement("div");
        m.className = `mark ${cls}`;
        m.style.left = `${((p.x + 0.5) * 100) / result.width}%`;
        m.style.top = `${((p.y + 0.5) * 100) / result.height}%`;
        if (p.n) {
          const label = document.createElement("span");
          label.className = "pin-label";
          label.textContent = String(p.n);
          m.appendChild(label);
        }
        frame.appendChild(m);
      }
    }
  }

  function readout(x, y) {
    const i = y * result.width + x;
    const d = result.disparity[i];
    const z = result.depth[i];
    const bf = result.rig.bf_m_px;
    const step = result.rig.disparity_step_px;
    $("ro-x").textContent = String(x);
    $("ro-y").textContent = String(y);
    $("ro-disparity").textContent = f32(d);
    $("ro-depth").textContent = f32(z);
    // StereoRig.depth_resolution_m: Z * Z * step / (B f), in the same order of operations.
    const ok = Number.isFinite(z);
    $("ro-res1").textContent = ok ? g((z * z * 1.0) / bf) : "—";
    $("ro-resstep").textContent = ok ? g((z * z * step) / bf) : "—";
    $("ro-confidence").textContent = result.confidence && Number.isFinite(d) ? g(result.confidence[i], 3) : "—";
    placeMarks("cursor", [{ x, y }]);
  }

  // A pixel of the depth map shown: an answer that comes after another map was drawn is of
  // the old map (it was pinned on the new one, with the old one's numbers), and is dropped.
  async function pin(x, y) {
    const mine = result;
    let p;
    try {
      const response = await fetch(`/api/depthmap/${mine.id}/point?x=${x}&y=${y}`);
      if (result !== mine) return;
      if (!response.ok) { setStatus("stale", "That result is no longer on the server; compute again."); return; }
      p = await response.json();
    } catch (err) {
      if (result === mine) setStatus("stale", `The server does not answer; pixel ${x}, ${y} is not pinned.`);
      return;
    }
    if (result !== mine) return;
    p.n = pins.length ? pins[pins.length - 1].n + 1 : 1;
    pins.push(p);
    renderPins();
    drawCloud();
  }

  function renderPins() {
    const rows = pins.map((p, k) => {
      const tr = document.createElement("tr");
      const cells = [String(p.n), String(p.x), String(p.y), f32(p.disparity_px), f32(p.depth_m),
        p.point_m ? g(p.point_m[0]) : "—", p.point_m ? g(p.point_m[1]) : "—"];
      for (const c of cells) {
        const td = document.createElement("td");
        td.textContent = c;
        tr.appendChild(td);
      }
      const td = document.createElement("td");
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = "✕";
      b.title = "unpin";
      b.addEventListener("click", () => { pins.splice(k, 1); renderPins(); drawCloud(); });
      td.appendChild(b);
      tr.appendChild(td);
      return tr;
    });
    $("pin-table").tBodies[0].replaceChildren(...rows);
    const withPoints = pins.filter((p) => p.point_m);
    const text = $("pin-distance");
    if (withPoints.length >= 2) {
      const [a, b] = withPoints.slice(-2);
      const dist = Math.sqrt((a.point_m[0] - b.point_m[0]) ** 2 + (a.point_m[1] - b.point_m[1]) ** 2 + (a.point_m[2] - b.point_m[2]) ** 2);
      text.innerHTML = "";
      text.append(`Distance from point ${a.n} to point ${b.n}: `);
      const strong = document.createElement("strong");
      strong.id = "distance-value";
      strong.textContent = g(dist);
      text.append(strong, " m");
    } else {
      text.textContent = pins.length >= 2 ? "A pinned point has no depth: pin points with a disparity to measure."
        : "Pin two points to measure the distance between them.";
    }
    if (result) placeMarks("pin", pins);
  }

  // The method's own defaults in the form: semi-global matching has another block size than
  // block matching's 9 and no cost. A block size the user typed is kept.
  let shownMethod = "bm";
  function methodChanged() {
    const method = $("method").value;
    const defaults = limits && limits.defaults;
    if (defaults && defaults[method] && defaults[shownMethod]) {
      const box = $("block_size");
      const before = String(defaults[shownMethod].block_size);
      if (box.value.trim() === "" || box.value.trim() === before) box.value = String(defaults[method].block_size);
    }
    $("cost").disabled = method !== "bm";
    shownMethod = method;
  }

  // --- start -------------------------------------------------------------------------------
  async function loadLimits() {
    try {
      limits = await (await fetch("/api/depthmap/limits")).json();
      $("limit-text").textContent = `${g(limits.max_upload_bytes / 1e6, 3)} MB and ${g(limits.max_pixels / 1e6, 3)} megapixels`;
      methodChanged();  // a method the browser restored in the form gets its defaults
      if (!limits.methods.includes("sgm")) {
        const opt = $("method").querySelector('option[value="sgm"]');
        opt.disabled = true;
        opt.textContent = "semi-global (not in this version)";
      }
    } catch (err) {
      limits = null;
    }
  }

  function start() {
    $("tab-calc").addEventListener("click", () => { history.replaceState(null, "", "#"); showTab("calc"); });
    $("tab-depth").addEventListener("click", () => { history.replaceState(null, "", "#depth"); showTab("depth"); });
    if (location.hash === "#depth") showTab("depth");
    $("run-depth").addEventListener("click", () => run(false));
    $("use-sample").addEventListener("click", useSample);
    $("calib-file").addEventListener("change", loadCalib);
    $("method").addEventListener("change", methodChanged);
    for (const n of ["left", "right"]) $(`${n}-file`).addEventListener("change", () => checkSize(n));
    for (const id of ["img-left", "img-disparity", "img-depth"]) {
      const img = $(id);
      img.addEventListener("mousemove", (e) => { const p = result && pixelOf(img, e); if (p) readout(p.x, p.y); });
      img.addEventListener("click", (e) => { const p = result && pixelOf(img, e); if (p) pin(p.x, p.y); });
    }
    loadLimits();
  }

  window.stereodepthDepth = { f32, result: () => result, pins: () => pins };  // for tests
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
