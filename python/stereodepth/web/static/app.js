// The stereodepth calculator page: every number comes from the library via /api/calc.
"use strict";

(function () {
  // The worked examples: the rig and the target; the matcher settings are left as they are.
  const PRESETS = {
    arm: { focal_mode: "mm", baseline_mm: "150", focal_mm: "6", pixel_um: "2.8", width_px: "1280", disparity_px: "250" },
    car: { focal_mode: "mm", baseline_mm: "250", focal_mm: "12", pixel_um: "4.2", width_px: "2048", disparity_px: "35" },
  };
  const INPUTS = [
    "baseline_mm", "focal_mm", "pixel_um", "focal_px", "doffs_px", "width_px", "disparity_px",
    "disparity_step_px", "max_disparity_px", "inverse_depth_m", "inverse_depth_resolution_m",
  ];
  const RESULTS = [
    "depth_m", "depth_resolution_m", "depth_resolution_subpx_m", "disparity_mm",
    "max_depth_m", "min_depth_m", "hfov_deg", "focal_px",
  ];
  const TABLE_COLUMNS = {
    disparity_px: "Disparity d (px)",
    disparity_mm: "on the sensor (mm)",
    depth_m: "Depth Z (m)",
    depth_resolution_m: "Depth resolution, 1 px (m)",
    depth_resolution_subpx_m: "Depth resolution, Δd (m)",
  };
  const SERIES_COLOURS = ["#2563eb", "#d97706", "#059669"];
  const TARGET_COLOUR = "#dc2626";

  const $ = (id) => document.getElementById(id);
  let labels = {};        // field name -> its label text, for messages
  let lastGood = null;    // the last answer without errors
  let sequence = 0;       // answers to older requests are dropped
  let controller = null;
  let timer = null;

  // value.toExponential(fraction), but a value exactly halfway between the two nearest
  // decimals of that many digits goes to the one whose last digit is even, as C's printf,
  // Python's % and numpy round it: JavaScript rounds it away from zero (1000.125 to six
  // digits: 1000.12 in Python, 1000.13 in JavaScript).
  function toExponentialEven(value, fraction) {
    const text = value.toExponential(fraction);
    // The value's exact decimal digits (a tie has fraction + 2 of them; 100 is the most
    // toExponential gives, and shows such a value exactly).
    const [exact, exp] = value.toExponential(100).split("e");
    const digits = exact.replace("-", "").replace(".", "");
    const tie = digits[fraction + 1] === "5" && /^0*$/.test(digits.slice(fraction + 2));
    if (!tie || Number(digits[fraction]) % 2 === 1) return text;  // odd: away is to even
    const kept = digits.slice(0, fraction + 1);
    const mant = fraction > 0 ? `${kept[0]}.${kept.slice(1)}` : kept;
    return `${value < 0 ? "-" : ""}${mant}e${exp}`;
  }

  // Formats like C's %.6g (and Python's, which the CLI prints), so the page and
  // `stereodepth calc` show the same digits.
  function formatG(value, digits = 6) {
    if (value === null || value === undefined) return "—";
    if (!Number.isFinite(value)) return value > 0 ? "∞" : "—";
    if (value === 0) return "0";
    // Round to `digits` significant digits first: that may carry into the next power of ten
    // (and past the largest double, so the exponent is read from the text).
    const [first, firstExp] = toExponentialEven(value, digits - 1).split("e");
    const exp = Number(firstExp);
    if (exp < -4 || exp >= digits) {
      let mant = first;
      if (mant.includes(".")) mant = mant.replace(/0+$/, "").replace(/\.$/, "");
      const sign = firstExp[0] === "-" ? "-" : "+";
      const mag = firstExp.replace(/^[+-]/, "").padStart(2, "0");
      return `${mant}e${sign}${mag}`;
    }
    const rounded = Number(`${first}e${firstExp}`);
    let text = rounded.toFixed(Math.max(0, digits - 1 - exp));
    if (text.includes(".")) text = text.replace(/0+$/, "").replace(/\.$/, "");
    return text;
  }

  function mode() {
    return document.querySelector('input[name="focal_mode"]:checked').value;
  }

  function activeInputs() {
    const m = mode();
    return INPUTS.filter((name) => {
      const field = document.querySelector(`.field[data-field="${name}"]`);
      return !field.dataset.mode || field.dataset.mode === m;
    });
  }

  function query() {
    const params = new URLSearchParams();
    for (const name of activeInputs()) {
      const text = $(name).value.trim();
      if (text !== "") params.set(name, text);
    }
    return params;
  }

  // --- messages at the fields -----------------------------------------------------------
  function clearErrors() {
    for (const name of INPUTS) {
      const field = document.querySelector(`.field[data-field="${name}"]`);
      field.classList.remove("invalid");
      $(name).removeAttribute("aria-invalid");
      const box = $(`${name}-error`);
      box.hidden = true;
      box.textContent = "";
    }
  }

  // The API's messages name parameters, as the library's do; on the page, use their labels.
  function friendly(name, message) {
    let text = message;
    if (labels[name] && text.startsWith(name)) text = labels[name] + text.slice(name.length);
    const others = Object.keys(labels).filter((n) => n !== name).sort((a, b) => b.length - a.length);
    for (const other of others) {
      const label = labels[other];
      text = text.replace(new RegExp(`\\b${other}\\b`, "g"), label.charAt(0).toLowerCase() + label.slice(1));
    }
    return text;
  }

  function showErrors(detail) {
    const general = [];
    for (const item of detail) {
      let name = Array.isArray(item.loc) ? item.loc[1] : undefined;
      let msg = item.msg;
      // The focal length in pixels left empty: the API, which has no modes, asks for the
      // focal length in mm and the pixel size, inputs this mode hides (the page said "Check
      // the marked input" and marked none); ask for the one it shows.
      if (mode() === "px" && item.type === "missing" && (name === "focal_mm" || name === "pixel_um")) {
        if ($("focal_px").getAttribute("aria-invalid") === "true") continue;  // said once
        name = "focal_px";
        msg = "focal_px is required";
      }
      if (name && INPUTS.includes(name) && activeInputs().includes(name)) {
        const field = document.querySelector(`.field[data-field="${name}"]`);
        field.classList.add("invalid");
        $(name).setAttribute("aria-invalid", "true");
        const box = $(`${name}-error`);
        box.textContent = box.textContent ? `${box.textContent} ${friendly(name, msg)}` : friendly(name, msg);
        box.hidden = false;
      } else {
        general.push(item.msg);
      }
    }
    return general;
  }

  function setStatus(kind, text) {
    const status = $("status");
    status.className = `status ${kind}`;
    status.textContent = text;
    document.body.classList.toggle("stale-results", kind === "stale" && lastGood !== null);
  }

  // --- drawing ---------------------------------------------------------------------------
  function setValue(id, value) {
    const box = $(id).querySelector(".value");
    box.textContent = formatG(value);
    box.title = value === null || value === undefined ? "not available" : String(value);
  }

  function render(answer) {
    const s = answer.summary;
    for (const key of RESULTS) setValue(`out-${key}`, s[key]);
    $("step-label").textContent = `${formatG(s.disparity_step_px)} px`;
    $("note-exact").textContent = s.depth_resolution_exact_m === null ? "first order"
      : `exact Z(d) − Z(d+1): ${formatG(s.depth_resolution_exact_m)} m`;
    $("out-min_depth_m").querySelector(".note").textContent = s.max_disparity_px === null
      ? "give a search range" : `searching up to ${formatG(s.max_disparity_px)} px`;

    const inv = answer.inverse;
    setValue("out-required_baseline_mm", inv ? inv.required_baseline_mm : null);
    $("use-baseline").disabled = !(inv && inv.required_baseline_mm !== null);
    $("inverse-note").textContent = inv
      ? `with f = ${formatG(inv.focal_px)} px and a ${formatG(inv.disparity_step_px)} px disparity step`
      : "give both values";

    renderTable(s);
    plotlyReady.then(() => {
      if (lastGood !== answer) return;  // a newer answer draws its own charts
      renderChart("chart-depth", answer.charts.depth_vs_disparity);
      renderChart("chart-error", answer.charts.error_vs_depth);
    }, () => {
      for (const id of ["chart-depth", "chart-error"]) {
        $(id).innerHTML = '<p class="chart-wait">The chart library did not load.</p>';
      }
    });
  }

  // plotly.js loads asynchronously (see index.html); the charts wait for it, the numbers don't.
  const plotlyReady = new Promise((resolve, reject) => {
    if (window.Plotly) { resolve(); return; }
    const script = $("plotly-js");
    script.addEventListener("load", () => (window.Plotly ? resolve() : reject()));
    script.addEventListener("error", reject);
  });

  function renderTable(s) {
    const rows = s.table;
    const columns = rows.length ? Object.keys(rows[0]) : [];
    const head = document.createElement("tr");
    for (const c of columns) {
      const th = document.createElement("th");
      th.scope = "col";
      th.textContent = c === "depth_resolution_subpx_m"
        ? `Depth resolution, ${formatG(s.disparity_step_px)} px (m)` : (TABLE_COLUMNS[c] || c);
      th.dataset.column = c;
      head.appendChild(th);
    }
    $("depth-table").tHead.replaceChildren(head);

    // The row nearest the target, by ratio (the table is geometric).
    let near = -1;
    if (s.disparity_px !== null && s.disparity_px > 0) {
      let best = Infinity;
      rows.forEach((r, i) => {
        const dist = Math.abs(Math.log(r.disparity_px / s.disparity_px));
        if (r.disparity_px > 0 && dist < best) { best = dist; near = i; }
      });
    }
    const body = rows.map((r, i) => {
      const tr = document.createElement("tr");
      if (i === near) tr.className = "near";
      for (const c of columns) {
        const td = document.createElement("td");
        td.textContent = formatG(r[c]);
        tr.appendChild(td);
      }
      return tr;
    });
    $("depth-table").tBodies[0].replaceChildren(...body);
  }

  function renderChart(id, chart) {
    const wait = $(id).querySelector(".chart-wait");
    if (wait) wait.remove();
    const traces = chart.series.map((series, i) => ({
      type: "scatter",
      mode: "lines",
      name: series.name,
      x: series.x,
      y: series.y,
      line: { color: SERIES_COLOURS[i % SERIES_COLOURS.length], width: 2.5 },
      hovertemplate: `${chart.x_label}: %{x:.4g}<br>${chart.y_label}: %{y:.4g}<extra>${series.name}</extra>`,
    }));
    // The target: a red diamond (ringed in its curve's colour when there are several) with
    // its value in a box, on the side of the chart with more room.
    const xs = chart.series.flatMap((series) => series.x);
    const [xmin, xmax] = [Math.min(...xs), Math.max(...xs)];
    const what = chart.y_label.startsWith("depth Z") ? "Z" : "ΔZ";
    const first = chart.series[0];
    const descending = first && first.y.length > 1 && first.y[first.y.length - 1] < first.y[0];
    const annotations = [];
    // A log axis has no place for a marker at or below 0: the target disparity 0 or below of a
    // rig with doffs > 0, whose depth is finite (the other chart shows it). Plotly drew it
    // where the last target had been, its label over the axis; `calc --plot` leaves it out.
    const drawable = (m) => (!chart.x_log || m.x > 0) && (!chart.y_log || m.y > 0);
    chart.markers.forEach((m, i) => {
      if (!drawable(m)) return;
      traces.push({
        type: "scatter",
        mode: "markers",
        name: m.name,
        x: [m.x],
        y: [m.y],
        cliponaxis: false,
        marker: {
          symbol: "diamond", size: 12, color: TARGET_COLOUR,
          line: { width: 2, color: chart.markers.length > 1 ? SERIES_COLOURS[i % SERIES_COLOURS.length] : "#fff" },
        },
        hovertemplate: `${chart.x_label}: %{x:.6g}<br>${chart.y_label}: %{y:.6g}<extra>${m.name}</extra>`,
      });
      const frac = xmax > xmin ? Math.log(m.x / xmin) / Math.log(xmax / xmin) : 0;  // log axes
      const step = m.name.split(", ")[1];
      const right = frac > 0.6;
      annotations.push({
        // Annotations on a log axis take the log of the position.
        x: chart.x_log ? Math.log10(m.x) : m.x, y: chart.y_log ? Math.log10(m.y) : m.y,
        xref: "x", yref: "y",
        text: `${what} = ${formatG(m.y, 4)} m${step ? ` (${step})` : ""}`,
        showarrow: true, arrowhead: 0, arrowcolor: TARGET_COLOUR, arrowwidth: 1,
        ax: right ? -60 : 60,
        // One target: into the empty corner beside the curve; two: one above, one below.
        ay: chart.markers.length > 1 ? (i === 0 ? -26 : 26) : (right === descending ? 30 : -30),
        xanchor: right ? "right" : "left",
        font: { color: "#991b1b", size: 12 },
        bgcolor: "rgba(255,255,255,0.92)", bordercolor: "#fca5a5", borderwidth: 1, borderpad: 3,
      });
    });
    const shapes = chart.markers.length && drawable(chart.markers[0]) ? [{
      type: "line", xref: "x", yref: "paper", x0: chart.markers[0].x, x1: chart.markers[0].x,
      y0: 0, y1: 1, line: { color: TARGET_COLOUR, width: 1, dash: "dot" },
    }] : [];
    const axis = (title, log) => ({
      title: { text: title, font: { size: 13 } },
      type: log ? "log" : "linear",
      gridcolor: "#e4e4e7",
      zeroline: false,
      linecolor: "#a1a1aa",
      mirror: true,
      ticks: "outside",
      exponentformat: "power",
    });
    const layout = {
      title: { text: chart.title, x: 0.01, xanchor: "left", font: { size: 15 } },
      margin: { l: 64, r: 24, t: 44, b: 52 },
      xaxis: axis(chart.x_label, chart.x_log),
      yaxis: axis(chart.y_label, chart.y_log),
      legend: { orientation: "h", x: 0, y: -0.22, font: { size: 11 } },
      shapes,
      annotations,
      font: { family: getComputedStyle(document.body).fontFamily, color: "#27272a" },
      paper_bgcolor: "#fff",
      plot_bgcolor: "#fff",
      hovermode: "closest",
    };
    const config = { displaylogo: false, responsive: true, modeBarButtonsToRemove: ["lasso2d", "select2d"] };
    window.Plotly.react(id, traces, layout, config);
  }

  // --- asking the API --------------------------------------------------------------------
  // A worked example's button shows whether the inputs are that example.
  function markPreset() {
    for (const b of document.querySelectorAll(".preset")) {
      const preset = PRESETS[b.dataset.preset];
      const same = Object.entries(preset).every(([name, value]) =>
        name === "focal_mode" ? mode() === value : Number($(name).value.trim()) === Number(value));
      b.classList.toggle("active", same);
      b.setAttribute("aria-pressed", String(same));
    }
  }

  async function update() {
    const mine = ++sequence;
    markPreset();
    if (controller) controller.abort();
    controller = new AbortController();
    setStatus("busy", "Calculating…");
    let response;
    try {
      response = await fetch(`/api/calc?${query()}`, { signal: controller.signal, headers: { Accept: "application/json" } });
    } catch (err) {
      if (err.name === "AbortError") return;
      if (mine === sequence) setStatus("stale", "The server does not answer; showing the last valid results.");
      return;
    }
    let body = null;
    try { body = await response.json(); } catch (err) { body = null; }
    if (mine !== sequence) return;
    clearErrors();
    if (response.ok && body) {
      lastGood = body;
      render(body);
      setStatus("ok", "Up to date.");
    } else if (response.status === 422 && body && Array.isArray(body.detail)) {
      const general = showErrors(body.detail);
      const what = lastGood ? "showing the last valid results" : "no results yet";
      setStatus("stale", `Check the marked input; ${what}.${general.length ? " " + general.join(" ") : ""}`);
    } else {
      setStatus("stale", `The server answered ${response.status}; showing the last valid results.`);
    }
  }

  function schedule() {
    clearTimeout(timer);
    timer = setTimeout(update, 120);
  }

  function applyPreset(key) {
    const preset = PRESETS[key];
    document.querySelector(`input[name="focal_mode"][value="${preset.focal_mode}"]`).checked = true;
    applyMode();
    for (const [name, value] of Object.entries(preset)) if (name !== "focal_mode") $(name).value = value;
    update();
  }

  function applyMode() {
    const m = mode();
    for (const field of document.querySelectorAll(".field[data-mode]")) field.hidden = field.dataset.mode !== m;
    // Carry the focal length over in pixels when switching to pixels.
    if (m === "px" && $("focal_px").value.trim() === "" && lastGood) {
      $("focal_px").value = String(lastGood.summary.focal_px);
    }
  }

  // The allowed range of a field as the API states it, e.g. "> 0, up to 1,000,000 mm".
  function rangeText(f) {
    const n = (v) => v.toLocaleString("en-US", { maximumSignificantDigits: 6 });
    const unit = ` ${f.unit}`;
    if (f.minimum === null) return f.maximum === null ? "" : `up to ${n(f.maximum)}${unit}`;
    if (f.exclusive_minimum) return `> ${n(f.minimum)}, up to ${n(f.maximum)}${unit}`;
    return `${f.integer ? "whole number, " : ""}${n(f.minimum)} to ${n(f.maximum)}${unit}`;
  }

  async function loadFields() {
    try {
      const response = await fetch("/api/fields");
      const body = await response.json();
      $("version").textContent = body.version;
      for (const f of body.fields) {
        const hint = document.querySelector(`[data-hint="${f.name}"]`);
        if (hint) hint.textContent = rangeText(f);
        const label = document.querySelector(`label[for="${f.name}"]`);
        if (label) label.title = f.description;
      }
    } catch (err) {
      // The hints are a help only; the calculator works without them.
    }
  }

  function start() {
    for (const name of INPUTS) $(name).addEventListener("input", schedule);
    for (const radio of document.querySelectorAll('input[name="focal_mode"]')) {
      radio.addEventListener("change", () => { applyMode(); update(); });
    }
    for (const b of document.querySelectorAll(".preset")) b.addEventListener("click", () => applyPreset(b.dataset.preset));
    $("use-baseline").addEventListener("click", () => {
      if (lastGood && lastGood.inverse && lastGood.inverse.required_baseline_mm !== null) {
        $("baseline_mm").value = formatG(lastGood.inverse.required_baseline_mm);
        update();
      }
    });
    $("inputs").addEventListener("submit", (e) => { e.preventDefault(); update(); });
    for (const name of INPUTS) labels[name] = document.querySelector(`label[for="${name}"]`).textContent.trim();
    loadFields();
    applyMode();
    update();
  }

  // The rig as the inputs give it (the calculator's names), for the depth-map view.
  function rigValues() {
    const rig = {};
    for (const name of ["baseline_mm", "focal_mm", "pixel_um", "focal_px", "doffs_px"]) {
      if (activeInputs().includes(name)) {
        const text = $(name).value.trim();
        if (text !== "") rig[name] = text;
      }
    }
    return rig;
  }

  // Sets rig inputs (focal length in pixels when focal_px is given) and recalculates.
  function setRig(values) {
    if (values.focal_px !== undefined) {
      document.querySelector('input[name="focal_mode"][value="px"]').checked = true;
      applyMode();
    }
    for (const [name, value] of Object.entries(values)) {
      if (value !== null && value !== undefined && $(name)) $(name).value = String(value);
    }
    update();
  }

  // Errors of the depth-map request located at rig inputs: shown at those inputs.
  function showRigErrors(detail) {
    clearErrors();
    return showErrors(detail);
  }

  window.stereodepth = { formatG, toExponentialEven, rigValues, setRig, showRigErrors };  // also for tests
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
