"""Render a synthetic light-stage capture of a sphere or the embedded face, with ground truth.

For every frame, view and band: the face's maps give ``pbssrdf``'s glossy
parameters and, through the two-layer skin model, per-texel layer totals
(eq. 42) at each wavelength of the bands' spectral quadrature
(:mod:`polarbssrdf.skin.quadrature`); the coaxial light's transmitted
irradiance is diffused in texture space through each wavelength's layer
profiles (sums of Gaussians, eq. 46) and the band's image is the
quadrature's weighted sum over its wavelengths, the band integral a camera
behind the filter records (the truth albedo ``rho_sss`` is the band integral
of eq. 47's reflectance the same way). The result is rendered by
``pexitance``, which the camera sees directly (glossy lobes reflect it only
with ``interreflection``); the camera records I0/I45/I90/I135 (or, with
``raw``, the noisy 12-bit mosaic of a polarization sensor). The geometry is
the base mesh displaced by the displacement map, subdivided until its edges are
no longer than a texel so that it carries the map's detail
(:mod:`polarbssrdf.geometry.displaced`); the capture stores the base mesh, as a
multi-view-stereo reconstruction would give it.

Raw exposure: one fixed exposure per camera for the whole capture, set the way
a stage is metered with a white target before the shoot, from the rig alone
(:func:`raw_sensor`): a white Lambertian reflector facing the camera's light at
the rig's working distance ``d`` (light to the camera's aim point) would read
:data:`RAW_WHITE_FULL_WELL` of the full well through one analyser, whose
radiance is ``I / (2 pi d^2)``. Every band and frame of a camera uses it, so
it is known before anything is rendered: the plan (``capture.plan.json``)
holds each raw record's ``radiance_per_dn``, ``black_level_dn`` and
``saturation_dn`` (:func:`raw_calibration`), and a resumed run is
bit-identical to a fresh one.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba, uv_sphere
from polarbssrdf.geometry.displaced import displaced_mesh, subdivided_for_texels
from polarbssrdf.geometry.face import face_region_masks
from polarbssrdf.render.lightstage import ring_light_stage
from polarbssrdf.render.subsurface import (
    band_exitances,
    emitted_exitance,
    layer_profile_kernels,
    layer_totals_maps,
    transmitted_irradiance,
)
from polarbssrdf.skin.quadrature import SPECTRAL_METHODS, spectral_quadrature
from polarbssrdf.render.view import render_analyser_images, set_exitance, view_scene
from polarbssrdf.synth.truth import TruthSettings, frame_maps, relief_notes, truth_maps

OBJECTS = ("sphere", "face")
ANALYSER = ("I0", "I45", "I90", "I135")
SEED_LIMIT = 2**64
"""Seeds are below this: NumPy's seeding takes any, and 64 bits keep capture.json readable."""


def image_seed(seed, frame, camera_index, band_index):
    """The 32-bit render seed of one image: ``mi.render`` takes a ``UInt32`` seed.

    A hash of all four numbers (``numpy.random.SeedSequence``), so every
    capture seed works and images get distinct sample patterns (two images of
    a capture share one with probability about ``n_images**2 / 2**33``).
    ``mi.render`` derives its gradient seed from this one
    (``sample_tea_32(seed, 1)``), so ``seed != seed_grad`` holds.
    """
    sequence = np.random.SeedSequence([int(seed), int(frame), int(camera_index), int(band_index)])
    return int(sequence.generate_state(1, np.uint32)[0])


