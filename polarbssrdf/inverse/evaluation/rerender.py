"""Held-out views: re-render a camera left out of the fit with the recovered maps, and compare.

For each held-out camera of a run (``result.json`` ``settings.holdout``) the
view is rendered through Mitsuba: the capture's base mesh displaced by the
recovered ``displacement`` (:func:`polarbssrdf.geometry.displace`) and moved
by the frame's pose, the ``pbssrdf`` plugin with the recovered glossy maps
and, per band, ``rho_sss`` = that band's map (the plugin's local subsurface
lobe: no texture-space blur), the capture's camera
(:func:`polarbssrdf.io.mitsuba_camera.mitsuba_sensor_dict`) and its light
(:meth:`polarbssrdf.io.manifest.Light.mitsuba_dict`), with
``stokes(direct)`` in a mono polarized variant, one band at a time.

The comparison uses the paper's separations (see ``docs/conventions.md``):
``I_s = I0 - I90`` and ``I_sss = 2 I90``, over the pixels whose centre ray
hits the re-rendered mesh, minus a one-pixel band along the silhouette
(partly covered pixels; a sub-pixel change of the outline would dominate
them), minus non-finite capture pixels. Errors are RMSEs in the capture's
image units, and relative to the mean observed ``I_sss`` over the same
pixels, per band and averaged over bands.

Maps are clamped into ``pbssrdf``'s parameter ranges before rendering
(albedos in [0, 1], roughness in (0, 1], eta > 1); the number of clamped
texels is reported.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import binary_erosion

from polarbssrdf._arrays import to_jit
from polarbssrdf.geometry import SurfaceMesh, texel_atlas, to_mitsuba
from polarbssrdf.geometry.displaced import displaced_mesh
from polarbssrdf.inverse.observations.build import ANALYSER_ANGLES, analyser_images
from polarbssrdf.io.mitsuba_camera import mitsuba_sensor_dict
from polarbssrdf.render.view import (
    GLOSSY_MAPS,
    glossy_bsdf_dict,
    map_texture,
    render_analyser_images,
)
from polarbssrdf.variants import DEFAULT_VARIANT, ensure_mono_polarized_variant

RENDER_VARIANT = DEFAULT_VARIANT
DEFAULT_SPP = 16

PLUGIN_RANGES = {"eta": (1.0 + 1e-4, None), "rho_s": (0.0, 1.0), "alpha_s": (1e-3, 1.0),
                 "rho_ss": (0.0, 1.0), "alpha_ss": (1e-3, 1.0), "rho_sss": (0.0, 1.0)}
"""Where maps are clamped before rendering: ``pbssrdf`` refuses values outside its ranges."""

SILHOUETTE_PX = 1
"""Pixels along the silhouette of the re-rendered mesh left out of the errors."""


def clamp_to_plugin(name, values):
    """``(values clamped to pbssrdf's range for the parameter, number of clamped texels)``."""
    low, high = PLUGIN_RANGES[name.partition(".")[0]]
    values = np.asarray(values, dtype=np.float32)
    clamped = np.clip(values, low, high if high is not None else np.inf).astype(np.float32)
    return clamped, int(np.count_nonzero(clamped != values))


def posed_mesh(mesh, pose):
    """``mesh`` moved by the frame's rigid object -> world ``pose`` (4 x 4, mm)."""

    pose = np.asarray(pose, dtype=np.float64)
    if np.allclose(pose, np.eye(4)):
        return mesh
    vertices = mesh.vertices @ pose[:3, :3].T + pose[:3, 3]
    normals = None if mesh.normals is None else mesh.normals @ pose[:3, :3].T
    return SurfaceMesh(vertices, mesh.faces, mesh.uvs, name=mesh.name, normals=normals)


def view_scene(capture, maps, camera_name, frame=0, spp=DEFAULT_SPP, seed=0,
               variant=RENDER_VARIANT):
    """One capture view with the recovered maps, ready to render band by band.

    ``maps`` are result channels (``eta``, ..., ``displacement``,
    ``rho_sss.<band>``); the subsurface texture starts with the first band.
    Returns ``(scene, clamped maps, {map: clamped texel count} of the maps that
    needed clamping, the capture's image record of the view)``.
    """

    ensure_mono_polarized_variant(variant)
    manifest = capture.manifest
    frame_record = manifest.frame(int(frame))
    record = next((r for r in frame_record.images
                   if r.camera == camera_name and r.kind in ("analyser", "raw")), None)
    if record is None:
        raise ValueError(f"frame {frame} has no polarization image of camera {camera_name!r}")
    camera, light = manifest.camera(camera_name), manifest.light(record.light)
    bands = manifest.band_names
    missing = [name for name in (*GLOSSY_MAPS, "displacement") if name not in maps]
    missing += [f"rho_sss.{band}" for band in bands if f"rho_sss.{band}" not in maps]
    if missing:
        raise ValueError(f"the maps lack {missing}: cannot re-render camera {camera_name!r}")
    clamped, counts = {}, {}
    for name in (*GLOSSY_MAPS, *(f"rho_sss.{band}" for band in bands)):
        clamped[name], counts[name] = clamp_to_plugin(name, maps[name])
    base = capture.load_mesh()
    mesh = displaced_mesh(base, np.nan_to_num(np.asarray(maps["displacement"], dtype=np.float64)),
                          texel_atlas(to_mitsuba(base), np.asarray(maps["displacement"]).shape[0]))
    mesh = posed_mesh(mesh, frame_record.pose)
    bsdf = glossy_bsdf_dict(clamped)
    bsdf["rho_sss"] = map_texture(clamped[f"rho_sss.{bands[0]}"])
    scene = mi.load_dict({
        "type": "scene",
        # a point light is found only by emitter sampling: BSDF samples would add nothing
        "integrator": {"type": "stokes", "inner": {"type": "direct", "bsdf_samples": 0}},
        "sensor": mitsuba_sensor_dict(camera, spp, seed=seed),
        "light": light.mitsuba_dict(),
        "skin": to_mitsuba(mesh, mi.load_dict(bsdf)),
    })
    return scene, clamped, {name: n for name, n in counts.items() if n}, record


def set_subsurface_albedo(scene, values):
    """Replace the ``rho_sss`` texture data of a :func:`view_scene` (the next band)."""

    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("bsdf.rho_sss.data"))
    params[key] = to_jit(mi.TensorXf, np.asarray(values)[..., None], np.float32)
    params.update()


