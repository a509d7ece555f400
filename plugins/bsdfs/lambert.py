"""The ``lambert`` BSDF: an ideal diffuse (Lambertian) reflector, written in Python."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from pointillist.plugins.properties import texture_property

__all__ = ["LambertBSDF", "PLUGIN_CLASS"]


class LambertBSDF(mi.BSDF):
    r"""Lambertian (ideal diffuse) BSDF (:monosp:`lambert`)

    .. pluginparameters::

     * - reflectance
       - |spectrum| or |texture|
       - Diffuse reflectance :math:`K_d` (default: 0.5). A constant must lie in
         [0, 1] (ValueError otherwise); a texture is used as it is.
       - exposed, differentiable

    The BSDF is :math:`f(\omega_i, \omega_o) = K_d / \pi` for directions on the
    front side of the surface; ``eval`` returns :math:`f \cos\theta_o`. Against the
    course's diffuse term :math:`K_d I_L (n \cdot l)`: a point light of intensity
    :math:`I_L` at distance :math:`d` contributes :math:`\frac{I_L}{d^2} \frac{K_d}{\pi}
    (n \cdot l)`, the course's value divided by the constant :math:`\pi` (and the
    distance falloff, which the course's point light leaves out).
    ``sample`` draws :math:`\omega_o` from the cosine-weighted hemisphere
    (pdf :math:`\cos\theta_o / \pi`), so the sample weight is exactly
    :math:`K_d`. It is the same model as Mitsuba's built-in ``diffuse`` and
    consumes the random numbers the same way (``sample2`` only), so both render
    the same image from the same seed.

    Edges of the domain: the BSDF is one-sided like ``diffuse``: where
    :math:`\cos\theta_i \le 0` (the normal faces away from the viewer) or
    :math:`\cos\theta_o \le 0` it returns 0 (value, pdf and sample weight);
    wrap it in ``twosided`` for a two-sided surface. At grazing incidence
    (:math:`\cos\theta_i \to 0^+`) the value stays finite and the sample weight
    stays :math:`K_d`.

    .. code-block:: xml

        <bsdf type="lambert">
            <rgb name="reflectance" value="0.2, 0.25, 0.7"/>
        </bsdf>
    """

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.m_reflectance = texture_property(props, "reflectance", 0.5)
        flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        if self.m_reflectance.is_spatially_varying():
            flags = flags | mi.BSDFFlags.SpatiallyVarying
        self.m_components = [flags]
        self.m_flags = flags

    def sample(self, ctx, si, sample1, sample2, active=True):
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        bs = dr.zeros(mi.BSDFSample3f)
        if not ctx.is_enabled(mi.BSDFFlags.DiffuseReflection):
            return bs, mi.Spectrum(0.0)
        active = mi.Bool(active) & (cos_theta_i > 0)
        bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
        bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
        bs.eta = mi.Float(1.0)
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
        bs.sampled_component = mi.UInt32(0)
        value = self.m_reflectance.eval(si, active)
        return bs, dr.select(active & (bs.pdf > 0), value, 0.0)

    def eval(self, ctx, si, wo, active=True):
        if not ctx.is_enabled(mi.BSDFFlags.DiffuseReflection):
            return mi.Spectrum(0.0)
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        cos_theta_o = mi.Frame3f.cos_theta(wo)
        active = mi.Bool(active) & (cos_theta_i > 0) & (cos_theta_o > 0)
        value = self.m_reflectance.eval(si, active) * dr.inv_pi * cos_theta_o
        return dr.select(active, value, 0.0)

    def pdf(self, ctx, si, wo, active=True):
        if not ctx.is_enabled(mi.BSDFFlags.DiffuseReflection):
            return mi.Float(0.0)
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        cos_theta_o = mi.Frame3f.cos_theta(wo)
        pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
        return dr.select((cos_theta_i > 0) & (cos_theta_o > 0) & active, pdf, 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        if not ctx.is_enabled(mi.BSDFFlags.DiffuseReflection):
            return mi.Spectrum(0.0), mi.Float(0.0)
        cos_theta_i = mi.Frame3f.cos_theta(si.wi)
        cos_theta_o = mi.Frame3f.cos_theta(wo)
        active = mi.Bool(active) & (cos_theta_i > 0) & (cos_theta_o > 0)
        value = self.m_reflectance.eval(si, active) * dr.inv_pi * cos_theta_o
        pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    def eval_diffuse_reflectance(self, si, active=True):
        return self.m_reflectance.eval(si, active)

    def traverse(self, callback):
        callback.put("reflectance", self.m_reflectance, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys=[]):
        pass

    def to_string(self) -> str:
        return f"LambertBSDF[\n  reflectance = {self.m_reflectance}\n]"


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = LambertBSDF