@dataclasses.dataclass(frozen=True)
class SynthesisSettings:
    """What to render.

    Attributes
    ----------
    object : str
        ``"sphere"`` (radius 60 mm) or ``"face"`` (the canonical face, mm).
    views : int
        Cameras on the rig, each with its coaxial light (one frame = every view once).
    frames : int
        Frames of the sequence (hemoglobin changes over them).
    resolution : int
        Image width and height, pixels.
    texture : int
        Texture (map) resolution ``T``.
    spp : int
        Samples per pixel.
    seed : int
        Seed of the truth maps, the render noise and the sensor noise, in
        ``[0, 2**64)``; each image's render seed is derived from it
        (:func:`image_seed`).
    raw : bool
        Write noisy raw sensor mosaics instead of analyser images.
    interreflection : bool
        Let the glossy lobes reflect the subsurface light leaving other
        texels (found by BSDF sampling). Off by default: then subsurface light
        reaches the camera only directly and glossy lobes reflect only the
        camera's light, as in the per-texel model the inverse stages fit.
    subsurface_diffusion : bool
        Diffuse each view's transmitted irradiance in texture space through the
        layers' profiles (eq. 46; the default, as skin does). ``False`` leaves the
        subsurface light where it entered: the exitance of each texel is
        ``R_bar E / c(eta)`` (:func:`subsurface_exitances`), exactly the per-texel
        subsurface model of the polarimetric stages (``rho_sss E``), so a capture
        made so isolates what the blur costs the inverse chain. Recorded in
        ``capture.json`` only when ``False`` (captures made before it existed
        resume).
    spectral : str
        How a band's image is formed from the spectrum: ``"integral"`` (default) is
        what a camera behind the band's filter records, the band integral of the
        diffused spectral light by the quadrature of
        :func:`~polarbssrdf.skin.quadrature.band_integral_quadrature` (within 0.2% of
        the 1 nm integral); ``"effective"`` renders each band once with its
        band-averaged coefficients, the band-effective approximation (10-19% off in
        some bands: for measuring what the approximation costs, never for scoring).
    """

    object: str = "face"
    views: int = 8
    frames: int = 1
    resolution: int = 512
    texture: int = 512
    spp: int = 16
    seed: int = 0
    raw: bool = False
    interreflection: bool = False
    subsurface_diffusion: bool = True
    spectral: str = "integral"

    def __post_init__(self):
        if self.spectral not in SPECTRAL_METHODS:
            raise ValueError(f"spectral must be one of {SPECTRAL_METHODS}, got {self.spectral!r}")
        if self.object not in OBJECTS:
            raise ValueError(f"object must be one of {OBJECTS}, got {self.object!r}")
        for name in ("views", "frames", "resolution", "texture", "spp"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be a positive integer")
        if not 0 <= int(self.seed) < SEED_LIMIT:
            raise ValueError(f"seed must be an integer in [0, 2**64), got {self.seed}")
        if self.raw and self.resolution % 2:
            raise ValueError("raw mosaics need an even resolution (2 x 2 polarizer cells)")


def object_mesh(name):
    """Base geometry of the synthetic object, mm."""
    return face_mesh(1) if name == "face" else uv_sphere(60.0, rings=96, segments=192)


def subsurface_albedo(maps, bands, spectral="integral"):
    """(n_bands, T, T) subsurface lobe albedo ``rho_sss = R_bar / c(eta)`` per band.

    ``R_bar`` is the band integral of the total diffuse reflectance of the two-layer
    skin (eq. 47, at each texel's chromophores, oxygenation ``gamma`` and epidermal
    ``thickness_mm`` where the maps hold them), the flux that leaves the skin;
    ``c(eta)`` the share of a lobe albedo that the eq. 19 lobe
    (``rho_sss T+(theta_o) / pi``) emits
    (:func:`~polarbssrdf.render.subsurface.subsurface_exit_fraction`), so a lobe
    with this albedo emits ``R_bar E`` (see docs/biophysical.md). ``spectral``: a
    quadrature, or its method (:func:`~polarbssrdf.skin.quadrature.spectral_quadrature`)."""
    from polarbssrdf.render.subsurface import subsurface_exit_fraction
    from polarbssrdf.skin.model import DEFAULT_GAMMA, DEFAULT_THICKNESS_MM
    from polarbssrdf.skin.quadrature import as_quadrature, quadrature_reflectance

    quadrature = spectral_quadrature(bands, spectral) if isinstance(spectral, str) else as_quadrature(spectral)
    reflectance = quadrature_reflectance(quadrature, maps["C_m"], maps["beta_m"], maps["C_h_out"], maps["C_h_in"],
                                         maps.get("gamma", DEFAULT_GAMMA),
                                         maps.get("thickness_mm", DEFAULT_THICKNESS_MM), maps["eta"])
    reflectance = reflectance / subsurface_exit_fraction(maps["eta"])[..., None]
    return np.moveaxis(np.asarray(reflectance, dtype=np.float32), -1, 0)


def subsurface_exitances(irradiance, state, prepared, diffusion=True):
    """The ``pexitance`` map of every band (W/mm^2 for ``irradiance`` in W/mm^2): the
    band integral of the layered exitance (eq. 46, the flux ``R_bar E`` after diffusion,
    per quadrature node with that wavelength's profiles,
    :func:`~polarbssrdf.render.subsurface.band_exitances`) divided by ``c(eta)``, so that
    the emitted flux is the multipole's (:func:`~polarbssrdf.render.subsurface.emitted_exitance`).

    Without ``diffusion`` nothing is blurred: ``R_bar E / c(eta) = rho_sss E`` per
    texel (``state.albedo``, eq. 47), the per-texel model of the inverse stages."""
    if not diffusion:
        irradiance = np.asarray(irradiance, dtype=np.float64)
        return [(np.asarray(albedo, dtype=np.float64) * irradiance).astype(np.float32) for albedo in state.albedo]
    exitances = band_exitances(irradiance, state.layers, prepared.kernels, prepared.quadrature.weights,
                               state.atlas)
    return [emitted_exitance(exitance, state.maps["eta"]) for exitance in exitances]


@dataclasses.dataclass
class PreparedCapture:
    """Everything fixed before rendering: rig, base geometry, static truth maps, blur kernels."""

    settings: SynthesisSettings
    bands: list
    stage: object
    base_mesh: object
    static_maps: dict
    kernels: list  # per quadrature node
    truth_settings: TruthSettings
    flush_region: np.ndarray | None
    quadrature: object  # SpectralQuadrature of the bands
    base_atlas: object  # TexelAtlas of base_mesh at the texture size
    render_base: object  # base_mesh subdivided to carry the displacement map (subdivided_for_texels)
    notes: list  # what the texture cannot hold of the truth's relief (relief_notes)

    def maps(self, frame):
        return frame_maps(self.static_maps, frame, self.settings.frames, self.truth_settings,
                          self.flush_region)


def prepare_capture(settings, bands, truth_settings=None):
    """Rig, geometry, static truth maps, the bands' spectral quadrature and its blur kernels.

    The kernels are the layer profiles of the maps' base skin (the Table 2 row, or its
    bases moved by ``truth_settings.biophysical``, with the thickness and oxygenation
    bases) at each quadrature node."""
    truth_settings = truth_settings or TruthSettings()
    base = object_mesh(settings.object)
    distance = 600.0 if settings.object == "face" else 450.0
    stage = ring_light_stage(settings.views, distance_mm=distance, width=settings.resolution,
                             height=settings.resolution, fov_x_deg=22.0)
    atlas = texel_atlas(to_mitsuba(base), settings.texture)
    rng = np.random.default_rng(settings.seed)
    landmarks = face_mesh(0) if settings.object == "face" else None
    static = truth_maps(atlas, truth_settings, rng, landmarks)
    flush = None
    if settings.object == "face":
        masks = face_region_masks(settings.texture)
        flush = gaussian_filter(masks["cheeks"].astype(np.float64), 4.0)
        flush /= max(flush.max(), 1e-12)
    quadrature = spectral_quadrature(bands, settings.spectral)
    kernels = layer_profile_kernels(quadrature, truth_settings.skin_parameters())
    return PreparedCapture(settings, list(bands), stage, base, static, kernels, truth_settings,
                           flush, quadrature, atlas, subdivided_for_texels(base, atlas),
                           relief_notes(atlas, truth_settings, landmarks))


@dataclasses.dataclass
class FrameState:
    """What one frame shares between its views: maps, displaced geometry, atlas, albedo."""

    index: int
    maps: dict
    mesh: object
    atlas: object
    albedo: np.ndarray  # (n_bands, T, T), lobe albedo R_bar / c(eta) (eq. 47), band-integrated
    layers: list  # per quadrature node, LayerTotals of (T, T) maps


def prepare_frame(prepared, frame):
    """Maps of ``frame``, the displaced mesh (fine enough to carry the displacement map,
    :func:`~polarbssrdf.geometry.displaced.displaced_mesh`), its texel atlas and the
    per-band albedo."""
    maps = prepared.maps(frame)
    mesh = displaced_mesh(prepared.base_mesh, maps["displacement"], prepared.base_atlas,
                          prepared.render_base)
    atlas = texel_atlas(to_mitsuba(mesh), prepared.settings.texture)
    return FrameState(frame, maps, mesh, atlas, subsurface_albedo(maps, prepared.bands, prepared.quadrature),
                      layer_totals_maps(maps, prepared.quadrature))


def render_frame_view(prepared, state, camera, rng=None):
    """Images per band (``"<band>.I0"`` ...) of one camera lit by its light in one frame.

    With ``raw``, the channels are ``"<band>.raw"`` sensor mosaics in digital numbers,
    exposed with the camera's fixed :func:`raw_sensor`.
    """
    settings = prepared.settings
    light = prepared.stage.light(prepared.stage.light_for_camera[camera.name])
    # the sampler's own seed does not matter: every render passes its image_seed
    scene = view_scene(state.mesh, camera, light, state.maps, np.zeros_like(state.maps["eta"]),
                       settings.spp, 0, interreflection=settings.interreflection)
    irradiance = transmitted_irradiance(scene, state.atlas, state.maps["eta"])
    camera_index = [c.name for c in prepared.stage.cameras].index(camera.name)
    channels, channel_names = {}, None
    noise = raw_sensor(prepared.stage, camera.name) if settings.raw else None
    exitances = subsurface_exitances(irradiance, state, prepared, settings.subsurface_diffusion)
    for band_index, band in enumerate(prepared.bands):
        set_exitance(scene, exitances[band_index])
        # a distinct, reproducible sample pattern per image
        seed = image_seed(settings.seed, state.index, camera_index, band_index)
        images, channel_names = render_analyser_images(scene, settings.spp, seed, channel_names)
        if settings.raw:
            channels[f"{band.name}.raw"] = _raw_mosaic(images, noise, rng)
        else:
            for name in ANALYSER:
                channels[f"{band.name}.{name}"] = images[name]
    return channels


RAW_WHITE_FULL_WELL = 0.8
"""Fraction of the full well a white diffuse reflector at the working distance fills
(through one analyser): skin (albedo well below 1, and half of it with cross-polarized
analysers) stays far below, leaving headroom for the specular highlights."""
RAW_BLACK_LEVEL_DN = 64.0
"""Black level of the simulated sensor, DN: keeps read noise of dark pixels off the
clip at 0 (so the mean response stays linear) and makes saturated pixels read 4095."""


def raw_sensor(stage, camera_name):
    """The fixed exposure (:class:`~polarbssrdf.capture.SensorNoise`) of one rig camera.

    ``electrons_per_radiance = RAW_WHITE_FULL_WELL * full_well / L_white`` with
    ``L_white = I / (2 pi d^2)`` (W/(sr mm^2)): the analyser radiance of a white
    Lambertian facing the camera's light (intensity ``I``, W/sr) at the distance
    ``d`` (mm) from the light to the camera's aim point. A function of the rig
    only, so every frame and band of the camera shares it.
    """
    from polarbssrdf.capture import SensorNoise

    camera = next(c for c in stage.cameras if c.name == camera_name)
    light = stage.light(stage.light_for_camera[camera_name])
    distance = float(np.linalg.norm(np.asarray(light.position, float)
                                    - np.asarray(camera.target, float)))
    white = float(light.intensity) / (2.0 * np.pi * distance ** 2)
    if not (np.isfinite(white) and white > 0):
        raise ValueError(f"camera {camera_name}: its light gives no radiance to meter raw "
                         f"exposure on (intensity {light.intensity}, distance {distance} mm)")
    full_well = SensorNoise(electrons_per_radiance=1.0).full_well_electrons  # the default
    return SensorNoise(electrons_per_radiance=RAW_WHITE_FULL_WELL * full_well / white,
                       black_level_dn=RAW_BLACK_LEVEL_DN)


def raw_calibration(noise, band_names):
    """The image-record calibration of a raw shot with ``noise`` (see ``docs/capture_format.md``).

    Below saturation ``E[DN] = gain * electrons_per_radiance * L + black_level``
    (:func:`polarbssrdf.capture.expected_raw_mean`), so
    ``radiance_per_dn = 1 / (gain * electrons_per_radiance)`` for every band;
    the ADC clips at ``max_dn``, which is the saturation level.
    """
    scale = 1.0 / (noise.gain * noise.electrons_per_radiance)
    return {"radiance_per_dn": {name: scale for name in band_names},
            "black_level_dn": float(noise.black_level_dn),
            "saturation_dn": float(noise.max_dn)}


def _raw_mosaic(images, noise, rng):
    """Noisy 12-bit mosaic (DN) of a mono polarization sensor (IMX250MZR) from analyser images."""
    from polarbssrdf.capture import IMX250MZR, mosaic_images, simulate_raw

    # I(theta) = (S0 + S1 cos 2theta + S2 sin 2theta) / 2 can round to -1e-11 where S0 ~ |S1|
    radiance = mosaic_images({name: np.maximum(values, 0.0) for name, values in images.items()},
                             IMX250MZR)
    return simulate_raw(radiance, noise, rng).astype(np.float32)


FRAME_INTERVAL_S = 1.0 / 30.0


def capture_manifest(prepared):
    """The capture's manifest: capture-format cameras and lights of the rig, one frame per time step."""
    from polarbssrdf.io import CaptureManifest, Light, camera_from_look_at, plan_frame
    from polarbssrdf import __version__

    settings, stage = prepared.settings, prepared.stage
    sensor = "IMX250MZR" if settings.raw else "ideal"
    cameras = [camera_from_look_at(c.origin, c.target, c.up, c.fov_x_deg, (c.width, c.height),
                                   name=c.name, sensor=sensor) for c in stage.cameras]
    lights = [Light(light.name, position=light.position, intensity=light.intensity,
                    polarization_axis=light.polarization_axis,
                    polarizer_normal=light.polarizer_normal) for light in stage.lights]
    pairs = [(c.name, stage.light_for_camera[c.name]) for c in stage.cameras]
    kind = "raw" if settings.raw else "analyser"
    band_names = [band.name for band in prepared.bands]
    # the exposure is fixed per camera and known from the rig: the plan records it
    calibration = ({c.name: raw_calibration(raw_sensor(stage, c.name), band_names)
                    for c in stage.cameras} if settings.raw else None)
    frames = [plan_frame(index, index * FRAME_INTERVAL_S, np.eye(4), pairs, kind, calibration)
              for index in range(settings.frames)]
    # everything the images depend on, so that a resume with other settings is refused
    metadata = {"generator": f"polarbssrdf {__version__} synth",
                "settings": settings_json(settings),
                "skin": list(prepared.truth_settings.skin),
                "truth_settings": truth_settings_json(prepared.truth_settings)}
    return CaptureManifest(bands=prepared.bands, cameras=cameras, lights=lights, frames=frames,
                           mesh="mesh.obj", synthetic=True, truth="truth/truth.json",
                           metadata=metadata)


def settings_json(settings):
    """The synthesis settings as recorded in ``capture.json``: ``subsurface_diffusion`` only
    when it is off, so a capture made before the switch existed records what it did (and
    resumes)."""
    record = dataclasses.asdict(settings)
    if record["subsurface_diffusion"]:
        del record["subsurface_diffusion"]
    return record


def truth_settings_json(truth_settings):
    """The truth settings as plain JSON (tuples as lists), as a settings file would hold them.

    ``biophysical`` and ``features`` are left out while empty, so a capture made with
    settings that have neither records what it did before they existed (and resumes)."""
    record = json.loads(json.dumps(dataclasses.asdict(truth_settings)))
    for key in ("biophysical", "features"):
        if not record[key]:
            del record[key]
    return record


def truth_channels(state, bands):
    """Ground-truth maps of one frame, with the subsurface albedo per band as ``rho_sss.<band>``."""
    channels = {name: np.ascontiguousarray(values, dtype=np.float32)
                for name, values in state.maps.items()}
    for index, band in enumerate(bands):
        channels[f"rho_sss.{band.name}"] = np.ascontiguousarray(state.albedo[index])
    return channels


PREVIEW_FILE = "preview.png"
PREVIEW_SIZE = 160


def preview_bands(bands):
    """Indices of three bands shown as red, green and blue in previews (reddest first)."""
    order = sorted(range(len(bands)), key=lambda i: bands[i].centroid_nm, reverse=True)
    if len(order) >= 3:
        return [order[0], order[len(order) // 2], order[-1]]
    return [order[0]] * 3


def preview_tiles(channels, bands, camera_name):
    """``{"cam00 I0": rgb, "cam00 I90": rgb}`` of one view, as linear false colour (float, H x W x 3)."""
    from PIL import Image

    picked = [bands[i].name for i in preview_bands(bands)]
    tiles = {}
    for analyser in ("I0", "I90"):
        key = f"{{}}.{analyser}"
        if key.format(picked[0]) not in channels:  # raw captures have no analyser images
            return {}
        rgb = np.stack([channels[key.format(name)] for name in picked], axis=-1)
        height, width = rgb.shape[:2]
        scale = PREVIEW_SIZE / max(height, width)
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        resized = [np.asarray(Image.fromarray(rgb[..., c].astype(np.float32), "F")
                              .resize(size, Image.BILINEAR)) for c in range(3)]
        tiles[f"{camera_name} {analyser}"] = np.stack(resized, axis=-1)
    return tiles


def write_preview(outdir, tiles):
    """A contact sheet of the views (I0 next to I90, one exposure for all) as ``preview.png``."""
    from polarbssrdf.io.atomic import atomic_write_bytes
    from polarbssrdf.render.stokes_images import contact_sheet, png_bytes, tonemap_srgb

    if not tiles:
        return None
    peak = np.percentile(np.concatenate([t.ravel() for t in tiles.values()]), 99.5)
    exposure = 1.0 / max(float(peak), 1e-12)
    sheet = contact_sheet({label: tonemap_srgb(tile, exposure) for label, tile in tiles.items()},
                          columns=4)
    path = Path(outdir) / PREVIEW_FILE
    atomic_write_bytes(path, png_bytes(sheet), overwrite=True)
    return path


def synthesize(outdir, settings, bands=None, truth_settings=None, overwrite=False, resume=False,
               progress=True):
    """Render a synthetic capture with ground truth into ``outdir`` (see the module docstring).

    Images are written one by one as they are rendered, each atomically, and
    ``capture.json`` only once all are there. Without ``resume`` everything
    is rendered anew (``overwrite`` lets the run start over in a directory
    that holds an earlier capture); with ``resume`` an interrupted run
    continues where it stopped and reuses its finished images, which needs
    the same settings (else :class:`~polarbssrdf.io.capture.PlanMismatchError`).
    Either way the result is bit-identical to a fresh run into an empty
    directory. ``preview.png`` shows frame 0 of every view (I0 and I90, three
    bands as red, green and blue). Returns the path of the finished
    ``capture.json``.
    """
    from tqdm import tqdm

    from polarbssrdf.io import CaptureWriter
    from polarbssrdf.spectral import default_bands

    bands = list(bands) if bands is not None else default_bands()
    prepared = prepare_capture(settings, bands, truth_settings)
    if progress:
        for note in prepared.notes:
            print(f"synth: {note}", file=sys.stderr)
    manifest = capture_manifest(prepared)
    writer = CaptureWriter(outdir, manifest, overwrite=overwrite, resume=resume)
    writer.add_mesh(prepared.base_mesh)
    # only a resumed run may reuse files: the writer checked that its plan is this one
    done = writer.completed() if resume else set()
    truth_done = writer.completed_truth() if resume else set()
    stage = prepared.stage
    total = settings.frames * len(stage.cameras)
    with tqdm(total=total, desc="synth", unit="image", disable=not progress) as bar:
        for frame in range(settings.frames):
            state = None
            for camera_index, camera in enumerate(stage.cameras):
                light = stage.light_for_camera[camera.name]
                if (frame, camera.name, light) in done:
                    bar.update()
                    continue
                state = state or prepare_frame(prepared, frame)
                # sensor noise reproducible per image, so a resumed run matches a fresh one
                rng = np.random.default_rng([settings.seed, frame, camera_index])
                channels = render_frame_view(prepared, state, camera, rng)
                writer.add_image(frame, camera.name, light, channels)
                bar.update()
            if frame not in truth_done:
                state = state or prepare_frame(prepared, frame)
                writer.add_truth(frame, truth_channels(state, bands))
    manifest_path = writer.finish()
    write_preview(outdir, written_preview_tiles(writer, stage, bands))
    return manifest_path


def written_preview_tiles(writer, stage, bands):
    """Preview tiles of frame 0 of every view, read back from the capture on disk.

    Reading them (rather than keeping the rendered ones) makes the preview of
    a resumed run the same as that of a fresh run.
    """
    from polarbssrdf.io.exr import read_exr

    tiles = {}
    for camera in stage.cameras:
        channels, _ = read_exr(writer.path_of(0, camera.name, stage.light_for_camera[camera.name]))
        tiles.update(preview_tiles(channels, bands, camera.name))
    return tiles
