"""The light stage: cameras around the head, each with a near-coaxial polarized light.

Supplement sec. 3.1 and 8: every camera has a point light next to it (the
paper's is about 5.7 degrees off the camera axis as seen from the face),
linearly polarized along the camera's image x; in a frame one light is on
and its camera records I0/I45/I90/I135. Lengths in mm.

Cameras follow Mitsuba's ``look_at`` convention: ``forward`` from the origin
to the target, image x (``right``) = ``forward x up``, image y = ``up``
made orthogonal. The light's polarizer is a sheet facing along the camera's
forward direction (``ppoint``'s ``polarizer_normal``), so its light is
polarized along image x in every pixel of that camera's Stokes frame.
"""

from __future__ import annotations

import dataclasses

import numpy as np

PAPER_LIGHT_OFFSET_DEG = 5.7


def _unit(vector, name):
    vector = np.asarray(vector, dtype=np.float64)
    norm = np.linalg.norm(vector)
    if vector.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"{name} must be a finite, non-zero 3-vector, got {vector.tolist()}")
    return vector / norm


@dataclasses.dataclass(frozen=True)
class RigCamera:
    """A pinhole camera of the rig (Mitsuba ``perspective``).

    Attributes
    ----------
    name : str
    origin, target, up : 3-sequences
        ``look_at`` frame, mm.
    fov_x_deg : float
        Horizontal field of view, degrees.
    width, height : int
        Image size in pixels.
    """

    name: str
    origin: tuple
    target: tuple
    up: tuple
    fov_x_deg: float
    width: int
    height: int

    def __post_init__(self):
        forward = np.asarray(self.target, float) - np.asarray(self.origin, float)
        _unit(forward, f"camera {self.name}: target - origin")
        if abs(np.dot(_unit(forward, "forward"), _unit(self.up, f"camera {self.name}: up"))) > 0.999:
            raise ValueError(f"camera {self.name}: 'up' is parallel to the viewing direction")
        if not 0 < self.fov_x_deg < 180:
            raise ValueError(f"camera {self.name}: fov_x_deg must lie in (0, 180)")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera {self.name}: image size must be positive")

    @property
    def forward(self):
        return _unit(np.asarray(self.target, float) - np.asarray(self.origin, float), "forward")

    @property
    def right(self):
        """Image x in world space."""
        return _unit(np.cross(self.forward, self.up), "right")

    @property
    def image_up(self):
        """Image y in world space."""
        return np.cross(self.right, self.forward)

    @property
    def distance_mm(self):
        return float(np.linalg.norm(np.asarray(self.target, float) - np.asarray(self.origin, float)))

    def sensor_dict(self, spp=16, seed=0):
        """Mitsuba ``perspective`` sensor with a box-filtered float32 film."""
        import mitsuba as mi

        return {
            "type": "perspective",
            "fov": float(self.fov_x_deg),
            "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=list(map(float, self.origin)),
                                                       target=list(map(float, self.target)),
                                                       up=list(map(float, self.up))),
            "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
            "film": {"type": "hdrfilm", "width": int(self.width), "height": int(self.height),
                     "rfilter": {"type": "box"}, "pixel_format": "luminance"},
        }


@dataclasses.dataclass(frozen=True)
class RigLight:
    """A ``ppoint`` light of the rig.

    Attributes
    ----------
    name : str
    position : 3-sequence, mm
    intensity : float, W/sr (Stokes S0 leaving the polarizer)
    polarization_axis : 3-sequence
    polarizer_normal : 3-sequence or None
    """

    name: str
    position: tuple
    intensity: float
    polarization_axis: tuple
    polarizer_normal: tuple | None = None

    def __post_init__(self):
        if not np.isfinite(self.intensity) or self.intensity < 0:
            raise ValueError(f"light {self.name}: intensity must be finite and >= 0")
        _unit(self.polarization_axis, f"light {self.name}: polarization_axis")

    def emitter_dict(self):
        result = {"type": "ppoint", "position": list(map(float, self.position)),
                  "intensity": float(self.intensity),
                  "polarization_axis": list(map(float, self.polarization_axis))}
        if self.polarizer_normal is not None:
            result["polarizer_normal"] = list(map(float, self.polarizer_normal))
        return result


def coaxial_light(camera, name=None, offset_deg=PAPER_LIGHT_OFFSET_DEG, intensity=4e5):
    """The light beside ``camera``: ``offset_deg`` above its axis as seen from the target.

    Polarized along the camera's image x, with the polarizer sheet facing
    along the camera's forward direction.
    """
    offset = camera.distance_mm * np.tan(np.deg2rad(offset_deg))
    position = np.asarray(camera.origin, float) + offset * camera.image_up
    return RigLight(name or f"light_{camera.name}", tuple(position), float(intensity),
                    tuple(camera.right), tuple(camera.forward))


@dataclasses.dataclass(frozen=True)
class LightStage:
    """Cameras, lights, and which light fires for which camera."""

    cameras: tuple
    lights: tuple
    light_for_camera: dict

    def __post_init__(self):
        camera_names = [c.name for c in self.cameras]
        light_names = [light.name for light in self.lights]
        for kind, names in (("camera", camera_names), ("light", light_names)):
            if len(set(names)) != len(names):
                raise ValueError(f"duplicate {kind} names in the light stage: {names}")
        for camera, light in self.light_for_camera.items():
            if camera not in camera_names or light not in light_names:
                raise ValueError(f"light_for_camera: unknown pair {camera!r} -> {light!r}")

    def camera(self, name):
        return next(c for c in self.cameras if c.name == name)

    def light(self, name):
        return next(light for light in self.lights if light.name == name)


def ring_light_stage(n_cameras=8, distance_mm=600.0, azimuth_span_deg=120.0,
                     elevations_deg=(-10.0, 15.0), target=(0.0, 0.0, 0.0), width=512, height=512,
                     fov_x_deg=22.0, light_offset_deg=PAPER_LIGHT_OFFSET_DEG, intensity=4e5):
    """Cameras on an arc in front of a face looking along -z (the canonical face faces +z).

    Azimuths spread evenly over ``azimuth_span_deg`` around +z, elevations
    alternate through ``elevations_deg``; each camera gets a coaxial light.
    """
    if n_cameras < 1:
        raise ValueError("n_cameras must be >= 1")
    azimuths = (np.linspace(-0.5, 0.5, n_cameras) * azimuth_span_deg if n_cameras > 1
                else np.zeros(1))
    cameras, lights, pairs = [], [], {}
    for index, azimuth in enumerate(np.deg2rad(azimuths)):
        elevation = np.deg2rad(elevations_deg[index % len(elevations_deg)])
        direction = np.array([np.sin(azimuth) * np.cos(elevation), np.sin(elevation),
                              np.cos(azimuth) * np.cos(elevation)])
        origin = np.asarray(target, float) + distance_mm * direction
        camera = RigCamera(f"cam{index:02d}", tuple(origin), tuple(map(float, target)),
                           (0.0, 1.0, 0.0), fov_x_deg, width, height)
        light = coaxial_light(camera, f"light{index:02d}", light_offset_deg, intensity)
        cameras.append(camera)
        lights.append(light)
        pairs[camera.name] = light.name
    return LightStage(tuple(cameras), tuple(lights), pairs)