def hit_mask(scene, silhouette_px=SILHOUETTE_PX):
    """(H, W) bool: pixels whose centre ray hits the mesh, eroded by ``silhouette_px``."""

    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().crop_size())
    rows, columns = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    position = mi.Point2f(to_jit(mi.Float, (columns.ravel() + 0.5) / width, np.float32),
                          to_jit(mi.Float, (rows.ravel() + 0.5) / height, np.float32))
    count = width * height
    ray, _ = sensor.sample_ray(dr.zeros(mi.Float, count), dr.full(mi.Float, 0.5, count), position,
                               dr.full(mi.Point2f, 0.5, count))
    hit = np.array(scene.ray_intersect(ray).is_valid(), dtype=bool).reshape(height, width)
    if silhouette_px > 0:
        hit = binary_erosion(hit, iterations=int(silhouette_px), border_value=0)
    return hit


def render_view(capture, maps, camera_name, frame=0, spp=DEFAULT_SPP, seed=0,
                variant=RENDER_VARIANT):
    """Re-render one view per band.

    Returns
    -------
    dict
        ``images``: band -> ``{"I0", "I45", "I90", "I135"}`` (H x W float32),
        ``mask``: the pixels to compare (:func:`hit_mask`), ``clamped``:
        map -> number of texels clamped into the plugin's range, ``record``:
        the capture's image record of the view.
    """

    scene, clamped_maps, clamped, record = view_scene(capture, maps, camera_name, frame, spp,
                                                      seed, variant)
    images, channel_names = {}, None
    for band in capture.manifest.band_names:
        set_subsurface_albedo(scene, clamped_maps[f"rho_sss.{band}"])
        rendered, channel_names = render_analyser_images(scene, spp, seed, channel_names)
        images[band] = rendered
    return {"images": images, "mask": hit_mask(scene), "clamped": clamped, "record": record}


