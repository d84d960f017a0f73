"""Texel-views of a sphere seen by a ring of cameras with near-coaxial lights, made in memory.

The analyser samples come from the model itself with known maps, so a fit
that recovers the maps tests the losses, the closed-form albedo and the
optimizer (the model is tested against Mitsuba in test_model.py). The ring
has the real rig's geometry: the light 5.7 degrees off the camera axis,
polarized along image x (dichroic sheet facing the camera).
"""

from __future__ import annotations

import types

import numpy as np

from polarbssrdf._arrays import to_jit


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def ring_cameras(count, distance=450.0, elevations=(0.0, 25.0, -25.0)):
    """(centre, right, up, light position) per camera, looking at the origin."""
    cameras = []
    per_ring = [count - 2 * (count // 3), count // 3, count // 3]
    for elevation, n in zip(elevations, per_ring):
        for k in range(n):
            azimuth = 2 * np.pi * (k + 0.5 * (elevation != 0)) / max(n, 1)
            e = np.radians(elevation)
            centre = distance * np.array([np.sin(azimuth) * np.cos(e), np.sin(e),
                                          np.cos(azimuth) * np.cos(e)])
            forward = _unit(-centre)
            right = _unit(np.cross(forward, [0.0, 1.0, 0.0]))
            up = np.cross(right, forward)
            light = centre + np.tan(np.radians(5.7)) * distance * right
            cameras.append((centre, right, up, light, forward))
    return cameras


class InMemoryStore:
    """The read side of an observation store over arrays held in memory."""

    def __init__(self, views, texture_size, bands, block_size=8):
        self.views_data = views
        self.texture_size = texture_size
        self.block_size = block_size
        self.bands = tuple(bands)
        self.views = []

    def __len__(self):
        return len(self.views_data.texel)

    def read_window(self, row0, col0, rows, cols):
        T = self.texture_size
        r, c = np.divmod(self.views_data.texel, T)
        keep = (r >= row0) & (r < row0 + rows) & (c >= col0) & (c < col0 + cols)
        from polarbssrdf.inverse.observations.store import FIELDS, TexelViews

        return TexelViews(**{name: getattr(self.views_data, name)[keep] for name in FIELDS})

    def texel_view_counts(self):
        T = self.texture_size
        return np.bincount(self.views_data.texel, minlength=T * T).reshape(T, T)


def sphere_views(atlas, truth, rho_sss, n_cameras=12, intensity=4e4, min_cosine=0.1,
                 noise=0.0, seed=0):
    """(TexelViews-like namespace) of every texel seen and lit by each camera of a ring.

    ``truth`` holds (T, T) maps of eta, rho_s, alpha_s, rho_ss, alpha_ss and
    the normals ``normal`` (T, T, 3); ``rho_sss`` is (n_bands, T, T).
    """
    import mitsuba as mi

    from polarbssrdf.inverse.polarimetric.model import ViewGeometry, predict_stokes

    T = atlas.resolution
    valid = np.flatnonzero(atlas.valid.ravel())
    p = atlas.position.reshape(-1, 3)[valid].astype(np.float64)
    n = truth["normal"].reshape(-1, 3)[valid].astype(np.float64)
    parts = []
    for index, (centre, right, up, light, forward) in enumerate(ring_cameras(n_cameras)):
        to_camera = _unit(centre - p)
        to_light_vec = light - p
        distance = np.linalg.norm(to_light_vec, axis=-1)
        to_light = to_light_vec / distance[:, None]
        keep = (np.sum(n * to_camera, -1) > min_cosine) & (np.sum(n * to_light, -1) > min_cosine)
        absorption = np.cross(forward, right)
        field = _unit(np.cross(-to_light, absorption))
        basis = _unit(np.cross(-to_camera, up))
        parts.append(dict(texel=valid[keep].astype(np.int32),
                          view=np.full(keep.sum(), index, np.int16),
                          to_camera=to_camera[keep], to_light=to_light[keep],
                          light_distance_mm=distance[keep],
                          light_intensity=np.full(keep.sum(), intensity),
                          light_field=field[keep], camera_basis=basis[keep],
                          normal=n[keep]))
    data = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    Float, Array3f = mi.Float, mi.Vector3f

    def vec(a):
        return Array3f(*(to_jit(Float, a[:, i], np.float32) for i in range(3)))

    geometry = ViewGeometry(vec(data["to_camera"]), vec(data["to_light"]),
                            to_jit(Float, data["light_intensity"] / data["light_distance_mm"] ** 2,
                                   np.float32),
                            vec(data["light_field"]), vec(data["camera_basis"]))
    texel = data["texel"]
    params = [to_jit(Float, truth[name].ravel()[texel], np.float32)
              for name in ("eta", "rho_s", "alpha_s", "rho_ss", "alpha_ss")]
    stokes = predict_stokes(geometry, vec(data.pop("normal")), *params)
    analyser = np.stack([np.stack([np.array(image) for image in stokes.analyser_images(
        to_jit(Float, rho_sss[b].ravel()[texel], np.float32))], axis=-1)
        for b in range(len(rho_sss))], axis=1)
    if noise:
        rng = np.random.default_rng(seed)
        analyser = analyser * (1.0 + noise * rng.standard_normal(analyser.shape))
    data["analyser"] = analyser.astype(np.float32)
    for key in ("to_camera", "to_light", "light_distance_mm", "light_intensity", "light_field",
                "camera_basis"):
        data[key] = data[key].astype(np.float32)
    return types.SimpleNamespace(**data)
