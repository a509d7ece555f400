/* pointillist compare, report.html: the page's start. It reads the data (#report-data), makes the
 * plots (plots.js) and the viewer (viewer.js), and connects them: a click on a plot point or a
 * table row shows that render in the viewer, the error menu redraws the plots.
 */
var D = JSON.parse(document.getElementById("report-data").textContent);
var viewer = null;
var plots = Plots(D, function (index, axis) { showPoint(index, axis); });
viewer = Viewer(D, plots);

function showPoint(index, axis) {  // a picked plot point or table row: its render in the viewer
  viewer.show(D.points[index], axis);
  plots.select(index);
  document.getElementById("viewer-section").scrollIntoView({ behavior: "smooth" });
}

document.getElementById("metric").addEventListener("change", function (e) { plots.build(e.target.value); });
Array.prototype.forEach.call(document.querySelectorAll("#results tbody tr"), function (row, index) {
  row.addEventListener("click", function () { showPoint(index, "spp"); });
});

viewer.setMode("spp", null);
plots.build(document.getElementById("metric").value);
viewer.build();
