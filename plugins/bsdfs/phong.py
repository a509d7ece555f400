"""The ``phong`` BSDF: the energy-normalised (modified) Phong model, written in Python."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from pointillist.plugins.bsdfs._common import safe_power, texture_range
from pointillist.plugins.properties import texture_property

__all__ = ["PhongBSDF", "PLUGIN_CLASS"]

#: Below this magnitude of ``t = log(u) / (n + 1)`` the sampler computes
#: ``1 - cos^2(alpha) = -expm1(2 t)`` from its Taylor series instead of
#: ``1 - exp(2 t)``, which cancels catastrophically in float32 for large exponents.
_EXPM1_SERIES_BELOW = 1e-3


class PhongBSDF(mi.BSDF):
    r"""Modified Phong BSDF (:monosp:`phong`)

    .. pluginparameters::

     * - diffuse_reflectance
       - |spectrum| or |texture|
       - Diffuse reflectance :math:`K_d` (default: 0.5)
       - exposed, differentiable
     * - specular_reflectance
       - |spectrum| or |texture|
       - Specular reflectance :math:`K_s` (default: 0.2)
       - exposed, differentiable
     * - exponent
       - |float| or |texture|
       - Phong exponent :math:`n \ge 0` (default: 30)
       - exposed, differentiable

    The energy-normalised Phong model (Lafortune and Willems 1994, the
    ``phong`` plugin of Mitsuba 0.5):

    .. math::

        f(\omega_i, \omega_o) = \frac{K_d}{\pi}
            + K_s \frac{n + 2}{2\pi} \max(0, r \cdot \omega_o)^n,
        \qquad r = (-\omega_{i,x}, -\omega_{i,y}, \omega_{i,z}),

    the mirror direction of :math:`\omega_i`. At normal incidence the specular
    lobe reflects exactly :math:`K_s` and the diffuse lobe :math:`K_d`; at other
    angles the horizon clips the lobe, so the albedo never exceeds
    :math:`K_d + K_s`. Physically plausible: where :math:`K_d + K_s > 1` in a
    channel both are divided by their sum in that channel (a warning is logged
    when this is detected on construction; for textures it is applied per
    texel while rendering). Derivatives: every parameter is differentiable; the
    rescale is continuous but has a kink where :math:`K_d + K_s = 1` exactly, so
    there the derivative is the one-sided one from below, the unscaled branch
    (on a tie Dr.Jit's ``maximum(Kd + Ks, 1)`` gives the gradient to the constant).

    Relation to the course's local model :math:`I = K_a I_a + K_d I_L (n \cdot l) + K_s I_L
    (r \cdot e)^n`: a BSDF is multiplied by the cosine :math:`n \cdot l` in the rendering
    equation, so one point light of intensity :math:`I_L` at distance :math:`d` contributes

    .. math::

        \frac{I_L}{d^2} \Bigl[\frac{K_d}{\pi} (n \cdot l)
            + K_s \frac{n + 2}{2\pi} (r \cdot e)^n (n \cdot l)\Bigr].

    The diffuse term is the course's divided by the constant :math:`\pi`; the specular term is
    the course's times :math:`\frac{n+2}{2\pi} (n \cdot l)`, a factor that depends on the angle
    of incidence (the course's specular term has no :math:`n \cdot l`), so no constant rescaling
    of :math:`K_s` turns one into the other. The ambient term is the ``whitted`` integrator's
    (``ambient`` :math:`I_a`, times :math:`K_d`: the course's :math:`K_a = K_d`).

    Sampling: the lobe is chosen with probability proportional to its weight
    (:math:`p_s = \bar K_s / (\bar K_d + \bar K_s)`, channel means); the
    diffuse lobe samples the cosine-weighted hemisphere, the specular lobe
    :math:`\cos^n` about :math:`r` (:math:`\cos\alpha = u^{1/(n+1)}`); the pdf is
    the mixture of both, so ``pdf`` matches ``sample`` exactly (checked with
    ``mitsuba.chi2``).

    Edges of the domain: one-sided like ``diffuse`` (0 where
    :math:`\cos\theta_i \le 0` or :math:`\cos\theta_o \le 0`); specular samples
    below the horizon get weight 0. :math:`n = 0` makes the specular lobe the
    constant :math:`K_s/\pi` (uniform sampling of the hemisphere about
    :math:`r`); :math:`n = 10^4` and above stay finite (no NaN or inf; the
    lobe is then narrower than float32 resolves near :math:`r`). A negative
    exponent raises ValueError (a texture is clamped at 0).

    .. code-block:: xml

        <bsdf type="phong">
            <rgb name="diffuse_reflectance" value="0.6, 0.1, 0.1"/>
            <float name="specular_reflectance" value="0.3"/>
            <float name="exponent" value="50"/>
        </bsdf>
    """

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.m_kd = texture_property(props, "diffuse_reflectance", 0.5)
        self.m_ks = texture_property(props, "specular_reflectance", 0.2)
        self.m_exponent = texture_property(props, "exponent", 30.0, kind="float", upper=None)
        kd_max, ks_max = texture_range(self.m_kd), texture_range(self.m_ks)
        if kd_max + ks_max > 1.0 + 1e-6:   # float32 0.2 + 0.8 is not above 1
            mi.Log(mi.LogLevel.Warn,
                   f"phong: diffuse_reflectance + specular_reflectance may exceed 1 "
                   f"(max {kd_max:g} + {ks_max:g}); both are rescaled where their sum is above 1 "
                   "so the BSDF reflects at most what arrives")
        varying = mi.BSDFFlags.SpatiallyVarying if any(
            t.is_spatially_varying() for t in (self.m_kd, self.m_ks, self.m_exponent)) else mi.BSDFFlags.Empty
        diffuse = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | varying
        glossy = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide | varying
        self.m_components = [diffuse, glossy]
        self.m_flags = diffuse | glossy

    # ------------------------------------------------------------------ helpers
    def _coefficients(self, si, active):
        """Kd, Ks (rescaled so that Kd + Ks <= 1 per channel) and the exponent n >= 0."""
        kd = self.m_kd.eval(si, active)
        ks = self.m_ks.eval(si, active)
        scale = dr.rcp(dr.maximum(kd + ks, 1.0))
        n = dr.maximum(self.m_exponent.eval_1(si, active), 0.0)
        return kd * scale, ks * scale, n

    @staticmethod
    def _specular_probability(ctx, kd, ks):
        has_diffuse = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
        has_glossy = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)
        if has_diffuse and has_glossy:
            wd, ws = dr.mean(kd), dr.mean(ks)
            total = wd + ws
            return dr.select(total > 0, ws / dr.select(total > 0, total, 1.0), 0.0)
        return mi.Float(1.0 if has_glossy else 0.0)

    @staticmethod
    def _cos_alpha(wi, wo):
        reflected = mi.Vector3f(-wi.x, -wi.y, wi.z)
        return dr.dot(reflected, wo)

    def _eval_pdf(self, ctx, si, wo, active):
        has_diffuse = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
        has_glossy = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        cos_theta_o = mi.Frame3f.cos_theta(wo)
        active = mi.Bool(active) & (cos_theta_i > 0) & (cos_theta_o > 0)
        kd, ks, n = self._coefficients(si, active)
        p_spec = self._specular_probability(ctx, kd, ks)
        value = mi.Spectrum(0.0)
        pdf = mi.Float(0.0)
        if has_diffuse:
            value += kd * dr.inv_pi
            pdf += (1.0 - p_spec) * cos_theta_o * dr.inv_pi
        if has_glossy:
            lobe = safe_power(dr.maximum(self._cos_alpha(si.wi, wo), 0.0), n)
            value += ks * ((n + 2.0) * dr.inv_two_pi * lobe)
            pdf += p_spec * (n + 1.0) * dr.inv_two_pi * lobe
        return dr.select(active, value * cos_theta_o, 0.0), dr.select(active, pdf, 0.0)

    # -------------------------------------------------------------- interface
    def sample(self, ctx, si, sample1, sample2, active=True):
        bs = dr.zeros(mi.BSDFSample3f)
        has_diffuse = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
        has_glossy = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)
        if not (has_diffuse or has_glossy):
            return bs, mi.Spectrum(0.0)
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        active = mi.Bool(active) & (cos_theta_i > 0)
        kd, ks, n = self._coefficients(si, active)
        p_spec = self._specular_probability(ctx, kd, ks)
        choose_spec = sample1 < p_spec

        wo_diffuse = mi.warp.square_to_cosine_hemisphere(sample2)

        # cos^n lobe about the mirror direction: cos(alpha) = u^(1/(n+1)).
        t = dr.log(dr.maximum(sample2.x, 1e-30)) / (n + 1.0)     # <= 0
        cos_alpha = dr.exp(t)
        two_t = 2.0 * t
        sin2_alpha = dr.select(two_t > -_EXPM1_SERIES_BELOW,
                               -two_t * (1.0 + 0.5 * two_t + two_t * two_t / 6.0),
                               1.0 - cos_alpha * cos_alpha)
        sin_alpha = dr.safe_sqrt(sin2_alpha)
        sin_phi, cos_phi = dr.sincos(dr.two_pi * sample2.y)
        reflected = mi.Vector3f(-si.wi.x, -si.wi.y, si.wi.z)
        wo_spec = mi.Frame3f(reflected).to_world(
            mi.Vector3f(sin_alpha * cos_phi, sin_alpha * sin_phi, cos_alpha))

        bs.wo = dr.select(choose_spec, wo_spec, wo_diffuse)
        bs.eta = mi.Float(1.0)
        bs.sampled_component = dr.select(choose_spec, mi.UInt32(1), mi.UInt32(0))
        bs.sampled_type = dr.select(choose_spec, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                    mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        value, pdf = self._eval_pdf(ctx, si, bs.wo, active)
        bs.pdf = pdf
        ok = active & (pdf > 0)
        return bs, dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

    def eval(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)

    def eval_diffuse_reflectance(self, si, active=True):
        return self._coefficients(si, active)[0]

    def traverse(self, callback):
        callback.put("diffuse_reflectance", self.m_kd, mi.ParamFlags.Differentiable)
        callback.put("specular_reflectance", self.m_ks, mi.ParamFlags.Differentiable)
        callback.put("exponent", self.m_exponent, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys=[]):
        pass

    def to_string(self) -> str:
        return (f"PhongBSDF[\n  diffuse_reflectance = {self.m_kd},\n"
                f"  specular_reflectance = {self.m_ks},\n  exponent = {self.m_exponent}\n]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = PhongBSDF
