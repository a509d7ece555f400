/* pointillist compare, report.html: the plots, drawn as SVG.
 *
 * Plots(D, onPick) draws into #plots the log-log plots of the chosen error against render time
 * and against spp (one point per sweep point, hover for its numbers, click to pick it: onPick(index
 * of the point, "time" or "spp")), and into #spectrum the radially averaged power spectra of the
 * renders on show (log-log, the low-frequency band shaded).
 */
function Plots(D, onPick) {
  "use strict";
  var SVGNS = "http://www.w3.org/2000/svg";
  var METRICS = { mse: "MSE", relmse: "relMSE", flip: "HDR-FLIP", lowfreq: "low-freq MSE" };
  var colourOf = {};
  D.methods.forEach(function (m) { colourOf[m.name] = m.colour; });
  var tooltip = document.getElementById("tooltip");
  var spectrumShown = [];  // the curves of the spectrum plot: {render, points}

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
    if (axis === "time") return Format.time(Math.pow(10, k)).replace(/\.0+ /, " ");
    if (axis === "spp") return String(Math.pow(10, k));
    return "1e" + k;
  }

  function axisTitles(root, w, h, left, right, top, bottom, xlabel, ylabel) {
    svg("line", { x1: left, x2: left, y1: top, y2: h - bottom, "class": "axis" }, root);
    svg("line", { x1: left, x2: w - right, y1: h - bottom, y2: h - bottom, "class": "axis" }, root);
    svg("text", { x: (left + w - right) / 2, y: h - 8, "text-anchor": "middle" }, root).textContent = xlabel;
    svg("text", { x: 14, y: (top + h - bottom) / 2, "text-anchor": "middle",
      transform: "rotate(-90 14 " + (top + h - bottom) / 2 + ")" }, root).textContent = ylabel;
  }

  function swatch(colour, text) {
    var item = document.createElement("span"), sw = document.createElement("span");
    sw.className = "swatch"; sw.style.background = colour;
    item.appendChild(sw);
    item.appendChild(document.createTextNode(text));
    return item;
  }

  // ---------------------------------------------------------------- error against time and spp
  function build(metric) {
    var box = document.getElementById("plots");
    box.innerHTML = "";
    [["time", "render time without JIT compile"], ["spp", "samples per pixel"]].forEach(function (spec) {
      box.appendChild(plot(spec[0], spec[1], metric));
    });
  }

  function plot(axis, xlabel, metric) {
    var w = 520, h = 340, left = 62, right = 22, top = 12, bottom = 44;
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
    axisTitles(root, w, h, left, right, top, bottom, xlabel, METRICS[metric] + " against the reference");
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
        tooltip.textContent = p.method + " · " + p.setting + " · " + Format.spp(p.spp) + " spp · " + p.time_text +
          (p.short ? " (under " + D.timing_floor_text + ")" : "") + " · " + METRICS[metric] + " " + Format.number(p[metric]);
        tooltip.style.display = "block";
        tooltip.style.left = (e.clientX + 12) + "px";
        tooltip.style.top = (e.clientY + 12) + "px";
      });
      c.addEventListener("mouseleave", function () { tooltip.style.display = "none"; });
      c.addEventListener("click", function () { onPick(index, axis); });
    });
    var legend = document.createElement("div");
    legend.className = "legend";
    D.methods.forEach(function (m) {
      var slope = axis === "time" ? m.slope_time : m.slope_spp;
      var text = m.name;
      if (metric === "mse" && m.sweeps_spp) text += " (slope " + (slope == null ? "–" : slope.toFixed(2)) + ")";
      legend.appendChild(swatch(m.colour, text));
    });
    wrap.appendChild(legend);
    return wrap;
  }

  function select(index) {  // outline the points of sweep point `index` in both plots
    Array.prototype.forEach.call(document.querySelectorAll(".point"), function (c) {
      c.classList.toggle("selected", c.dataset.point === String(index));
    });
  }

  // ---------------------------------------------------------------- error spectra
  function spectrum(renders) {  // radial power spectra of these renders' luminance errors
    var box = document.getElementById("spectrum"), S = D.spectrum;
    var w = 520, h = 300, left = 62, right = 22, top = 12, bottom = 44;
    box.innerHTML = "";
    spectrumShown = [];
    var root = svg("svg", { width: w, height: h, viewBox: "0 0 " + w + " " + h, role: "img" }, box);
    var curves = renders.map(function (r) {
      var pts = [];
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
    axisTitles(root, w, h, left, right, top, bottom, "frequency (cycles per pixel; Nyquist 0.5)",
      "power of the luminance error");
    var legend = document.createElement("div");
    legend.className = "legend";
    curves.forEach(function (c) {
      var line = svg("polyline", { points: c.pts.map(function (q) { return X(q[0]) + "," + Y(q[1]); }).join(" "),
        fill: "none", stroke: colourOf[c.render.method], "stroke-width": 1.5, "class": "spectrum-curve" }, root);
      line.dataset.render = String(c.render.id);
      svg("title", {}, line).textContent = c.render.method + " " + c.render.setting;
      spectrumShown.push({ render: c.render.id, points: c.pts.length });
      legend.appendChild(swatch(colourOf[c.render.method], c.render.method + " " + c.render.setting + " (low-freq " +
        Format.number(c.render.lowfreq) + ")"));
    });
    box.appendChild(legend);
  }

  return { build: build, select: select, spectrum: spectrum,
    spectrumShown: function () { return spectrumShown.slice(); } };
}
