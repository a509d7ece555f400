/* The self-test of compare's report.html, injected by tests/test_compare_html.py (never shipped):
 * it runs after the page's own scripts, in their scope (pointillist.compare.html.page_script), and
 * after the page has loaded it drives the page as a user would (every render shown in turn, a
 * wheel zoom, a drag, the exposure slider, a hover, a click on a plot point) and writes what it
 * found as JSON into a new element #selftest-result. SELFTEST_VALUES (defined before this script
 * by the test) are times and linear values to format here, for the test to compare with Python.
 */
var selftestErrors = [];
var selftestViolations = [];
window.addEventListener("error", function (e) { selftestErrors.push(String(e.message || e)); });
document.addEventListener("securitypolicyviolation", function (e) {
  selftestViolations.push(e.violatedDirective + " " + e.blockedURI);
});
window.addEventListener("load", function () { setTimeout(selftest, 0); });

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

function renderPanes() {
  return viewer.panes().filter(function (c) { return c.dataset.kind === "rgb" && c.dataset.column !== "reference"; });
}

function selftest() {
  var result = { renders: [] };
  try {
    // the page's formats, for the test to compare with Python's
    result.formats = { times: SELFTEST_VALUES.times.map(Format.time), srgb: SELFTEST_VALUES.linear.map(Format.srgb8) };
    // every render of the sweep, shown in turn: its panes (render, relMSE, FLIP, samples) drawn
    D.renders.forEach(function (r) {
      viewer.state.override = {}; viewer.state.override[r.method] = r.id;
      viewer.build();
      result.renders.push({ id: r.id, method: r.method, setting: r.setting, has_count: !!r.count_map,
        panes: viewer.panes().filter(function (c) { return c.dataset.column === String(r.id); }).map(paneInfo) });
    });
    viewer.state.override = {};
    viewer.build();
    result.initial = viewer.panes().map(paneInfo);
    result.methods = viewer.methods;
    result.spectrum = plots.spectrumShown();
    result.spectrum_columns = renderPanes().map(function (c) { return +c.dataset.column; });
    // zoom: a wheel event on the first method's render pane
    var first = renderPanes()[0];
    var rect = first.getBoundingClientRect();
    first.dispatchEvent(new WheelEvent("wheel", { deltaY: -1500, clientX: rect.left + rect.width * 0.3,
      clientY: rect.top + rect.height * 0.6, bubbles: true, cancelable: true }));
    result.zoomed_pane = first.dataset.column + ":" + first.dataset.kind;
    result.after_zoom = viewer.panes().map(paneInfo);
    // nearest neighbour: the image pixel under each pane's centre fills a uniform square of the
    // expected colour (exposure 0, sRGB) at this magnification
    var view = viewer.view, s = viewer.fit() * view.zoom, ix = Math.floor(view.cx), iy = Math.floor(view.cy);
    result.pixel_checks = viewer.panes().map(function (c) {
      var cxs = c.width / 2, cys = c.height / 2;  // the canvas centre shows image pixel (ix, iy)
      var x0 = (ix - view.cx) * s + cxs, y0 = (iy - view.cy) * s + cys;  // that pixel's square on screen
      var src = viewer.source(c.dataset.column === "reference" ? "reference" : +c.dataset.column, c.dataset.kind);
      var corners = [];
      [[-6, -6], [6, -6], [-6, 6], [6, 6]].forEach(function (o) {
        corners.push(pixelAt(c, Math.min(x0 + s - 2, Math.max(x0 + 1, cxs + o[0])),
          Math.min(y0 + s - 2, Math.max(y0 + 1, cys + o[1]))));
      });
      return { column: c.dataset.column, kind: c.dataset.kind, expected: pixelAt(src.canvas, ix, iy),
        centre: pixelAt(c, cxs, cys), corners: corners, scale: s };
    });
    // pan: drag on another pane (the reference) moves every pane
    var ref = viewer.panes()[0], r2 = ref.getBoundingClientRect();
    var x0 = r2.left + r2.width / 2, y0 = r2.top + r2.height / 2;
    ref.dispatchEvent(new MouseEvent("mousedown", { clientX: x0, clientY: y0, bubbles: true }));
    window.dispatchEvent(new MouseEvent("mousemove", { clientX: x0 + 20, clientY: y0 + 10, bubbles: true }));
    window.dispatchEvent(new MouseEvent("mouseup", { clientX: x0 + 20, clientY: y0 + 10, bubbles: true }));
    result.after_pan = viewer.panes().map(paneInfo);
    // exposure +1 EV brightens the reference (where not saturated)
    var exposureInput = document.getElementById("exposure"), W = D.width;
    var before = pixelAt(viewer.source("reference", "rgb").canvas, ix, iy);
    exposureInput.value = "1"; exposureInput.dispatchEvent(new Event("input"));
    var values = viewer.source("reference", "rgb").values;
    result.exposure = { before: before, after: pixelAt(viewer.source("reference", "rgb").canvas, ix, iy),
      value: Array.prototype.slice.call(values.slice(3 * (iy * W + ix), 3 * (iy * W + ix) + 3)) };
    exposureInput.value = "0"; exposureInput.dispatchEvent(new Event("input"));
    // readout: hovering a pane names the pixel's values
    first.dispatchEvent(new MouseEvent("mousemove", { clientX: rect.left + rect.width / 2,
      clientY: rect.top + rect.height / 2, bubbles: true }));
    result.readout = document.getElementById("readout").textContent;
    // a click on the time plot's last point shows that render
    var dots = document.querySelectorAll(".plot[data-axis=time] .point");
    var dot = dots[dots.length - 1], point = D.points[+dot.dataset.point];
    dot.dispatchEvent(new MouseEvent("click", { bubbles: true }));
    result.click = { point: point.render, method: point.method, mode: viewer.state.mode,
      shown: viewer.panes().filter(function (c) { return c.dataset.method === point.method; })
        .map(function (c) { return +c.dataset.column; }),
      selected: Array.prototype.map.call(document.querySelectorAll(".point.selected"), function (c) { return +c.dataset.point; }),
      index: +dot.dataset.point,
      spectrum: plots.spectrumShown().map(function (c) { return c.render; }) };
    result.plots = Array.prototype.map.call(document.querySelectorAll(".plot"), function (p) {
      return { axis: p.dataset.axis, points: p.querySelectorAll(".point").length };
    });
    result.scales = Array.prototype.map.call(document.querySelectorAll("canvas.colour-scale"), function (c) { return c.dataset.kind; });
    viewer.resetView();
  } catch (e) {
    selftestErrors.push("selftest: " + (e && e.stack ? e.stack : e));
  }
  result.errors = selftestErrors;
  result.violations = selftestViolations;
  result.resources = performance.getEntriesByType("resource").map(function (e) { return e.name; });
  var pre = document.createElement("pre");
  pre.id = "selftest-result";
  pre.textContent = JSON.stringify(result);
  document.body.appendChild(pre);
}
