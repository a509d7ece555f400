/* pointillist compare, report.html: the image viewer.
 *
 * Viewer(D, plots) shows the reference and one render per method side by side (the renders of
 * equal spp or equal time, or the ones picked), each with its relMSE and FLIP maps (and an
 * adaptive method's sample counts) as canvases that share one view: wheel to zoom (nearest
 * neighbour, down to single pixels), drag to pan, double-click to fit; exposure and the sRGB
 * encoding are applied here to the HDR data; hovering reads out the pixel's values. It asks
 * plots.spectrum(renders) to draw the error spectra of the renders on show.
 */
function Viewer(D, plots) {
  "use strict";
  var W = D.width, H = D.height, N = W * H;
  var KINDS = { rgb: "render", relmse: "relMSE", flip: "FLIP", count: "samples" };
  var COLORMAPS = Decode.colormaps(D.colormaps);
  var methods = D.methods.map(function (m) { return m.name; });
  var colourOf = {};
  D.methods.forEach(function (m) { colourOf[m.name] = m.colour; });

  // ---------------------------------------------------------------- image sources
  var sources = {};  // "reference:rgb", "3:flip", ... -> {values, canvas, kind, exposure}
  var exposure = 0;

  function entryOf(column) { return column === "reference" ? D.reference : D.renders[column]; }

  function source(column, kind) {  // the decoded image of a column (reference or render id), painted
    var key = column + ":" + kind, src = sources[key];
    if (!src) {
      var entry = entryOf(column), field = kind === "rgb" ? "rgb" : kind + "_map";
      if (!entry[field]) return null;
      var canvas = document.createElement("canvas");
      canvas.width = W; canvas.height = H;
      src = sources[key] = { values: Decode.half(entry[field]), canvas: canvas, kind: kind, exposure: null };
    }
    if (src.exposure !== (kind === "rgb" ? exposure : 0)) paint(src);
    return src;
  }

  function paint(src) {
    var ctx = src.canvas.getContext("2d"), image = ctx.createImageData(W, H), d = image.data, v = src.values;
    if (src.kind === "rgb") {
      var m = Math.pow(2, exposure), srgb8 = Format.srgb8;
      for (var i = 0, j = 0; i < N; i++, j += 4) {
        d[j] = srgb8(v[3 * i] * m); d[j + 1] = srgb8(v[3 * i + 1] * m); d[j + 2] = srgb8(v[3 * i + 2] * m);
        d[j + 3] = 255;
      }
      src.exposure = exposure;
    } else {
      var scale = D.scales[src.kind], table = COLORMAPS[scale.map];
      for (var k = 0, q = 0; k < N; k++, q += 4) {
        var t = Decode.scaleT(scale, v[k]);
        if (t !== t) { d[q] = 255; d[q + 1] = 0; d[q + 2] = 255; }  // NaN: magenta
        else { var c = 3 * Math.round(255 * t); d[q] = table[c]; d[q + 1] = table[c + 1]; d[q + 2] = table[c + 2]; }
        d[q + 3] = 255;
      }
      src.exposure = 0;
    }
    ctx.putImageData(image, 0, 0);
  }

  // ---------------------------------------------------------------- which renders are shown
  var state = { mode: "spp", target: null, shown: {}, override: {} };
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

  function pick(method) {  // the render shown for a method: picked, or the point closest to the target
    if (state.override[method] != null) return state.override[method];
    var best = null, bestD = Infinity;
    D.points.forEach(function (p) {
      if (p.method !== method || !(p[state.mode] > 0)) return;
      var d = Math.abs(Math.log(p[state.mode]) - Math.log(state.target));
      if (d < bestD) { bestD = d; best = p.render; }
    });
    return best;
  }

  function closest(values, v) {
    var best = values[0];
    values.forEach(function (x) { if (Math.abs(Math.log(x) - Math.log(v)) < Math.abs(Math.log(best) - Math.log(v))) best = x; });
    return best;
  }

  // ---------------------------------------------------------------- controls
  var targetSelect = document.getElementById("target");
  var toggles = document.getElementById("method-toggles");
  var exposureInput = document.getElementById("exposure");

  function fillTargets() {
    var values = targets(state.mode);
    targetSelect.innerHTML = "";
    values.forEach(function (v) {
      var o = document.createElement("option");
      o.value = String(v);
      var p = D.points.filter(function (q) { return q[state.mode] === v; })[0];
      o.textContent = state.mode === "spp" ? Format.spp(v) + " spp" : Format.time(v) + " (" + p.method + " " + p.setting + ")";
      targetSelect.appendChild(o);
    });
    if (state.target == null || values.indexOf(state.target) < 0) {
      state.target = closest(values, state.target == null ? values[Math.floor(values.length / 2)] : state.target);
    }
    targetSelect.value = String(state.target);
  }

  function setMode(mode, target) {  // compare at equal spp or equal time, near `target`
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
      if (old !== radio.value) build();
    });
  });
  targetSelect.addEventListener("change", function () {
    state.target = parseFloat(targetSelect.value);
    state.override = {};
    build();
  });

  methods.forEach(function (m) {
    var label = document.createElement("label"), box = document.createElement("input");
    box.type = "checkbox"; box.checked = true; box.dataset.method = m;
    box.addEventListener("change", function () { state.shown[m] = box.checked; build(); });
    var sw = document.createElement("span");
    sw.className = "swatch"; sw.style.background = colourOf[m];
    label.appendChild(box); label.appendChild(sw); label.appendChild(document.createTextNode(m));
    toggles.appendChild(label);
  });

  exposureInput.addEventListener("input", function () {
    exposure = parseFloat(exposureInput.value);
    document.getElementById("exposure-value").textContent = (exposure >= 0 ? "+" : "") + exposure.toFixed(1) + " EV";
    drawAll();
  });

  document.getElementById("zoom-in").addEventListener("click", function () { zoomAt(2, null); });
  document.getElementById("zoom-out").addEventListener("click", function () { zoomAt(0.5, null); });
  document.getElementById("zoom-fit").addEventListener("click", function () { resetView(); });

  function show(point, axis) {  // a picked sweep point (plot or table): its render, at its spp or time
    setMode(axis === "time" ? "time" : "spp", point[axis === "time" ? "time" : "spp"]);
    state.override = {};
    state.override[point.method] = point.render;
    state.shown[point.method] = true;
    Array.prototype.forEach.call(toggles.querySelectorAll("input"), function (box) {
      if (box.dataset.method === point.method) box.checked = true;
    });
    build();
  }

  // ---------------------------------------------------------------- panes
  var viewer = document.getElementById("viewer");

  function build() {
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
        cell.appendChild(label(column, kind));
        var canvas = document.createElement("canvas");
        canvas.className = "pane"; canvas.width = cw; canvas.height = ch;
        canvas.dataset.kind = kind;
        canvas.dataset.column = String(column);
        canvas.dataset.method = column === "reference" ? "reference" : D.renders[column].method;
        cell.appendChild(canvas);
        attach(canvas);
        panes.push(canvas);
      });
    });
    clampView();
    drawAll();
    buildScales(kinds);
    plots.spectrum(columns.filter(function (c) { return c !== "reference"; }).map(function (c) { return D.renders[c]; }));
  }

  function label(column, kind) {
    var div = document.createElement("div");
    div.className = "label";
    var bold = document.createElement("b"), rest = document.createElement("span");
    div.appendChild(bold); div.appendChild(document.createTextNode(" ")); div.appendChild(rest);
    if (column === "reference") {
      bold.textContent = D.reference.label;
    } else {
      var r = D.renders[column];
      var sweepsSpp = D.methods.filter(function (m) { return m.name === r.method; })[0].sweeps_spp;
      bold.textContent = r.method;
      bold.style.color = colourOf[r.method];
      rest.textContent = kind === "rgb" ? r.setting + (sweepsSpp ? "" : ", " + Format.spp(r.spp) + " spp") + ", " +
        Format.time(r.time) : kind === "count" ? "mean " + Format.spp(r.spp) : "mean " + Format.number(r[kind]);
    }
    return div;
  }

  // ---------------------------------------------------------------- one view for every pane
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
        if (src) text += "   " + KINDS[kind] + " " + (kind === "count" ? Format.spp(src.values[i]) : Format.number(src.values[i]));
      });
      lines.push(text);
    });
    out.textContent = lines.join("\n");
  }

  // ---------------------------------------------------------------- colour scales of the maps
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

  return {
    build: build, setMode: setMode, show: show, resetView: resetView, zoomAt: zoomAt, source: source,
    methods: methods, state: state, view: view,
    panes: function () { return panes.slice(); },
    fit: function () { return fit; }
  };
}
