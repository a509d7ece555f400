/* pointillist compare, report.html: how the page writes times and numbers, and the sRGB encoding.
 *
 * One definition of each for the whole page. The constants are Python's, written into PAGE before
 * the scripts by pointillist/compare/html.py: the time units of pointillist.compare.tables (so a
 * time reads here as in results.md: "12.3 ms") and the sRGB transfer function of
 * pointillist.imaging.colour (so a pixel shows as in the PNG that `pointillist render --png` writes).
 * tests/test_compare_html.py checks that this script and Python agree.
 */
var Format = (function (units, rounding, srgb) {
  "use strict";

  // v with `digits` significant digits as Python's format(v, "#.{digits}g") writes it (trailing
  // zeros kept; a value exactly halfway rounds to even, where toPrecision rounds up).
  function significant(v, digits) {
    var text = v.toPrecision(digits), exact = Math.abs(v).toPrecision(digits + 25);
    var mantissa = exact.replace(/e.*$/, "").replace(".", "").replace(/^0+/, "");
    var halfway = /^\d+5(0*)$/.test(mantissa) && mantissa.replace(/0+$/, "").length === digits + 1;
    if (halfway && +mantissa.charAt(digits - 1) % 2 === 0) {  // round down to the even digit
      var step = Math.pow(10, Math.floor(Math.log10(Math.abs(v))) - digits + 1);
      text = (v - (v > 0 ? 1 : -1) * step / 2).toPrecision(digits);
    }
    return text;
  }

  // A time in seconds with three significant digits in s, ms or µs: "12.3 ms", "1.50 s", "0 s";
  // null (a missing value) is "–".
  function time(t) {
    if (t == null) return "–";
    if (t === 0) return "0 s";
    var unit = units[units.length - 1];
    for (var i = 0; i < units.length; i++) if (Math.abs(t) >= rounding * units[i][1]) { unit = units[i]; break; }
    var v = t / unit[1];
    return (Math.abs(v) >= 999.5 ? v.toFixed(0) : significant(v, 3)) + " " + unit[0];
  }

  function number(v) { return v == null ? "–" : (v === 0 ? "0" : v.toExponential(3)); }

  function spp(v) { return v == null ? "–" : String(+v.toPrecision(4)); }

  // A linear value as an 8-bit sRGB code value: clipped to [0, 1], encoded, rounded.
  function srgb8(x) {
    if (!(x > 0)) return 0;
    if (x >= 1) return 255;
    var v = x <= srgb.threshold ? srgb.slope * x : srgb.scale * Math.pow(x, 1 / srgb.exponent) - srgb.offset;
    return Math.round(255 * v);
  }

  return { time: time, number: number, spp: spp, srgb8: srgb8 };
})(PAGE.time_units, PAGE.time_unit_rounding, PAGE.srgb);