def captured_view(capture, record):
    """band -> ``{"I0", ..., "I135"}`` of the capture's image (raw images demosaicked)."""

    images = analyser_images(capture, record)
    bands = capture.manifest.band_names
    per_band = {}
    for index, band in enumerate(bands):
        chunk = images[4 * index:4 * index + 4]
        per_band[band] = {f"I{angle}": image for angle, image in zip(ANALYSER_ANGLES, chunk)}
    return per_band


def separation_errors(observed, rendered, mask):
    """RMSE of ``I_s = I0 - I90`` and ``I_sss = 2 I90`` over ``mask`` (one band)."""
    def parts(images):
        i0 = np.asarray(images["I0"], dtype=np.float64)
        i90 = np.asarray(images["I90"], dtype=np.float64)
        return i0 - i90, 2.0 * i90

    obs_s, obs_sss = parts(observed)
    ren_s, ren_sss = parts(rendered)
    mask = mask & np.isfinite(obs_s) & np.isfinite(obs_sss)
    if not mask.any():
        raise ValueError("no pixel of the view is both on the mesh and finite in the capture")
    rmse_s = float(np.sqrt(np.mean((ren_s[mask] - obs_s[mask]) ** 2)))
    rmse_sss = float(np.sqrt(np.mean((ren_sss[mask] - obs_sss[mask]) ** 2)))
    mean_sss = float(np.mean(obs_sss[mask]))
    scale = mean_sss if mean_sss > 0 else float("nan")
    return {"pixels": int(mask.sum()), "mean_observed_I_sss": mean_sss,
            "rmse_I_s": rmse_s, "rmse_I_sss": rmse_sss,
            "relative_rmse_I_s": rmse_s / scale, "relative_rmse_I_sss": rmse_sss / scale}


AVERAGED = ("rmse_I_s", "rmse_I_sss", "relative_rmse_I_s", "relative_rmse_I_sss")


def holdout_errors(capture, maps, cameras, frame=0, spp=DEFAULT_SPP, seed=0,
                   variant=RENDER_VARIANT):
    """Re-render every camera of ``cameras`` and compare it with the capture.

    Returns
    -------
    dict
        ``{"cameras": {name: {"bands": {band: errors}, "mean": errors, "pixels",
        "clamped_texels", "light"}}, "mean": errors over cameras, "spp",
        "separation", "pixels"}`` where ``errors`` are the keys of
        :func:`separation_errors` (``mean`` averages the bands, then cameras).
    """
    known = {camera.name for camera in capture.manifest.cameras}
    unknown = sorted(set(cameras) - known)
    if unknown:
        raise ValueError(f"held-out cameras {unknown} are not in the capture "
                         f"(cameras: {', '.join(sorted(known))})")
    result = {"spp": int(spp), "variant": variant,
              "separation": "I_s = I0 - I90, I_sss = 2 I90; relative = RMSE / mean observed I_sss",
              "pixels": f"centre ray hits the re-rendered mesh, {SILHOUETTE_PX} px silhouette "
                        "band and non-finite capture pixels left out",
              "cameras": {}}
    for name in cameras:
        view = render_view(capture, maps, name, frame, spp, seed, variant)
        observed = captured_view(capture, view["record"])
        bands = {band: separation_errors(observed[band], view["images"][band], view["mask"])
                 for band in capture.manifest.band_names}
        result["cameras"][name] = {
            "light": view["record"].light, "image": view["record"].path,
            "pixels": next(iter(bands.values()))["pixels"],
            "clamped_texels": view["clamped"],
            "bands": bands,
            "mean": {key: float(np.mean([b[key] for b in bands.values()])) for key in AVERAGED}}
    if result["cameras"]:
        result["mean"] = {key: float(np.mean([c["mean"][key] for c in result["cameras"].values()]))
                          for key in AVERAGED}
    return result
