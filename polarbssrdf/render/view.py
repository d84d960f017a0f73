"""One light-stage view: a skin-covered mesh, one camera and its coaxial light, in one band.

The glossy lobes of ``pbssrdf`` reflect the light; the subsurface light
leaves through a ``pexitance`` emitter carrying the texture-space diffused
exitance (:mod:`polarbssrdf.render.subsurface`), so ``pbssrdf``'s own
subsurface albedo is 0. All maps follow the package's texture convention
(:mod:`polarbssrdf.geometry`) and are float32 (T, T) arrays.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.geometry import to_mitsuba
from polarbssrdf.render.stokes_images import analyser_images, render_channel_names, split_stokes

GLOSSY_MAPS = ("eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss")


def map_texture(values):
    """A Mitsuba ``bitmap`` texture (raw values, bilinear, clamped) from a (T, T) map."""
    import mitsuba as mi

    values = np.ascontiguousarray(values, dtype=np.float32)
    if values.ndim != 2:
        raise ValueError(f"maps must be 2-D (T, T), got shape {values.shape}")
    return {"type": "bitmap", "data": to_jit(mi.TensorXf, values[..., None]), "raw": True,
            "filter_type": "bilinear", "wrap_mode": "clamp"}


def glossy_bsdf_dict(maps):
    """``pbssrdf`` with the glossy maps and no local subsurface lobe."""
    missing = [name for name in GLOSSY_MAPS if name not in maps]
    if missing:
        raise ValueError(f"missing appearance maps: {missing}")
    bsdf = {"type": "pbssrdf", "rho_sss": 0.0}
    bsdf.update({name: map_texture(maps[name]) for name in GLOSSY_MAPS})
    return bsdf


def view_scene(mesh, camera, light, maps, exitance, spp=16, seed=0, interreflection=True):
    """The scene of one view: ``stokes(direct)``, the camera, its light, and the skin.

    Parameters
    ----------
    mesh : SurfaceMesh
        Geometry in mm (already displaced, for synthetic truth).
    camera : RigCamera
    light : RigLight
    maps : dict
        Glossy maps (see :data:`GLOSSY_MAPS`).
    exitance : (T, T) array
        Diffused exitance for the ``pexitance`` emitter.
    interreflection : bool
        With ``False``, ``direct`` takes no BSDF samples: the glossy lobes
        then reflect only the (point) light, found by emitter sampling, and
        not the ``pexitance`` glow of other texels, which only BSDF-sampled
        rays find; the camera still sees that glow directly.
    """
    import mitsuba as mi

    bsdf = mi.load_dict(glossy_bsdf_dict(maps))
    emitter = mi.load_dict({"type": "pexitance", "exitance": map_texture(exitance),
                            "eta": map_texture(maps["eta"])})
    direct = {"type": "direct"} if interreflection else {"type": "direct", "bsdf_samples": 0}
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "inner": direct},
        "sensor": camera.sensor_dict(spp, seed),
        "light": light.emitter_dict(),
        "skin": to_mitsuba(mesh, bsdf, emitter),
    })


def set_exitance(scene, exitance):
    """Replace the exitance map of a :func:`view_scene` (e.g. for the next band)."""
    import mitsuba as mi

    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("emitter.exitance.data"))
    params[key] = to_jit(mi.TensorXf, np.asarray(exitance)[..., None], np.float32)
    params.update()


def render_analyser_images(scene, spp=None, seed=0, channel_names=None):
    """``(images, channel_names)``: ``I0, I45, I90, I135`` (float32 H x W) of the first camera.

    Pass the returned ``channel_names`` back on later renders of the same
    scene: finding them develops the film, which costs as much as a render.
    """
    import mitsuba as mi

    image = mi.render(scene, spp=spp or 0, seed=seed)
    if channel_names is None:
        channel_names = render_channel_names(scene.sensors()[0].film())
    return analyser_images(split_stokes(image, channel_names, monochrome=True)), channel_names
