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
from typing import Any, NamedTuple

import drjit as dr
import mitsuba as mi

from pointillist.imaging.arrays import divmod_u32
from pointillist.imaging.colour import REC709_LUMINANCE_WEIGHTS
from pointillist.plugins.integrators._adaptive_range import (PixelSums, Squares, first_squares, lattice_sums,
                                                            new_points, next_squares, point_counts, split_squares)
from pointillist.plugins.integrators._common import develop_film, sample_radiance
from pointillist.plugins.integrators._lanes import add_blocks, add_by_pixel, all_finite
from pointillist.plugins.properties import boolean_property, integer_property, number_property, string_property

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

#: Most rays in one batch (lane indices are 32-bit).
_MAX_LANES = 1 << 31



class _RangeRender(NamedTuple):
    """What every level of one range-criterion render shares."""

    scene: Any
    sensor: Any
    seed: int
    size: tuple[int, int]  # (width, height) of the film
    threshold: Any         # mi.Float, opaque: the range above which a square is split
    channels: int          # channels of a sample: R, G, B, alpha, the nested AOVs (not the display values)


def srgb_display(value, exposure: float = 0.0, srgb: bool = True):
    """Display value 0..255 of a linear colour: ``255 encode(clip(2^exposure value, 0, 1))``.

    ``encode`` is the sRGB transfer function (:func:`imaging.colour.srgb_encode_values`, the
    one the PNG of ``pointillist render`` goes through in :func:`imaging.io.to_8bit`), or the
    identity with ``srgb=False``. Works on Python floats and Dr.Jit arrays; in the kernel it
    computes in float32, so rounded to 8 bits it gives the PNG's byte except for values within
    float32 rounding of a half step (1 input in about 4000 near the boundaries, never more
    than 1 apart).
    """
    from pointillist.imaging.colour import srgb_encode_values

    scale = 2.0 ** exposure if isinstance(exposure, (int, float)) else dr.exp2(exposure)
    v = dr.clip(value * scale, 0.0, 1.0)
    return (srgb_encode_values(v) if srgb else v) * 255.0


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
         features thinner than a pixel that all four corners miss. The whole
         (2^m W + 1) x (2^m H + 1) lattice of ``min_depth = m`` is one batch of rays.
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

        self.criterion = string_property(props, "criterion", "range", CRITERIA)
        self.threshold = number_property(props, "threshold", 20.0, minimum=0.0, allow_inf=True)
        self.max_depth = integer_property(props, "max_depth", 3, 0, MAX_DEPTH_LIMIT)
        self.min_depth = integer_property(props, "min_depth", 0, 0, MAX_DEPTH_LIMIT)
        if self.min_depth > self.max_depth:
            raise ValueError(f"min_depth: expected at most max_depth = {self.max_depth}, got {self.min_depth}")
        self.weighting = string_property(props, "weighting", "area", WEIGHTINGS)
        self.exposure = number_property(props, "exposure", 0.0)
        self.srgb = boolean_property(props, "srgb", True)
        self.max_error = number_property(props, "max_error", 0.05, minimum=0.0, strict=True)
        self.p_value = number_property(props, "p_value", 0.05, minimum=0.0, strict=True)
        if not self.p_value < 1.0:
            raise ValueError(f"p_value: expected a number in (0, 1), got {self.p_value}")
        self.max_sample_factor = integer_property(props, "max_sample_factor", 32, 1, 1 << 16)
        self.quantile = NormalDist().inv_cdf(1.0 - self.p_value / 2.0)
        #: Statistics of the last render (rays per level, seconds tracing / total).
        self.stats: dict = {}

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
        L, valid, aux = sample_radiance(self.nested, scene, sampler, ray, medium, active)
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
        self.stats = {"criterion": self.criterion, "rays": [], "squares": [], "host_reads": 0,
                      "trace_seconds": 0.0}
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
        return develop_film(film, develop, evaluate)

    # -- tracing -------------------------------------------------------------------------
    def _trace(self, scene, sensor, sampler, position, size, diff_scale, display=False):
        """Radiance of the rays through film ``position`` (local pixel units), evaluated.

        Returns ``(channels, valid)``: ``channels`` = [R, G, B, alpha, nested AOVs...]
        (then, with ``display``, the three display values of :meth:`_display`, computed
        once per sample in the same kernel) and ``valid`` = every channel finite.
        """
        begin = time.perf_counter()
        sample2 = position * dr.rcp(mi.ScalarVector2f(size))
        aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Point2f(0.5)
        ray_time = mi.Float(sensor.shutter_open())
        if sensor.shutter_open_time() > 0:
            ray_time += sampler.next_1d() * sensor.shutter_open_time()
        ray, weight = sensor.sample_ray_differential(ray_time, 0.0, sample2, aperture)
        ray.scale_differential(diff_scale)
        L, valid, aux = sample_radiance(self.nested, scene, sampler, ray, sensor.get_medium(), True)
        L = L * weight
        channels = [L.x, L.y, L.z, dr.select(valid, 1.0, 0.0)] + [mi.Float(a) for a in aux]
        finite = all_finite(channels)
        if display:
            shown = self._display(channels)
            channels = channels + [shown.x, shown.y, shown.z]
        dr.eval(channels, finite)
        dr.sync_thread()
        self.stats["trace_seconds"] += time.perf_counter() - begin
        self.stats["rays"].append(dr.width(finite))
        return channels, finite

    def _sampler(self, sensor, seed, batch, wavefront, spp=None, *, place_rays=False):
        """The scene's sampler, forked and seeded for one batch of ``wavefront`` rays.

        ``place_rays``: the integrator places the rays itself (range criterion), so the
        film-position request (the first 2D one, a pattern sampler's image-plane pattern,
        e.g. ``grid``'s cell centres) is drawn and dropped here; otherwise the nested
        integrator's first light or BSDF sample would follow that pattern (biased).
        """
        sampler = sensor.sampler().fork()
        if spp:
            sampler.set_sample_count(spp)
        sampler.seed(dr.opaque(mi.UInt32, _batch_seed(seed, batch)), wavefront)
        if place_rays:
            sampler.next_2d()
        return sampler

    def _display(self, channels):
        """Display values 0..255 (Color3f) of a sample, NaN where it is invalid."""
        colour = mi.Color3f(channels[0], channels[1], channels[2])
        shown = srgb_display(colour, dr.opaque(mi.Float, self.exposure), self.srgb)
        return dr.select(all_finite(channels), shown, dr.nan)

    # -- range criterion ------------------------------------------------------------------
    #
    # A render is one batch of rays over the lattice of level min_depth, its pixel sums, the
    # squares of that level to split, then one _refine per level; the lane arithmetic of each
    # step is in _adaptive_range, the tracing and the statistics here. Kernel launches per
    # refinement level (every scalar that changes per level or per call is opaque, and no
    # bound is a Python literal, so nothing recompiles between levels, thresholds, seeds or
    # square counts):
    #   1. the level's squares, gathered from their parents through the compacted list,
    #      with their right / lower neighbours (O(1) look-ups in the parent level's
    #      prefix sum: a neighbour is a sibling or a child of the parent's neighbour)
    #      and their point counts (point_counts);
    #   2. an inclusive prefix sum of the counts (one host read: the ray batch size);
    #   3. the ray batch: a scatter marks where each square's points start and an
    #      inclusive prefix sum of the marks gives each lane its square (before: a
    #      binary search per lane, 30% more time per ray), then the lane places its
    #      point (new_points) and runs the nested integrator;
    #   4. per square: its five new samples, what the split adds to its pixel, the
    #      sub-squares to split next (flags), and the slots of its points (split_squares);
    #   5. per run of squares in one pixel: the sum of those additions (one lane per
    #      pixel, in order: deterministic), added into the pixel sums;
    #   6. a prefix sum of the sub-square flags (one host read: the next level's size)
    #      and the compacted list (a scatter) (next_squares).
    def _render_range(self, scene, sensor, seed, width, height) -> PixelSums:
        m = self.min_depth
        stride, rows = (width << m) + 1, (height << m) + 1
        if stride * rows >= _MAX_LANES:
            raise ValueError(f"min_depth: a {width} x {height} film split to depth {m} needs "
                             f"{stride * rows} lattice rays, more than {_MAX_LANES}")
        run = _RangeRender(scene, sensor, seed, (width, height), dr.opaque(mi.Float, self.threshold), channels=0)
        # Batch 0: the uniform lattice of level min_depth (min_depth 0: the pixel corners,
        # (W + 1) x (H + 1) rays), step h = 2^-min_depth pixels.
        ly, lx = divmod_u32(dr.arange(mi.UInt32, stride * rows), stride)
        step = dr.opaque(mi.Float, 0.5 ** m)
        sampler = self._sampler(sensor, seed, 0, stride * rows, place_rays=True)
        lattice, finite = self._trace(scene, sensor, sampler, mi.Point2f(mi.Float(lx) * step, mi.Float(ly) * step),
                                      run.size, 0.5 ** m, display=True)
        del sampler, lx, ly
        run = run._replace(channels=len(lattice) - 3)  # the last three: display values
        pixels = lattice_sums(lattice, finite, run.size, m, stride, run.channels, area=self.weighting == "area")
        if m >= self.max_depth:
            return pixels
        squares = first_squares(lattice, run.size, m, stride, run.threshold)
        self.stats["host_reads"] += 1
        del lattice, finite
        for level in range(m, self.max_depth):
            if squares is None:
                break
            squares = self._refine(run, level, squares, pixels)
        return pixels

    def _refine(self, run: _RangeRender, level: int, squares: Squares, pixels: PixelSums) -> Squares | None:
        """Split the squares of ``level`` and add what that changes to the pixel sums; returns the
        sub-squares to split at the next level (None when there are none, or at the last level)."""
        shift = dr.opaque(mi.UInt32, level)
        last_level = level + 1 >= self.max_depth
        pixel, points_of, owned_r, owned_t = point_counts(squares, shift, run.size[0])
        n = dr.width(pixel)
        o_n = dr.opaque(mi.UInt32, n)
        end = dr.cumsum(points_of)  # where each square's own points end in the ray batch
        total = int(end[n - 1])
        self.stats["host_reads"] += 1
        self.stats["squares"].append(n)
        start = end - points_of
        position = new_points(squares, start, total, level)
        sampler = self._sampler(run.sensor, run.seed, level + 1, total, place_rays=True)
        points, finite = self._trace(run.scene, run.sensor, sampler, position, run.size, 0.5 ** (level + 1),
                                     display=True)
        del sampler, position
        split = split_squares(squares, points, finite, start, end, points_of, owned_r, owned_t, shift, level,
                              run.channels, run.threshold, self.weighting, last_level)
        # 5. Sum the additions of each pixel's run of squares (sorted by pixel).
        add_by_pixel(pixels.sums + [pixels.valid_n, pixels.count], pixel, split.outputs[:run.channels + 2], o_n)
        if last_level:
            return None
        self.stats["host_reads"] += 1
        return next_squares(squares, split, points, n)

    # -- variance criterion ---------------------------------------------------------------
    def _render_variance(self, scene, sensor, seed, spp, width, height):
        spp = int(spp) if spp else int(sensor.sampler().sample_count())
        n_pixels = width * height
        wr, wg, wb = REC709_LUMINANCE_WEIGHTS  # for the variance criterion
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
            add_blocks(sums + [valid_n], active, ok + [ones], spp)
            grown = dr.gather(mi.Float, count, active) + spp
            dr.eval(grown)
            dr.scatter(count, grown, active)
            lum = wr * ok[0] + wg * ok[1] + wb * ok[2]
            if rounds == 0:  # shift of the shifted-data variance: the first round's mean
                shift = dr.select(valid_n > 0, (wr * sums[0] + wg * sums[1] + wb * sums[2]) / dr.maximum(valid_n, 1.0),
                                  0.0)
                dr.eval(shift)
            d = dr.select(finite, lum - dr.gather(mi.Float, shift, target), 0.0)
            add_blocks([s1, s2], active, [d, d * d], spp)
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



#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = AdaptiveIntegrator
