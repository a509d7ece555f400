/* pointillist compare: the script of report.html (inlined by pointillist/compare_html.py).
 *
 * Plain browser JavaScript, no dependencies and no build step. It reads
 * the element #report-data (JSON): renders as base64 float16 (RGB, then relMSE, FLIP and
 * sample-count maps), colour tables and the sweep's points; draws the two log-log
 * plots as SVG, the image viewer as canvases that share one view (zoom, pan),
 * applying exposure and the sRGB transfer function to the HDR data here, and the
 * error spectra of the renders on show (SVG, log-log).
 * (No closing-tag sequence may appear in this file: it is inlined into the page.)
 * With "#selftest" in the URL it runs scripted interactions after loading and writes
 * their results as JSON into a new element #selftest-result (tests/test_compare_html.py).
 */
(function () {
  "use strict";
  var errors = [];
  var violations = [];
  window.addEventListener("error", function (e) { errors.push(String(e.message || e)); });
  document.addEventListener("securitypolicyviolation", function (e) {
    violations.push(e.violatedDirective + " " + e.blockedURI);
  });

  var D = JSON.parse(document.getElementById("report-data").textContent);
  var W = D.width, H = D.height, N = W * H;
  var SVGNS = "http://www.w3.org/2000/svg";
  var KINDS = { rgb: "render", relmse: "relMSE", flip: "FLIP", count: "samples" };

  // ------------------------------------------------------------------ data decoding
  var HALF = new Float32Array(65536);
  (function () {
    for (var h = 0; h < 65536; h++) {
      var e = (h >> 10) & 31, f = h & 1023, s = (h & 32768) ? -1 : 1;
      HALF[h] = e === 0 ? s * f * Math.pow(2, -24)
        : e === 31 ? (f ? NaN : s * Infinity) : s * (1 + f / 1024) * Math.pow(2, e - 15);
    }
  })();

  function decodeHalf(b64) {  // little-endian float16 -> Float32Array
    var bin = atob(b64), n = bin.length >> 1, out = new Float32Array(n);
    for (var i = 0; i < n; i++) out[i] = HALF[bin.charCodeAt(2 * i) | (bin.charCodeAt(2 * i + 1) << 8)];
    return out;
  }

  var COLORMAPS = {};
  Object.keys(D.colormaps).forEach(function (name) {
    var hex = D.colormaps[name], table = new Uint8Array(hex.length / 2);
    for (var i = 0; i < table.length; i++) table[i] = parseInt(hex.substr(2 * i, 2), 16);
    COLORMAPS[name] = table;
  });

  function srgb8(x) {  // linear value -> 8-bit sRGB (IEC 61966-2-1)
    if (!(x > 0)) return 0;
    if (x >= 1) return 255;
    var v = x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055;
    return Math.round(255 * v);
  }

  function scaleT(scale, v) {  // value -> [0, 1] on the scale (log or linear); NaN stays NaN
    var t = scale.log ? (Math.log(v) - Math.log(scale.lo)) / (Math.log(scale.hi) - Math.log(scale.lo))
      : (v - scale.lo) / (scale.hi - scale.lo);
    if (scale.log && v <= 0) t = 0;
    return t !== t ? NaN : Math.min(1, Math.max(0, t));
  }

  // ------------------------------------------------------------------ image sources
  var sources = {};  // "reference:rgb", "3:flip", ... -> {values, canvas, exposure}
  var exposure = 0;

  function entryOf(column) { return column === "reference" ? D.reference : D.renders[column]; }

  function source(column, kind) {
    var key = column + ":" + kind, src = sources[key];
    if (!src) {
      var entry = entryOf(column), field = kind === "rgb" ? "rgb" : kind + "_map";
      if (!entry[field]) return null;
      var canvas = document.createElement("canvas");
      canvas.width = W; canvas.height = H;
      src = sources[key] = { values: decodeHalf(entry[field]), canvas: canvas, kind: kind, exposure: null };
    }
    if (src.exposure !== (kind === "rgb" ? exposure : 0)) paint(src);
    return src;
  }

  function paint(src) {
    var ctx = src.canvas.getContext("2d"), image = ctx.createImageData(W, H), d = image.data, v = src.values;
    if (src.kind === "rgb") {
      var m = Math.pow(2, exposure);
      for (var i = 0, j = 0; i < N; i++, j += 4) {
        d[j] = srgb8(v[3 * i] * m); d[j + 1] = srgb8(v[3 * i + 1] * m); d[j + 2] = srgb8(v[3 * i + 2] * m);
        d[j + 3] = 255;
      }
      src.exposure = exposure;
    } else {
      var scale = D.scales[src.kind], table = COLORMAPS[scale.map];
      for (var k = 0, q = 0; k < N; k++, q += 4) {
        var t = scaleT(scale, v[k]);
        if (t !== t) { d[q] = 255; d[q + 1] = 0; d[q + 2] = 255; }  // NaN: magenta
        else { var c = 3 * Math.round(255 * t); d[q] = table[c]; d[q + 1] = table[c + 1]; d[q + 2] = table[c + 2]; }
        d[q + 3] = 255;
      }
      src.exposure = 0;
    }
    ctx.putImageData(image, 0, 0);
  }

  // ------------------------------------------------------------------ state
  var methods = D.methods.map(function (m) { return m.name; });
  var colourOf = {};
  D.methods.forEach(function (m) { colourOf[m.name] = m.colour; });
  var state = { mode: "spp", target: null, shown: {}, override: {}, metric: "mse" };
  methods.forEach(function (m) { state.shown[m] = true; });
  var view = { zoom: 1, cx: W / 2, cy: H / 2, hover: null };
  var fit = 1, panes = [];

  function targets(mode) {  // the sweep's distinct spp or times, ascending
    var seen = {}, values = [];
    D.points.forEach(function (p) {
      var v = p[mode];
      if (v > 0) { var k = v.toPrecision(3); if (!seen[k]) { seen[k] = 1; values.push(v); } }
    });
    return values.sort(function (a, b) { return a - b; });
  }

  function pick(method) {  // the render shown for a method: clicked, or the point closest to the target
    if (state.override[method] != null) return state.override[method];
    var best = null, bestD = Infinity;
    D.points.forEach(function (p) {
      if (p.method !== method || !(p[state.mode] > 0)) return;
      var d = Math.abs(Math.log(p[state.mode]) - Math.log(state.target));
      if (d < bestD) { bestD = d; best = p.render; }
    });
    return best;
  }

  function fmtTime(t) {  // as compare_report.format_time: three significant digits, s / ms / µs
    if (t == null) return "–";
    var units = [["s", 1], ["ms", 1e-3], ["µs", 1e-6]], u = units[2];
    for (var i = 0; i < 3; i++) if (Math.abs(t) >= 0.9995 * units[i][1]) { u = units[i]; break; }
    var v = t / u[1];
    return (v >= 999.5 ? v.toFixed(0) : v.toPrecision(3)) + " " + u[0];
  }
  function fmtNum(v) { return v == null ? "–" : (v === 0 ? "0" : v.toExponential(3)); }
  function fmtSpp(v) { return v == null ? "–" : String(+v.toPrecision(4)); }

  // ------------------------------------------------------------------ controls
  var targetSelect = document.getElementById("target");

  function fillTargets() {
    var values = targets(state.mode);
    targetSelect.innerHTML = "";
    values.forEach(function (v) {
      var o = document.createElement("option");
      o.value = String(v);
      var p = D.points.filter(function (q) { return q[state.mode] === v; })[0];
      o.textContent = state.mode === "spp" ? fmtSpp(v) + " spp" : fmtTime(v) + " (" + p.method + " " + p.setting + ")";
      targetSelect.appendChild(o);
    });
    if (state.target == null || values.indexOf(state.target) < 0) {
      state.target = closest(values, state.target == null ? values[Math.floor(values.length / 2)] : state.target);
    }
    targetSelect.value = String(state.target);
  }

  function closest(values, v) {
    var best = values[0];
    values.forEach(function (x) { if (Math.abs(Math.log(x) - Math.log(v)) < Math.abs(Math.log(best) - Math.log(v))) best = x; });
    return best;
  }

  function setMode(mode, target) {
    state.mode = mode;
    document.querySelector("input[name=mode][value=" + mode + "]").checked = true;
    state.target = target == null ? null : closest(targets(mode), target);
    fillTargets();
  }

  Array.prototype.forEach.call(document.querySelectorAll("input[name=mode]"), function (radio) {
    radio.addEventListener("change", function () {
      var old = state.mode;
      // keep the comparison near the same renders: the time of the current spp, and back
      var anchor = D.points.filter(function (p) { return p.render === pick(methods[0]); })[0];
      state.override = {};
      setMode(radio.value, anchor ? anchor[radio.value] : null);
      if (old !== radio.value) buildViewer();
    });
  });
  targetSelect.addEventListener("change", function () {
    state.target = parseFloat(targetSelect.value);
    state.override = {};
    buildViewer();
  });

  var toggles = document.getElementById("method-toggles");
  methods.forEach(function (m) {
    var label = document.createElement("label"), box = document.createElement("input");
    box.type = "checkbox"; box.checked = true; box.dataset.method = m;
    box.addEventListener("change", function () { state.shown[m] = box.checked; buildViewer(); });
    var sw = document.createElement("span");
    sw.className = "swatch"; sw.style.background = colourOf[m];
    label.appendChild(box); label.appendChild(sw); label.appendChild(document.createTextNode(m));
    toggles.appendChild(label);
  });

  var exposureInput = document.getElementById("exposure");
  exposureInput.addEventListener("input", function () {
    exposure = parseFloat(exposureInput.value);
    document.getElementById("exposure-value").textContent = (exposure >= 0 ? "+" : "") + exposure.toFixed(1) + " EV";
    drawAll();
  });

  document.getElementById("zoom-in").addEventListener("click", function () { zoomAt(2, null); });
  document.getElementById("zoom-out").addEventListener("click", function () { zoomAt(0.5, null); });
  document.getElementById("zoom-fit").addEventListener("click", function () { resetView(); });

  // ------------------------------------------------------------------ viewer
  var viewer = document.getElementById("viewer");

  function buildViewer() {
    var columns = ["reference"];
    methods.forEach(function (m) { if (state.shown[m]) { var r = pick(m); if (r != null) columns.push(r); } });
    var kinds = ["rgb", "relmse", "flip"];
    if (columns.some(function (c) { return c !== "reference" && D.renders[c].count_map; })) kinds.push("count");
    var width = Math.max(viewer.clientWidth || document.body.clientWidth || 1200, 400) - 30;
    var size = Math.max(140, Math.min(360, Math.floor(width / columns.length) - 8));
    fit = Math.min(size / W, size / H);
    var cw = Math.max(1, Math.round(W * fit)), ch = Math.max(1, Math.round(H * fit));
    viewer.innerHTML = "";
    viewer.style.gridTemplateColumns = "18px repeat(" + columns.length + ", " + cw + "px)";
    panes = [];
    kinds.forEach(function (kind) {
      var name = document.createElement("div");
      name.className = "rowname"; name.textContent = KINDS[kind];
      viewer.appendChild(name);
      columns.forEach(function (column) {
        var cell = document.createElement("div");
        cell.className = "cell";
        viewer.appendChild(cell);
        if (!source(column, kind)) return;  // the reference has no error maps; samplers no sample counts
        var label = document.createElement("div");
        label.className = "label";
        var bold = document.createElement("b"), rest = document.createElement("span");
        label.appendChild(bold); label.appendChild(document.createTextNode(" ")); label.appendChild(rest);
        if (column === "reference") {
          bold.textContent = D.reference.label;
        } else {
          var r = D.renders[column];
          var sweepsSpp = D.methods.filter(function (m) { return m.name === r.method; })[0].sweeps_spp;
          bold.textContent = r.method;
          bold.style.color = colourOf[r.method];
          rest.textContent = kind === "rgb" ? r.setting + (sweepsSpp ? "" : ", " + fmtSpp(r.spp) + " spp") + ", " +
            fmtTime(r.time) : kind === "count" ? "mean " + fmtSpp(r.spp) : "mean " + fmtNum(r[kind]);
        }
        var canvas = document.createElement("canvas");
        canvas.className = "pane"; canvas.width = cw; canvas.height = ch;
        canvas.dataset.kind = kind;
        canvas.dataset.column = String(column);
        canvas.dataset.method = column === "reference" ? "reference" : D.renders[column].method;
        cell.appendChild(label); cell.appendChild(canvas);
        attach(canvas);
        panes.push(canvas);
      });
    });
    clampView();
    drawAll();
    buildScales(kinds);
    buildSpectrum(columns.filter(function (c) { return c !== "reference"; }));
  }

  // ------------------------------------------------------------------ error spectra
  var spectrumShown = [];

  function buildSpectrum(columns) {  // radial power spectra of the shown renders' luminance errors
    var box = document.getElementById("spectrum"), S = D.spectrum;
    var w = 520, h = 300, left = 62, right = 22, top = 12, bottom = 44;
    box.innerHTML = "";
    spectrumShown = [];
    var root = svg("svg", { width: w, height: h, viewBox: "0 0 " + w + " " + h, role: "img" }, box);
    var curves = columns.map(function (c) {
      var r = D.renders[c], pts = [];
      r.spectrum.forEach(function (p, i) { if (p > 0 && S.frequency[i] > 0) pts.push([S.frequency[i], p]); });
      return { render: r, pts: pts };
    }).filter(function (c) { return c.pts.length > 0; });
    if (!curves.length) {
      svg("text", { x: w / 2, y: h / 2, "text-anchor": "middle" }, root).textContent = "no error spectrum to plot";
      return;
    }
    var fs = [], ps = [];
    curves.forEach(function (c) { c.pts.forEach(function (q) { fs.push(q[0]); ps.push(q[1]); }); });
    var xr = [Math.log10(Math.min.apply(null, fs)), Math.log10(S.nyquist)], yr = decades(ps);
    function X(v) { return left + (Math.log10(v) - xr[0]) / (xr[1] - xr[0]) * (w - left - right); }
    function Y(v) { return top + (yr[1] - Math.log10(v)) / (yr[1] - yr[0]) * (h - top - bottom); }
    svg("rect", { x: left, y: top, width: Math.max(0, X(S.cutoff) - left), height: h - top - bottom,
      "class": "short" }, root);
    for (var ky = yr[0]; ky <= yr[1]; ky++) {
      svg("line", { x1: left, x2: w - right, y1: Y(Math.pow(10, ky)), y2: Y(Math.pow(10, ky)), "class": "grid" }, root);
      svg("text", { x: left - 5, y: Y(Math.pow(10, ky)) + 4, "text-anchor": "end" }, root).textContent = "1e" + ky;
    }
    [0.01, 0.02, 0.05, 0.1, 0.2, 0.5].forEach(function (f) {
      if (Math.log10(f) < xr[0]) return;
      svg("line", { x1: X(f), x2: X(f), y1: top, y2: h - bottom, "class": "grid" }, root);
      svg("text", { x: X(f), y: h - bottom + 15, "text-anchor": "middle" }, root).textContent = String(f);
    });
    svg("line", { x1: left, x2: left, y1: top, y2: h - bottom, "class": "axis" }, root);
    svg("line", { x1: left, x2: w - right, y1: h - bottom, y2: h - bottom, "class": "axis" }, root);
    svg("text", { x: (left + w - right) / 2, y: h - 8, "text-anchor": "middle" }, root).textContent =
      "frequency (cycles per pixel; Nyquist 0.5)";
    svg("text", { x: 14, y: (top + h - bottom) / 2, "text-anchor": "middle",
      transform: "rotate(-90 14 " + (top + h - bottom) / 2 + ")" }, root).textContent = "power of the luminance error";
    var legend = document.createElement("div");
    legend.className = "legend";
    curves.forEach(function (c) {
      var line = svg("polyline", { points: c.pts.map(function (q) { return X(q[0]) + "," + Y(q[1]); }).join(" "),
        fill: "none", stroke: colourOf[c.render.method], "stroke-width": 1.5, "class": "spectrum-curve" }, root);
      line.dataset.render = String(c.render.id);
      svg("title", {}, line).textContent = c.render.method + " " + c.render.setting;
      spectrumShown.push({ render: c.render.id, points: c.pts.length });
      var item = document.createElement("span"), sw = document.createElement("span");
      sw.className = "swatch"; sw.style.background = colourOf[c.render.method];
      item.appendChild(sw);
      item.appendChild(document.createTextNode(c.render.method + " " + c.render.setting + " (low-freq " +
        fmtNum(c.render.lowfreq) + ")"));
      legend.appendChild(item);
    });
    box.appendChild(legend);
  }

  function maxZoom() { return Math.max(8, 64 / fit); }  // to 64 screen pixels per image pixel (8x at least)

  function clampView() {
    view.zoom = Math.min(maxZoom(), Math.max(1, view.zoom));
    view.cx = Math.min(W, Math.max(0, view.cx));
    view.cy = Math.min(H, Math.max(0, view.cy));
  }

  function draw(canvas) {
    var ctx = canvas.getContext("2d"), s = fit * view.zoom;
    var src = source(canvas.dataset.column === "reference" ? "reference" : +canvas.dataset.column, canvas.dataset.kind);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#2a2a2a";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    ctx.imageSmoothingEnabled = false;  // nearest neighbour: single pixels stay squares
    var tx = canvas.width / 2 - view.cx * s, ty = canvas.height / 2 - view.cy * s;
    ctx.setTransform(s, 0, 0, s, tx, ty);
    ctx.drawImage(src.canvas, 0, 0);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    if (view.hover && s >= 4) {  // the hovered pixel, outlined in every pane
      ctx.strokeStyle = "rgba(255, 64, 64, 0.9)";
      ctx.lineWidth = 1;
      ctx.strokeRect(tx + view.hover[0] * s - 0.5, ty + view.hover[1] * s - 0.5, s + 1, s + 1);
    }
    canvas.drawn = { scale: s, cx: view.cx, cy: view.cy };
  }

  function drawAll() {
    panes.forEach(draw);
    document.getElementById("zoom-value").textContent = (fit * view.zoom).toPrecision(3) + " screen px per pixel";
  }

  function resetView() { view.zoom = 1; view.cx = W / 2; view.cy = H / 2; drawAll(); }

  function imagePoint(canvas, clientX, clientY) {
    var rect = canvas.getBoundingClientRect(), s = fit * view.zoom;
    var mx = (clientX - rect.left) * canvas.width / rect.width, my = (clientY - rect.top) * canvas.height / rect.height;
    return [(mx - canvas.width / 2) / s + view.cx, (my - canvas.height / 2) / s + view.cy, mx, my];
  }

  function zoomAt(factor, at) {  // at: [image x, image y, canvas x, canvas y] kept under the cursor
    var canvas = panes[0];
    var old = view.zoom;
    view.zoom = Math.min(maxZoom(), Math.max(1, view.zoom * factor));
    if (at && canvas) {
      var s = fit * view.zoom;
      view.cx = at[0] - (at[2] - canvas.width / 2) / s;
      view.cy = at[1] - (at[3] - canvas.height / 2) / s;
    }
    if (view.zoom === 1 && old !== 1) { view.cx = W / 2; view.cy = H / 2; }
    clampView();
    drawAll();
  }

  var drag = null;
  function attach(canvas) {
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      zoomAt(Math.exp(-e.deltaY * 0.002), imagePoint(canvas, e.clientX, e.clientY));
    }, { passive: false });
    canvas.addEventListener("mousedown", function (e) {
      drag = { x: e.clientX, y: e.clientY, cx: view.cx, cy: view.cy, canvas: canvas };
      e.preventDefault();
    });
    canvas.addEventListener("mousemove", function (e) {
      var p = imagePoint(canvas, e.clientX, e.clientY), x = Math.floor(p[0]), y = Math.floor(p[1]);
      view.hover = x >= 0 && y >= 0 && x < W && y < H ? [x, y] : null;
      readout();
      if (!drag) drawAll();
    });
    canvas.addEventListener("mouseleave", function () { view.hover = null; drawAll(); });
    canvas.addEventListener("dblclick", function () { resetView(); });
  }
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    var rect = drag.canvas.getBoundingClientRect(), s = fit * view.zoom * rect.width / drag.canvas.width;
    view.cx = drag.cx - (e.clientX - drag.x) / s;
    view.cy = drag.cy - (e.clientY - drag.y) / s;
    clampView();
    drawAll();
  });
  window.addEventListener("mouseup", function () { drag = null; });

  function readout() {
    var out = document.getElementById("readout");
    if (!view.hover) return;
    var x = view.hover[0], y = view.hover[1], i = y * W + x;
    var fx = D.offset + x * D.stride, fy = D.offset + y * D.stride;
    var lines = ["pixel x " + fx + ", y " + fy + (D.stride > 1 ? "  (1 in " + D.stride + " pixels in x and y shown)" : "")];
    var columns = [];
    panes.forEach(function (c) { if (c.dataset.kind === "rgb") columns.push(c.dataset.column); });
    columns.forEach(function (column) {
      var col = column === "reference" ? "reference" : +column;
      var entry = entryOf(col), rgb = source(col, "rgb").values;
      var name = column === "reference" ? "reference" : entry.method + " " + entry.setting;
      var text = (name + "                              ").slice(0, 30) + "RGB " +
        [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]].map(function (v) { return v.toFixed(4); }).join(" ");
      ["relmse", "flip", "count"].forEach(function (kind) {
        var src = col === "reference" ? null : source(col, kind);
        if (src) text += "   " + KINDS[kind] + " " + (kind === "count" ? fmtSpp(src.values[i]) : fmtNum(src.values[i]));
      });
      lines.push(text);
    });
    out.textContent = lines.join("\n");
  }

  function buildScales(kinds) {
    var box = document.getElementById("scales");
    box.innerHTML = "";
    kinds.forEach(function (kind) {
      if (kind === "rgb") return;
      var scale = D.scales[kind], table = COLORMAPS[scale.map];
      var wrap = document.createElement("div"), canvas = document.createElement("canvas");
      canvas.width = 256; canvas.height = 12; canvas.className = "colour-scale"; canvas.dataset.kind = kind;
      var ctx = canvas.getContext("2d"), img = ctx.createImageData(256, 12);
      for (var y = 0; y < 12; y++) for (var x = 0; x < 256; x++) {
        var j = 4 * (y * 256 + x);
        img.data[j] = table[3 * x]; img.data[j + 1] = table[3 * x + 1]; img.data[j + 2] = table[3 * x + 2];
        img.data[j + 3] = 255;
      }
      ctx.putImageData(img, 0, 0);
      var title = document.createElement("div");
      title.textContent = scale.label + (scale.log ? " (log scale)" : "");
      var ticks = document.createElement("div");
      ticks.className = "scale-ticks";
      var fmt = function (v) { return scale.log ? v.toExponential(1) : String(+v.toPrecision(3)); };
      var mid = scale.log ? Math.sqrt(scale.lo * scale.hi) : (scale.lo + scale.hi) / 2;
      [scale.lo, mid, scale.hi].forEach(function (v, k) {
        var t = document.createElement("span");
        t.textContent = (k === 0 && scale.log ? "≤ " : k === 2 && kind === "relmse" ? "≥ " : "") + fmt(v);
        ticks.appendChild(t);
      });
      wrap.appendChild(title); wrap.appendChild(canvas); wrap.appendChild(ticks);
      box.appendChild(wrap);
    });
  }

  // ------------------------------------------------------------------ plots
  var tooltip = document.getElementById("tooltip");
  var metricNames = { mse: "MSE", relmse: "relMSE", flip: "HDR-FLIP", lowfreq: "low-freq MSE" };

  function svg(tag, attrs, parent) {
    var el = document.createElementNS(SVGNS, tag);
    Object.keys(attrs).forEach(function (k) { el.setAttribute(k, attrs[k]); });
    if (parent) parent.appendChild(el);
    return el;
  }

  function decades(values) {
    var lo = Math.floor(Math.log10(Math.min.apply(null, values))), hi = Math.ceil(Math.log10(Math.max.apply(null, values)));
    if (hi <= lo) hi = lo + 1;
    return [lo, hi];
  }

  function tickLabel(axis, k) {
    if (axis === "time") return fmtTime(Math.pow(10, k)).replace(/\.0+ /, " ");
    if (axis === "spp") return String(Math.pow(10, k));
    return "1e" + k;
  }

  function buildPlots() {
    var box = document.getElementById("plots");
    box.innerHTML = "";
    [["time", "render time without JIT compile"], ["spp", "samples per pixel"]].forEach(function (spec) {
      box.appendChild(plot(spec[0], spec[1]));
    });
  }

  function plot(axis, xlabel) {
    var metric = state.metric, w = 520, h = 340, left = 62, right = 22, top = 12, bottom = 44;
    var pts = D.points.filter(function (p) { return p[axis] > 0 && p[metric] > 0; });
    var wrap = document.createElement("div");
    wrap.className = "plot"; wrap.dataset.axis = axis;
    var root = svg("svg", { width: w, height: h, viewBox: "0 0 " + w + " " + h, role: "img" }, wrap);
    if (!pts.length) {
      svg("text", { x: w / 2, y: h / 2, "text-anchor": "middle" }, root).textContent = "no positive values to plot";
      return wrap;
    }
    var xr = decades(pts.map(function (p) { return p[axis]; })), yr = decades(pts.map(function (p) { return p[metric]; }));
    function X(v) { return left + (Math.log10(v) - xr[0]) / (xr[1] - xr[0]) * (w - left - right); }
    function Y(v) { return top + (yr[1] - Math.log10(v)) / (yr[1] - yr[0]) * (h - top - bottom); }
    if (axis === "time" && pts.some(function (p) { return p.short; })) {
      var edge = Math.min(X(D.timing_floor), w - right);
      var shade = svg("rect", { x: left, y: top, width: Math.max(0, edge - left), height: h - top - bottom, "class": "short" }, root);
      svg("title", {}, shade).textContent = "under " + D.timing_floor_text + ": too short to time reliably";
      svg("text", { x: left + 4, y: top + 12 }, root).textContent = "< " + D.timing_floor_text + ": not timed reliably";
    }
    for (var kx = xr[0]; kx <= xr[1]; kx++) {
      svg("line", { x1: X(Math.pow(10, kx)), x2: X(Math.pow(10, kx)), y1: top, y2: h - bottom, "class": "grid" }, root);
      svg("text", { x: X(Math.pow(10, kx)), y: h - bottom + 15, "text-anchor": "middle" }, root).textContent = tickLabel(axis, kx);
    }
    for (var ky = yr[0]; ky <= yr[1]; ky++) {
      svg("line", { x1: left, x2: w - right, y1: Y(Math.pow(10, ky)), y2: Y(Math.pow(10, ky)), "class": "grid" }, root);
      svg("text", { x: left - 5, y: Y(Math.pow(10, ky)) + 4, "text-anchor": "end" }, root).textContent = tickLabel(metric, ky);
    }
    svg("line", { x1: left, x2: left, y1: top, y2: h - bottom, "class": "axis" }, root);
    svg("line", { x1: left, x2: w - right, y1: h - bottom, y2: h - bottom, "class": "axis" }, root);
    svg("text", { x: (left + w - right) / 2, y: h - 8, "text-anchor": "middle" }, root).textContent = xlabel;
    svg("text", { x: 14, y: (top + h - bottom) / 2, "text-anchor": "middle",
      transform: "rotate(-90 14 " + (top + h - bottom) / 2 + ")" }, root).textContent = metricNames[metric] + " against the reference";
    D.methods.forEach(function (m) {
      var mine = pts.filter(function (p) { return p.method === m.name; });
      if (m.sweeps_spp) mine.sort(function (a, b) { return a[axis] - b[axis]; });
      if (mine.length > 1) {
        svg("polyline", { points: mine.map(function (p) { return X(p[axis]) + "," + Y(p[metric]); }).join(" "),
          fill: "none", stroke: m.colour, "stroke-width": 1.5 }, root);
      }
    });
    D.points.forEach(function (p, index) {
      if (!(p[axis] > 0 && p[metric] > 0)) return;
      var c = svg("circle", { cx: X(p[axis]), cy: Y(p[metric]), r: 5, fill: colourOf[p.method], "class": "point" }, root);
      c.dataset.point = String(index);
      c.addEventListener("mouseenter", function (e) {
        tooltip.textContent = p.method + " · " + p.setting + " · " + fmtSpp(p.spp) + " spp · " + p.time_text +
          (p.short ? " (under " + D.timing_floor_text + ")" : "") + " · " + metricNames[metric] + " " + fmtNum(p[metric]);
        tooltip.style.display = "block";
        tooltip.style.left = (e.clientX + 12) + "px";
        tooltip.style.top = (e.clientY + 12) + "px";
      });
      c.addEventListener("mouseleave", function () { tooltip.style.display = "none"; });
      c.addEventListener("click", function () { showPoint(index, axis); });
    });
    var legend = document.createElement("div");
    legend.className = "legend";
    D.methods.forEach(function (m) {
      var item = document.createElement("span"), sw = document.createElement("span");
      sw.className = "swatch"; sw.style.background = m.colour;
      item.appendChild(sw);
      var slope = axis === "time" ? m.slope_time : m.slope_spp;
      var text = m.name;
      if (metric === "mse" && m.sweeps_spp) text += " (slope " + (slope == null ? "–" : slope.toFixed(2)) + ")";
      item.appendChild(document.createTextNode(text));
      legend.appendChild(item);
    });
    wrap.appendChild(legend);
    return wrap;
  }

  function showPoint(index, axis) {  // a clicked plot point or table row: its render in the viewer
    var p = D.points[index];
    setMode(axis === "time" ? "time" : "spp", p[axis === "time" ? "time" : "spp"]);
    state.override = {};
    state.override[p.method] = p.render;
    state.shown[p.method] = true;
    Array.prototype.forEach.call(toggles.querySelectorAll("input"), function (box) {
      if (box.dataset.method === p.method) box.checked = true;
    });
    Array.prototype.forEach.call(document.querySelectorAll(".point"), function (c) {
      c.classList.toggle("selected", c.dataset.point === String(index));
    });
    buildViewer();
    if (!selftesting) document.getElementById("viewer-section").scrollIntoView({ behavior: "smooth" });
  }

  document.getElementById("metric").addEventListener("change", function (e) {
    state.metric = e.target.value;
    buildPlots();
  });
  Array.prototype.forEach.call(document.querySelectorAll("#results tbody tr"), function (row, index) {
    row.addEventListener("click", function () { showPoint(index, "spp"); });
  });

  // ------------------------------------------------------------------ start
  var selftesting = location.hash === "#selftest";
  setMode("spp", null);
  buildPlots();
  buildViewer();
  if (selftesting) window.addEventListener("load", function () { setTimeout(selftest, 0); });

  // ------------------------------------------------------------------ self-test (tests/test_compare_html.py)
  var scratch = null;
  function readback(canvas) {  // the canvas's pixels, copied 1:1 through one canvas made for reading back
    scratch = scratch || document.createElement("canvas");
    scratch.width = canvas.width; scratch.height = canvas.height;
    var ctx = scratch.getContext("2d", { willReadFrequently: true });
    ctx.drawImage(canvas, 0, 0);
    return { data: ctx.getImageData(0, 0, canvas.width, canvas.height).data, width: canvas.width };
  }

  function painted(canvas) {  // how many pixels differ from the pane background
    var d = readback(canvas).data, n = 0;
    for (var i = 0; i < d.length; i += 4) if (d[i] !== 42 || d[i + 1] !== 42 || d[i + 2] !== 42) n++;
    return n;
  }

  function pixelAt(canvas, x, y) {
    var pixels = readback(canvas), j = 4 * (Math.floor(y) * pixels.width + Math.floor(x));
    return [pixels.data[j], pixels.data[j + 1], pixels.data[j + 2]];
  }

  function paneInfo(c) {
    return { column: c.dataset.column, method: c.dataset.method, kind: c.dataset.kind, painted: painted(c),
      width: c.width, height: c.height, scale: c.drawn.scale, cx: c.drawn.cx, cy: c.drawn.cy };
  }

  function selftest() {
    var result = { renders: [] };
    try {
      // every render of the sweep, shown in turn: its panes (render, relMSE, FLIP, samples) drawn
      D.renders.forEach(function (r) {
        state.override = {}; state.override[r.method] = r.id;
        buildViewer();
        result.renders.push({ id: r.id, method: r.method, setting: r.setting, has_count: !!r.count_map,
          panes: panes.filter(function (c) { return c.dataset.column === String(r.id); }).map(paneInfo) });
      });
      state.override = {};
      buildViewer();
      result.initial = panes.map(paneInfo);
      result.methods = methods;
      result.spectrum = spectrumShown.slice();
      result.spectrum_columns = panes.filter(function (c) { return c.dataset.kind === "rgb" && c.dataset.column !== "reference"; })
        .map(function (c) { return +c.dataset.column; });
      // zoom: a wheel event on the first method's render pane
      var first = panes.filter(function (c) { return c.dataset.kind === "rgb" && c.dataset.column !== "reference"; })[0];
      var rect = first.getBoundingClientRect();
      first.dispatchEvent(new WheelEvent("wheel", { deltaY: -1500, clientX: rect.left + rect.width * 0.3,
        clientY: rect.top + rect.height * 0.6, bubbles: true, cancelable: true }));
      result.zoomed_pane = first.dataset.column + ":" + first.dataset.kind;
      result.after_zoom = panes.map(paneInfo);
      // nearest neighbour: the image pixel under each pane's centre fills a uniform square of the
      // expected colour (exposure 0, sRGB) at this magnification
      var s = fit * view.zoom, ix = Math.floor(view.cx), iy = Math.floor(view.cy);
      result.pixel_checks = panes.map(function (c) {
        var cxs = c.width / 2, cys = c.height / 2;  // the canvas centre shows image pixel (ix, iy)
        var x0 = (ix - view.cx) * s + cxs, y0 = (iy - view.cy) * s + cys;  // that pixel's square on screen
        var src = source(c.dataset.column === "reference" ? "reference" : +c.dataset.column, c.dataset.kind);
        var corners = [];
        [[-6, -6], [6, -6], [-6, 6], [6, 6]].forEach(function (o) {
          corners.push(pixelAt(c, Math.min(x0 + s - 2, Math.max(x0 + 1, cxs + o[0])),
            Math.min(y0 + s - 2, Math.max(y0 + 1, cys + o[1]))));
        });
        return { column: c.dataset.column, kind: c.dataset.kind, expected: pixelAt(src.canvas, ix, iy),
          centre: pixelAt(c, cxs, cys), corners: corners, scale: s };
      });
      // pan: drag on another pane (the reference) moves every pane
      var ref = panes[0], r2 = ref.getBoundingClientRect();
      var x0 = r2.left + r2.width / 2, y0 = r2.top + r2.height / 2;
      ref.dispatchEvent(new MouseEvent("mousedown", { clientX: x0, clientY: y0, bubbles: true }));
      window.dispatchEvent(new MouseEvent("mousemove", { clientX: x0 + 20, clientY: y0 + 10, bubbles: true }));
      window.dispatchEvent(new MouseEvent("mouseup", { clientX: x0 + 20, clientY: y0 + 10, bubbles: true }));
      result.after_pan = panes.map(paneInfo);
      // exposure +1 EV brightens the reference (where not saturated)
      var before = pixelAt(source("reference", "rgb").canvas, ix, iy);
      exposureInput.value = "1"; exposureInput.dispatchEvent(new Event("input"));
      result.exposure = { before: before, after: pixelAt(source("reference", "rgb").canvas, ix, iy),
        value: source("reference", "rgb").values.slice(3 * (iy * W + ix), 3 * (iy * W + ix) + 3) };
      result.exposure.value = Array.prototype.slice.call(result.exposure.value);
      exposureInput.value = "0"; exposureInput.dispatchEvent(new Event("input"));
      // readout: hovering a pane names the pixel's values
      first.dispatchEvent(new MouseEvent("mousemove", { clientX: rect.left + rect.width / 2,
        clientY: rect.top + rect.height / 2, bubbles: true }));
      result.readout = document.getElementById("readout").textContent;
      // a click on the time plot's last point shows that render
      var dots = document.querySelectorAll(".plot[data-axis=time] .point");
      var dot = dots[dots.length - 1], point = D.points[+dot.dataset.point];
      dot.dispatchEvent(new MouseEvent("click", { bubbles: true }));
      result.click = { point: point.render, method: point.method, mode: state.mode,
        shown: panes.filter(function (c) { return c.dataset.method === point.method; }).map(function (c) { return +c.dataset.column; }),
        spectrum: spectrumShown.map(function (c) { return c.render; }) };
      result.plots = Array.prototype.map.call(document.querySelectorAll(".plot"), function (p) {
        return { axis: p.dataset.axis, points: p.querySelectorAll(".point").length };
      });
      result.scales = Array.prototype.map.call(document.querySelectorAll("canvas.colour-scale"), function (c) { return c.dataset.kind; });
      resetView();
    } catch (e) {
      errors.push("selftest: " + (e && e.stack ? e.stack : e));
    }
    result.errors = errors;
    result.violations = violations;
    result.resources = performance.getEntriesByType("resource").map(function (e) { return e.name; });
    var pre = document.createElement("pre");
    pre.id = "selftest-result";
    pre.textContent = JSON.stringify(result);
    document.body.appendChild(pre);
  }
})();
