"""The ``adaptive`` integrator: the course's adaptive super-sampling around a nested integrator.

Mitsuba renders the same number of samples in every pixel, so this plugin overrides
:meth:`render` and schedules the work itself, level by level: each refinement level
is one batch of rays over every square that still needs refinement (``dr.compress``
and gathers), never a Python loop over pixels or samples.
"""

from __future__ import annotations

import math
import time
from statistics import NormalDist

import drjit as dr
import mitsuba as mi

__all__ = ["AdaptiveIntegrator", "SAMPLE_COUNT_AOV", "CRITERIA", "WEIGHTINGS", "srgb_display"]

#: Name of the extra output channel (AOV / EXR layer) holding each pixel's sample count.
SAMPLE_COUNT_AOV = "sample_count"

#: The refinement criteria.
CRITERIA = ("range", "variance")

#: How the ``range`` criterion weights a pixel's samples.
WEIGHTINGS = ("area", "equal")

#: Deepest refinement accepted: a pixel refined to depth d holds up to (2^d + 1)^2
#: samples (depth 12: 16.8 million), and lattice coordinates must fit 32 bits.
MAX_DEPTH_LIMIT = 12

#: sRGB transfer function (IEC 61966-2-1:1999): linear segment below this value ...
SRGB_LINEAR_LIMIT = 0.0031308
#: ... with this slope, and 1.055 v^(1/2.4) - 0.055 above it.
SRGB_SLOPE = 12.92

#: New points of a refined square, on the doubled lattice of the next level, relative to
#: (2i, 2j): the midpoints of the edges y = j and x = i, the centre, the midpoints of the
#: edges x = i + 1 and y = j + 1.
_NEW_DX = (1, 0, 1, 2, 1)
_NEW_DY = (0, 1, 1, 1, 2)
#: Point on the 3 x 3 doubled lattice of a square (code u + 3 v) -> index of the new
#: point (0..4); the four corners (codes 0, 2, 6, 8) are the parent's corners.
_CODE_TO_NEW = (0, 0, 0, 1, 2, 3, 0, 4, 0)

#: Rec. 709 luminance weights (the ones ``mi.luminance`` uses), for the variance criterion.
_LUMINANCE = (0.212671, 0.715160, 0.072169)


def srgb_display(value, exposure: float = 0.0, srgb: bool = True):
    """Display value 0..255 of a linear colour: ``255 encode(clip(2^exposure value, 0, 1))``.

    The same mapping as ``imaging.io.to_8bit`` (and so the PNG of ``pointillist
    render``) before rounding; ``encode`` is the sRGB transfer function, or the
    identity with ``srgb=False``. Works on Python floats and Dr.Jit arrays.
    """
    scale = 2.0 ** exposure if isinstance(exposure, (int, float)) else dr.exp2(exposure)
    v = dr.clip(value * scale, 0.0, 1.0)
    if srgb:
        v = dr.select(v <= SRGB_LINEAR_LIMIT, SRGB_SLOPE * v,
                      1.055 * dr.power(v, 1.0 / 2.4) - 0.055)
    return v * 255.0


def _part1by1(x):
    """Spread the low 16 bits of a UInt32 to the even bits (Morton code helper)."""
    x = x & 0x0000FFFF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    x = (x | (x << 1)) & 0x55555555
    return x


