/* pointillist compare, report.html: the data's encodings. Images come as base64 little-endian
 * float16 (pointillist.compare.html.encode_half), colour tables as hex strings of 8-bit RGB
 * (colormap_table); a colour scale maps a value to [0, 1], linearly or on a log scale.
 */
var Decode = (function () {
  "use strict";

  var HALF = new Float32Array(65536);  // every float16 bit pattern -> its value
  for (var h = 0; h < 65536; h++) {
    var e = (h >> 10) & 31, f = h & 1023, s = (h & 32768) ? -1 : 1;
    HALF[h] = e === 0 ? s * f * Math.pow(2, -24)
      : e === 31 ? (f ? NaN : s * Infinity) : s * (1 + f / 1024) * Math.pow(2, e - 15);
  }

  function half(b64) {  // base64 of little-endian float16 -> Float32Array
    var bin = atob(b64), n = bin.length >> 1, out = new Float32Array(n);
    for (var i = 0; i < n; i++) out[i] = HALF[bin.charCodeAt(2 * i) | (bin.charCodeAt(2 * i + 1) << 8)];
    return out;
  }

  function colormaps(tables) {  // {name: "rrggbb..."} -> {name: Uint8Array of r, g, b, r, ...}
    var out = {};
    Object.keys(tables).forEach(function (name) {
      var hex = tables[name], table = new Uint8Array(hex.length / 2);
      for (var i = 0; i < table.length; i++) table[i] = parseInt(hex.substr(2 * i, 2), 16);
      out[name] = table;
    });
    return out;
  }

  function scaleT(scale, v) {  // value -> [0, 1] on the scale (log or linear); NaN stays NaN
    var t = scale.log ? (Math.log(v) - Math.log(scale.lo)) / (Math.log(scale.hi) - Math.log(scale.lo))
      : (v - scale.lo) / (scale.hi - scale.lo);
    if (scale.log && v <= 0) t = 0;
    return t !== t ? NaN : Math.min(1, Math.max(0, t));
  }

  return { half: half, colormaps: colormaps, scaleT: scaleT };
})();