def _batch_seed(seed: int, batch: int) -> int:
    """A 32-bit seed per ray batch from the render seed (splitmix-style integer hash)."""
    z = (seed * 0x9E3779B97F4A7C15 + (batch + 1) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return (z ^ (z >> 31)) & 0xFFFFFFFF


def _seed_int(seed) -> int:
    """The render seed as a Python int (Mitsuba may hand over a width-1 UInt32)."""
    if isinstance(seed, int):
        return seed
    try:
        return int(seed[0]) if dr.width(seed) >= 1 else 0
    except TypeError:
        return int(seed)


class AdaptiveIntegrator(mi.SamplingIntegrator):
    r"""
    Adaptive super-sampling (:monosp:`adaptive`)
    --------------------------------------------

    .. pluginparameters::

     * - (Nested plugin)
       - |integrator|
       - The integrator that computes the radiance along each ray (:monosp:`whitted`,
         :monosp:`path`, :monosp:`direct`, ...). Required, exactly one.
     * - criterion
       - |string|
       - ``range`` (the course's corner refinement, default) or ``variance`` (per-pixel
         confidence interval, as Mitsuba 0.6's adaptive integrator).
     * - threshold
       - |float|
       - ``range``: a square is refined when max - min of its corner colours exceeds this,
         on the display scale 0..255 (Default: 20). 0 refines every square that is not
         exactly flat; ``inf`` never refines (corner averaging).
     * - max_depth
       - |int|
       - ``range``: deepest refinement level (Default: 3). Level d splits a pixel into
         2^d x 2^d squares; 0 takes only the corner samples. At most 12.
     * - min_depth
       - |int|
       - ``range``: split every square down to this level before testing any (Default: 0,
         the course's method). 1 starts from a 3 x 3 lattice per pixel, which catches
         features thinner than a pixel that all four corners miss.
     * - weighting
       - |string|
       - ``range``: ``area`` (default) or ``equal``: how a pixel averages its samples
         (see *Weighting* below).
     * - exposure
       - |float|
       - ``range``: exposure in stops applied before the display mapping (Default: 0),
         i.e. the display value is ``255 encode(clip(2^exposure L, 0, 1))``.
     * - srgb
       - |bool|
       - ``range``: ``encode`` is the sRGB transfer function (Default: true, as in the
         PNG that ``pointillist render --png`` writes); false: linear.
     * - max_error
       - |float|
       - ``variance``: stop when the confidence interval half-width of the pixel's mean
         luminance is at most this fraction of the mean (Default: 0.05).
     * - p_value
       - |float|
       - ``variance``: the interval is the (1 - p_value) two-sided normal one
         (Default: 0.05, i.e. +-1.96 standard errors).
     * - max_sample_factor
       - |int|
       - ``variance``: at most this many times the sampler's sample count per pixel
         (Default: 32).

    **Range criterion (the course's method).** Rays go through every pixel corner
    (shared by neighbours: a W x H image starts with (W + 1) x (H + 1) rays). A pixel
    whose four corner colours differ by at most ``threshold`` (the largest per-channel
    max - min of the display values) takes their average. Otherwise the edge midpoints
    and the centre are added, the square splits into four, and each sub-square whose
    corners still differ by more than ``threshold`` is split again, down to
    ``max_depth``. Each level is one batch of rays over all squares being split. Every
    lattice point is traced once: corners and midpoints shared by two squares that are
    both refined are traced once and reused.

    *Weighting.* A pixel is the average of all its samples; how much each one counts:

    - ``area`` (default): every unsplit (leaf) square contributes the mean of its four
      corners times its area, i.e. the trapezoidal rule on the pixel's quadtree. A
      sample shared by several leaf squares counts once for each, a quarter of each
      square's area; a corner shared by four pixels counts 1/4 in each of them (the
      weights of a sample over all pixels add up to the area around it). With
      ``threshold = 0`` on a scene that varies everywhere this is the trapezoidal rule
      on the uniform (2^d + 1) x (2^d + 1) lattice of the pixel.
    - ``equal``: the course's plain mean of the distinct sample positions of the pixel's
      own refinement (its four corners and the points its splits added), each with
      weight 1, whether or not a neighbouring pixel uses the same sample too. With
      ``threshold = 0`` it is the plain mean of the uniform lattice. Refined areas are
      over-weighted: a pixel with an edge near one side is pulled toward the colour
      along the edge (on a vertical edge 1/5 of the way across, about 0.5 instead of
      0.2 at depth 3), which is why it is not the default.

    With ``threshold = inf`` (or ``max_depth = 0``) both are the mean of the four
    corners. The image-plane positions are deterministic; the nested integrator's other
    random numbers come from the scene's sampler, forked and seeded per level from
    ``seed`` (same seed, same image). The sampler's sample count is not used.

    **Variance criterion.** Every pixel first takes the sampler's ``spp`` samples
    (image-plane positions from the sampler, e.g. :monosp:`jitter`); then, in rounds of
    ``spp`` more samples for all pixels still active at once, a pixel stops when
    ``z sqrt(var / n) <= max_error |mean|`` for its luminance samples (z the normal
    quantile of ``1 - p_value / 2``) or when it holds ``max_sample_factor * spp``
    samples. The pixel is the mean of its samples. As in Mitsuba 0.6, stopping on the
    running estimate biases the result slightly toward pixels that stopped early.

    **Outputs.** The film's channels, then the nested integrator's AOVs (averaged like
    the colour), then :data:`SAMPLE_COUNT_AOV`: the number of rays the pixel's average
    used (``pointillist render`` writes it as an EXR layer and, with ``--png``, a heat
    map). The image is written through a box filter whatever the film's
    ``rfilter`` (uneven sample densities under a wide filter bias edges).

    **Edges of the domain.** A 1 x 1 image takes 4 corner rays. ``max_depth = 0`` is
    corner averaging. A huge or infinite threshold never refines. Invalid samples
    (NaN or +-inf in any channel, Mitsuba's "invalid sample") count as taken in the
    sample count but get weight 0 in the average and are ignored by the range; a pixel
    without a valid sample is 0. Radiance above the display range clips at 255, so two
    corners of 10 and 1e30 differ by 0 at exposure 0 (both white). Negative radiance
    clips to 0 on the display scale and is averaged as is.

    .. tabs::
        .. code-tab:: xml

            <integrator type="adaptive">
                <float name="threshold" value="20"/>
                <integer name="max_depth" value="3"/>
                <integrator type="direct"/>
            </integrator>

        .. code-tab:: python

            'type': 'adaptive',
            'threshold': 20.0,
            'max_depth': 3,
            'nested': {'type': 'direct'}
    """

    PLUGIN_NAME = "adaptive"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        nested = []
        for name in props.keys():
            value = props[name]
            if isinstance(value, mi.Object) and isinstance(value, mi.Integrator):
                nested.append(value)
        if len(nested) != 1:
            raise ValueError(f"adaptive: expected exactly one nested integrator, got {len(nested)}")
        if not isinstance(nested[0], mi.SamplingIntegrator):
            raise TypeError("adaptive: the nested integrator must be a sampling integrator "
                            f"(path, direct, whitted, ...), got {type(nested[0]).__name__}")
        if isinstance(nested[0], AdaptiveIntegrator):
            raise ValueError("adaptive: the nested integrator cannot be another adaptive integrator")
        self.nested = nested[0]

        self.criterion = self._string(props, "criterion", "range")
        if self.criterion not in CRITERIA:
            raise ValueError(f"criterion: expected one of {', '.join(CRITERIA)}, got {self.criterion!r}")
        self.threshold = self._number(props, "threshold", 20.0, minimum=0.0, allow_inf=True)
        self.max_depth = self._integer(props, "max_depth", 3, 0, MAX_DEPTH_LIMIT)
        self.min_depth = self._integer(props, "min_depth", 0, 0, MAX_DEPTH_LIMIT)
        if self.min_depth > self.max_depth:
            raise ValueError(f"min_depth: expected at most max_depth = {self.max_depth}, got {self.min_depth}")
        self.weighting = self._string(props, "weighting", "area")
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"weighting: expected one of {', '.join(WEIGHTINGS)}, got {self.weighting!r}")
        self.exposure = self._number(props, "exposure", 0.0)
        self.srgb = self._boolean(props, "srgb", True)
        self.max_error = self._number(props, "max_error", 0.05, minimum=0.0, strict=True)
        self.p_value = self._number(props, "p_value", 0.05, minimum=0.0, strict=True)
        if not self.p_value < 1.0:
            raise ValueError(f"p_value: expected a number in (0, 1), got {self.p_value}")
        self.max_sample_factor = self._integer(props, "max_sample_factor", 32, 1, 1 << 16)
        self.quantile = NormalDist().inv_cdf(1.0 - self.p_value / 2.0)
        #: Statistics of the last render (rays per level, seconds tracing / total).
        self.stats: dict = {}

    # -- property parsing ---------------------------------------------------------------
    @staticmethod
    def _string(props, name, default):
        value = props.get(name, default) if name in props else default
        if not isinstance(value, str):
            raise TypeError(f"{name}: expected a string, got {type(value).__name__}")
        return value

    @staticmethod
    def _boolean(props, name, default):
        value = props[name] if name in props else default
        if not isinstance(value, bool):
            raise TypeError(f"{name}: expected a boolean, got {type(value).__name__}")
        return value

    @staticmethod
    def _number(props, name, default, minimum=None, strict=False, allow_inf=False):
        value = props[name] if name in props else default
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f"{name}: expected a number, got {type(value).__name__}")
        value = float(value)
        if math.isnan(value) or (math.isinf(value) and not allow_inf):
            raise ValueError(f"{name}: expected a finite number, got {value}")
        if minimum is not None and (value < minimum or (strict and value == minimum)):
            relation = ">" if strict else ">="
            raise ValueError(f"{name}: expected a number {relation} {minimum:g}, got {value:g}")
        return value

    @staticmethod
    def _integer(props, name, default, minimum, maximum):
        value = props[name] if name in props else default
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
        if not minimum <= value <= maximum:
            raise ValueError(f"{name}: expected an integer in {minimum}..{maximum}, got {value}")
        return value

    # -- Mitsuba interface --------------------------------------------------------------
    def aov_names(self):
        return list(self.nested.aov_names()) + [SAMPLE_COUNT_AOV]

    def to_string(self):
        if self.criterion == "range":
            detail = (f"threshold={self.threshold:g}, max_depth={self.max_depth}, min_depth={self.min_depth}, "
                      f"exposure={self.exposure:g}, srgb={self.srgb}")
        else:
            detail = (f"max_error={self.max_error:g}, p_value={self.p_value:g}, "
                      f"max_sample_factor={self.max_sample_factor}")
        return f"AdaptiveIntegrator[criterion={self.criterion}, {detail}, nested={self.nested}]"

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """One sample of the nested integrator (the adaptive schedule lives in :meth:`render`)."""
        L, valid, aux = self.nested.sample(scene, sampler, ray, medium, active)
        return L, valid, list(aux) + [mi.Float(1.0)]

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        seed = _seed_int(seed)
        film = sensor.film()
        names = self.aov_names()
        channel_count = film.prepare(names)
        width, height = (int(v) for v in film.crop_size())
        start = time.perf_counter()
        self.stats = {"criterion": self.criterion, "rays": [], "trace_seconds": 0.0}
        with dr.suspend_grad():
            if self.criterion == "range":
                channels, valid_n, count = self._render_range(scene, sensor, seed, width, height)
            else:
                channels, valid_n, count = self._render_variance(scene, sensor, seed, spp, width, height)
        # Pixel values: mean of the valid samples (0 where there is none).
        inv = dr.select(valid_n > 0, dr.rcp(valid_n), 0.0)
        values = [c * inv for c in channels]
        color, alpha, aux = values[:3], values[3], values[4:]
        planes = list(color)
        if mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
            planes.append(alpha)
        planes.append(dr.full(mi.Float, 1.0, width * height))  # weight channel
        planes.extend(aux)
        planes.append(mi.Float(count))
        if len(planes) != channel_count:
            raise RuntimeError(f"adaptive: film {film.class_name()} expects {channel_count} channels, "
                               f"the adaptive integrator produces {len(planes)} (RGB films only)")
        data = dr.zeros(mi.Float, width * height * channel_count)
        base = dr.arange(mi.UInt32, width * height) * channel_count
        for index, plane in enumerate(planes):
            dr.scatter(data, plane, base + index)
        block = mi.ImageBlock(mi.TensorXf(data, (height, width, channel_count)), film.crop_offset())
        film.put_block(block)
        self.stats["total_seconds"] = time.perf_counter() - start
        if not develop:
            return mi.TensorXf()
        image = film.develop()
        if evaluate:
            dr.eval(image)
        return image

    # -- tracing -------------------------------------------------------------------------
    def _trace(self, scene, sensor, sampler, position, size, diff_scale):
        """Radiance of the rays through film ``position`` (local pixel units), evaluated.

        Returns ``(channels, valid)``: ``channels`` = [R, G, B, alpha, nested AOVs...]
        and ``valid`` = every channel finite.
        """
        begin = time.perf_counter()
        sample2 = position * dr.rcp(mi.ScalarVector2f(size))
        aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Point2f(0.5)
        ray_time = mi.Float(sensor.shutter_open())
        if sensor.shutter_open_time() > 0:
            ray_time += sampler.next_1d() * sensor.shutter_open_time()
        ray, weight = sensor.sample_ray_differential(ray_time, 0.0, sample2, aperture)
        ray.scale_differential(diff_scale)
        L, valid, aux = self.nested.sample(scene, sampler, ray, sensor.get_medium(), True)
        L = L * weight
        channels = [L.x, L.y, L.z, dr.select(valid, 1.0, 0.0)] + [mi.Float(a) for a in aux]
        finite = _finite(channels)
        dr.eval(channels, finite)
        dr.sync_thread()
        self.stats["trace_seconds"] += time.perf_counter() - begin
        self.stats["rays"].append(dr.width(finite))
        return channels, finite

    def _sampler(self, sensor, seed, batch, wavefront, spp=None):
        sampler = sensor.sampler().fork()
        if spp:
            sampler.set_sample_count(spp)
        sampler.seed(dr.opaque(mi.UInt32, _batch_seed(seed, batch)), wavefront)
        return sampler

    def _display(self, channels):
        """Display values 0..255 (Color3f) of a sample, NaN where it is invalid."""
        colour = mi.Color3f(channels[0], channels[1], channels[2])
        shown = srgb_display(colour, dr.opaque(mi.Float, self.exposure), self.srgb)
        return dr.select(_finite(channels), shown, dr.nan)

    # -- range criterion ------------------------------------------------------------------
    def _render_range(self, scene, sensor, seed, width, height):
        size = (width, height)
        threshold = dr.opaque(mi.Float, self.threshold)
        n_pixels = width * height

        # Level 0: the (W + 1) x (H + 1) pixel corners, one batch.
        stride = width + 1
        lattice = dr.arange(mi.UInt32, stride * (height + 1))
        ly = lattice // stride
        lx = lattice - ly * stride
        sampler = self._sampler(sensor, seed, 0, dr.width(lattice))
        corners, finite = self._trace(scene, sensor, sampler, mi.Point2f(mi.Float(lx), mi.Float(ly)),
                                      size, 1.0)
        del sampler, lattice, lx, ly

        pixel = dr.arange(mi.UInt32, n_pixels)
        py = pixel // width
        px = pixel - py * width
        c00 = px + py * stride
        ids = (c00, c00 + 1, c00 + stride, c00 + stride + 1)
        quad = [[dr.gather(mi.Float, channel, index) for channel in corners] for index in ids]
        # Each corner weighs 1/4 of the pixel (area) or 1 (equal): the same mean.
        sums = [mi.Float(0.0) for _ in corners]
        valid_n = mi.Float(0.0)
        for values in quad:
            ok = _finite(values)
            for c, value in enumerate(values):
                sums[c] += dr.select(ok, value, 0.0)
            valid_n += dr.select(ok, 1.0, 0.0)
        count = dr.full(mi.Float, 4.0, n_pixels)
        dr.eval(sums, valid_n, count)
        if self.max_depth == 0:
            return sums, valid_n, count
        if self.weighting == "area":
            sums = [s * 0.25 for s in sums]
            valid_n = valid_n * 0.25
            dr.eval(sums, valid_n)

        active = _spread([self._display(values) for values in quad]) > threshold
        if self.min_depth > 0:
            active |= True
        sel = dr.compress(active)
        i, j = dr.gather(mi.UInt32, px, sel), dr.gather(mi.UInt32, py, sel)
        key = mi.UInt64(dr.gather(mi.UInt32, pixel, sel))
        quad = [[dr.gather(mi.Float, value, sel) for value in values] for values in quad]
        dr.eval(i, j, key, quad)
        del sel, active, corners, finite, pixel, px, py, c00, ids

        for level in range(self.max_depth):
            if dr.width(key) == 0:
                break
            i, j, key, quad = self._refine(scene, sensor, seed, size, level, i, j, key, quad,
                                           sums, valid_n, count, threshold)
        return sums, valid_n, count

    def _refine(self, scene, sensor, seed, size, level, i, j, key, quad, sums, valid_n, count,
                threshold):
        """Split the ``n`` squares of ``level`` (coords ``i, j``, sorted ``key``, corner
        channels ``quad``): trace their new points, update the pixel sums, and return the
        sub-squares that must be split at the next level."""
        width, height = size
        n = dr.width(key)
        shift = dr.opaque(mi.UInt32, level)
        cells_x = dr.opaque(mi.UInt32, width << level)
        cells_y = dr.opaque(mi.UInt32, height << level)

        # Neighbours being split at the same level: the square to the right (x + 1) and
        # below (y + 1) own the midpoint of the shared edge; found by binary search in the
        # sorted keys (pixel index, then Morton order inside the pixel).
        def lookup(ni, nj, inside):
            target = _square_key(ni, nj, shift, width)
            index = mi.UInt32(dr.binary_search(0, n - 1, lambda k: dr.gather(mi.UInt64, key, k) < target))
            found = inside & (dr.gather(mi.UInt64, key, index) == target)
            return found, index

        found_r, index_r = lookup(i + 1, j, i + 1 < cells_x)
        found_t, index_t = lookup(i, j + 1, j + 1 < cells_y)
        same_r = ((i + 1) >> shift) == (i >> shift)
        same_t = ((j + 1) >> shift) == (j >> shift)
        dr.eval(found_r, index_r, found_t, index_t, same_r, same_t)

        # Lane 5 s + k: new point k of square s. Traced unless a neighbour owns it.
        lane = dr.arange(mi.UInt32, 5 * n)
        s = lane // 5
        k = lane - 5 * s
        owned_r = ~dr.gather(mi.Bool, found_r, s)
        owned_t = ~dr.gather(mi.Bool, found_t, s)
        traced = (k < 3) | ((k == 3) & owned_r) | ((k == 4) & owned_t)
        slot = dr.prefix_sum(dr.select(traced, mi.UInt32(1), mi.UInt32(0)))  # exclusive
        dr.eval(traced, slot)
        # The slot of a shared point is the owning neighbour's (its k = 1 or k = 0 point).
        right = k == 3
        owner = dr.select(right, dr.gather(mi.UInt32, index_r, s), dr.gather(mi.UInt32, index_t, s))
        slot = dr.select(traced, slot, dr.gather(mi.UInt32, slot, 5 * owner + dr.select(right, 1, 0), ~traced))
        dr.eval(slot)
        del owner, right

        # Trace the owned points: one batch for the whole level.
        which = dr.compress(traced)
        ws = which // 5
        wk = which - 5 * ws
        dx = dr.gather(mi.UInt32, mi.UInt32(_NEW_DX), wk)
        dy = dr.gather(mi.UInt32, mi.UInt32(_NEW_DY), wk)
        step = dr.opaque(mi.Float, 0.5 ** (level + 1))
        gx = 2 * dr.gather(mi.UInt32, i, ws) + dx
        gy = 2 * dr.gather(mi.UInt32, j, ws) + dy
        position = mi.Point2f(mi.Float(gx) * step, mi.Float(gy) * step)
        sampler = self._sampler(sensor, seed, level + 1, dr.width(which))
        points, finite = self._trace(scene, sensor, sampler, position, size, 0.5 ** (level + 1))
        del sampler, which, ws, wk, dx, dy, gx, gy, position

        # What the split adds to its pixel, per square (one lane each, so the sums are
        # deterministic: no floating-point atomics whose order varies between runs).
        # Sample count: each distinct position once per pixel. A point on the edge shared
        # with a split neighbour in the same pixel is counted by the neighbour (as its
        # k = 0 / 1 point); across a pixel border both pixels count it.
        distinct = [True, True, True, ~found_r | ~same_r, ~found_t | ~same_t]
        area = dr.opaque(mi.Float, 0.25 ** level)
        deltas = [mi.Float(0.0) for _ in points]
        weight_sum = mi.Float(0.0)
        new_count = mi.Float(3.0) + dr.select(distinct[3], 1.0, 0.0) + dr.select(distinct[4], 1.0, 0.0)
        base = 5 * dr.arange(mi.UInt32, n)
        for k in range(5):
            index = dr.gather(mi.UInt32, slot, base + k)
            ok = dr.gather(mi.Bool, finite, index)
            if self.weighting == "equal":
                ok &= distinct[k]
                weight = mi.Float(1.0)
            else:  # area: edge midpoints gain A/8, the centre A/4 (A: the square's area) ...
                weight = (0.25 if k == 2 else 0.125) * area
            for c, channel in enumerate(points):
                deltas[c] += dr.select(ok, weight * dr.gather(mi.Float, channel, index), 0.0)
            weight_sum += dr.select(ok, weight, 0.0)
        if self.weighting == "area":  # ... and each corner goes from A/4 to A/16.
            minus = -3.0 / 16.0 * area
            for values in quad:
                good = _finite(values)
                for c, value in enumerate(values):
                    deltas[c] += dr.select(good, minus * value, 0.0)
                weight_sum += dr.select(good, minus, 0.0)
        pixel = (j >> shift) * width + (i >> shift)
        _add_by_segment(sums + [valid_n, count], pixel, deltas + [weight_sum, new_count])
        del deltas, weight_sum, new_count, pixel, base
        if level + 1 >= self.max_depth:
            return mi.UInt32(), mi.UInt32(), mi.UInt64(), []

        # The four sub-squares of every split square; keep those that still differ.
        lane = dr.arange(mi.UInt32, 4 * n)
        s = lane >> 2
        q = lane & 3
        cx, cy = q & 1, q >> 1
        sub = []
        for a, b in ((0, 0), (1, 0), (0, 1), (1, 1)):
            u, v = cx + a, cy + b
            corner = ((u & 1) == 0) & ((v & 1) == 0)
            parent = (v >> 1) * 2 + (u >> 1)
            new = dr.gather(mi.UInt32, mi.UInt32(_CODE_TO_NEW), u + 3 * v)
            from_points = dr.gather(mi.UInt32, slot, 5 * s + new, ~corner)
            values = []
            for c, channel in enumerate(points):
                value = dr.gather(mi.Float, channel, from_points, ~corner)
                for p in range(4):
                    value = dr.select(corner & (parent == p), dr.gather(mi.Float, quad[p][c], s), value)
                values.append(value)
            sub.append(values)
        keep = _spread([self._display(values) for values in sub]) > threshold
        if level + 1 < self.min_depth:
            keep |= True
        dr.eval(sub, keep)
        sel = dr.compress(keep)
        ps = sel >> 2
        pq = sel & 3
        i = 2 * dr.gather(mi.UInt32, i, ps) + (pq & 1)
        j = 2 * dr.gather(mi.UInt32, j, ps) + (pq >> 1)
        key = dr.gather(mi.UInt64, key, ps) * 4 + mi.UInt64(pq)
        quad = [[dr.gather(mi.Float, value, sel) for value in values] for values in sub]
        dr.eval(i, j, key, quad)
        return i, j, key, quad

    # -- variance criterion ---------------------------------------------------------------
    def _render_variance(self, scene, sensor, seed, spp, width, height):
        spp = int(spp) if spp else int(sensor.sampler().sample_count())
        n_pixels = width * height
        limit = self.max_sample_factor * spp
        sums = None
        valid_n = dr.zeros(mi.Float, n_pixels)
        count = dr.zeros(mi.Float, n_pixels)
        shift = dr.zeros(mi.Float, n_pixels)
        s1 = dr.zeros(mi.Float, n_pixels)
        s2 = dr.zeros(mi.Float, n_pixels)
        active = dr.arange(mi.UInt32, n_pixels)
        rounds = 0
        while dr.width(active) > 0:
            lanes = dr.width(active) * spp
            lane = dr.arange(mi.UInt32, lanes)
            target = dr.gather(mi.UInt32, active, lane // dr.opaque(mi.UInt32, spp))
            py = target // width
            px = target - py * width
            sampler = self._sampler(sensor, seed, rounds, lanes, spp)
            position = mi.Point2f(mi.Float(px), mi.Float(py)) + sampler.next_2d()
            channels, finite = self._trace(scene, sensor, sampler, position, (width, height),
                                           1.0 / math.sqrt(spp))
            del sampler
            if sums is None:
                sums = [dr.zeros(mi.Float, n_pixels) for _ in channels]
            # Per-pixel sums of this round: each active pixel owns spp consecutive lanes.
            ok = [dr.select(finite, channel, 0.0) for channel in channels]
            ones = dr.select(finite, 1.0, 0.0)
            _add_blocks(sums + [valid_n], active, ok + [ones], spp)
            grown = dr.gather(mi.Float, count, active) + spp
            dr.eval(grown)
            dr.scatter(count, grown, active)
            lum = _LUMINANCE[0] * ok[0] + _LUMINANCE[1] * ok[1] + _LUMINANCE[2] * ok[2]
            if rounds == 0:  # shift of the shifted-data variance: the first round's mean
                shift = dr.select(valid_n > 0, (_LUMINANCE[0] * sums[0] + _LUMINANCE[1] * sums[1]
                                                + _LUMINANCE[2] * sums[2]) / dr.maximum(valid_n, 1.0), 0.0)
                dr.eval(shift)
            d = dr.select(finite, lum - dr.gather(mi.Float, shift, target), 0.0)
            _add_blocks([s1, s2], active, [d, d * d], spp)
            dr.eval(count)
            rounds += 1
            nv = dr.maximum(valid_n, 1.0)
            mean = shift + s1 / nv
            var = dr.maximum(s2 - s1 * s1 / nv, 0.0) / dr.maximum(valid_n - 1.0, 1.0)
            half_width = dr.opaque(mi.Float, self.quantile) * dr.sqrt(var / nv)
            converged = (valid_n >= 2) & (half_width <= dr.opaque(mi.Float, self.max_error) * dr.abs(mean))
            more = ~converged & (count + spp <= limit)
            active = dr.compress(more)
        self.stats["rounds"] = rounds
        return sums, valid_n, count


def _add_blocks(totals, owner, values, block: int) -> None:
    """``totals[c][owner[b]] +=`` the sum of block ``b`` (``block`` consecutive lanes) of
    ``values[c]``, in place; ``owner`` holds unique indices. Deterministic (no atomics)."""
    updated = [dr.gather(mi.Float, total, owner) + dr.block_sum(value, block)
               for total, value in zip(totals, values)]
    dr.eval(updated)
    for total, value in zip(totals, updated):
        dr.scatter(total, value, owner)
    dr.eval(totals)


def _add_by_segment(totals, owner, values) -> None:
    """``totals[c][owner[s]] += values[c][s]`` for ``owner`` sorted ascending, in place.

    Deterministic: each run of equal owners is summed in order by one lane of a
    symbolic loop, then written with a plain scatter (the owners are then unique).
    """
    n = dr.width(owner)
    if n == 0:
        return
    index = dr.arange(mi.UInt32, n)
    first = (index == 0) | (owner != dr.gather(mi.UInt32, owner, index - 1, index > 0))
    starts = dr.compress(first)
    m = dr.width(starts)
    ends = dr.gather(mi.UInt32, starts, dr.arange(mi.UInt32, m) + 1, dr.arange(mi.UInt32, m) + 1 < m)
    ends = dr.select(dr.arange(mi.UInt32, m) + 1 < m, ends, n)
    target = dr.gather(mi.UInt32, owner, starts)

    def cond(i, *partial):
        return i < ends

    def body(i, *partial):
        return (i + 1, *[p + dr.gather(mi.Float, v, i) for p, v in zip(partial, values)])

    state = dr.while_loop(state=(mi.UInt32(starts), *[dr.zeros(mi.Float, m) for _ in values]),
                          cond=cond, body=body, label="adaptive_segment_sum")
    updated = [dr.gather(mi.Float, total, target) + partial for total, partial in zip(totals, state[1:])]
    dr.eval(updated)
    for total, value in zip(totals, updated):
        dr.scatter(total, value, target)
    dr.eval(totals)


def _finite(channels) -> mi.Bool:
    """True where every channel of a sample is finite (neither NaN nor +-inf)."""
    ok = dr.isfinite(channels[0])
    for channel in channels[1:]:
        ok &= dr.isfinite(channel)
    return ok


def _spread(quad) -> mi.Float:
    """Largest per-channel max - min of four display colours, ignoring NaN (invalid)
    entries; 0 when fewer than one entry is valid."""
    low = mi.Color3f(dr.inf)
    high = mi.Color3f(-dr.inf)
    for value in quad:
        ok = ~dr.isnan(value)
        low = dr.select(ok, dr.minimum(low, value), low)
        high = dr.select(ok, dr.maximum(high, value), high)
    spread = dr.select(high >= low, high - low, 0.0)
    return dr.maximum(dr.maximum(spread.x, spread.y), spread.z)


def _square_key(i, j, shift, width):
    """Sort key of square (i, j) of a level: pixel index (row-major), then the Morton code
    of the square inside its pixel (so the four children of a square follow it in order)."""
    mask = (mi.UInt32(1) << shift) - 1
    local = _part1by1(i & mask) | (_part1by1(j & mask) << 1)
    pixel = (j >> shift) * width + (i >> shift)
    return (mi.UInt64(pixel) << mi.UInt64(2 * shift)) | mi.UInt64(local)


PLUGIN_NAME = AdaptiveIntegrator.PLUGIN_NAME
PLUGIN_CLASS = AdaptiveIntegrator
