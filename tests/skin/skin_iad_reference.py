"""Adding-doubling references (iadpython, independent of our code) for the skin tests."""

from __future__ import annotations

import copy

import iadpython
from iadpython.combine import add_layers, add_slide_above, simple_single_layer_matrices
from iadpython.start import boundary_layer


def specular(eta: float) -> float:
    """Normal-incidence Fresnel reflectance of the air/medium boundary."""
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def slab_rt(albedo: float, optical_thickness: float, eta: float, quad_pts: int = 16):
    """(R, T_diffuse, T_total) of a slab in air, per unit light entering
    (specular reflection removed: (ur1 - Rs) / (1 - Rs)). T_diffuse also
    removes the unscattered beam."""
    s = iadpython.Sample(a=albedo, b=optical_thickness, g=0.0, d=1.0, n=eta, quad_pts=quad_pts)
    ur1, ut1, _, _ = s.rt()
    _, unscattered_t = s.unscattered_rt()
    rs = specular(eta)
    return (ur1 - rs) / (1.0 - rs), (ut1 - unscattered_t) / (1.0 - rs), ut1 / (1.0 - rs)


def two_layer_reflectance(albedo_out, tau_out, albedo_in, eta, quad_pts: int = 16, tau_in: float = 2.0e4):
    """Diffuse reflectance of a slab over a (practically) semi-infinite slab,
    index eta in both, air above, built from iadpython's layer matrices:
    add the two layers (asymmetric adding), then the air boundary on top."""
    s = iadpython.Sample(a=albedo_out, b=tau_out, g=0.0, d=1.0, n=eta, quad_pts=quad_pts)
    s.update_quadrature()
    top = copy.deepcopy(s)
    r_out, t_out = simple_single_layer_matrices(top)
    bottom = copy.deepcopy(s)
    bottom.a, bottom.b = albedo_in, tau_in
    r_in, t_in = simple_single_layer_matrices(bottom)
    R02, R20, T02, T20 = add_layers(s, r_out, r_out, t_out, t_out, r_in, r_in, t_in, t_in)
    R01, R10, T01, T10 = boundary_layer(s, top=True)
    R, _, T, _ = add_slide_above(s, R01, R10, T01, T10, R02, R20, T02, T20)
    ur1, _, _, _ = s.UX1_and_UXU(R, T)
    rs = specular(eta)
    return (ur1 - rs) / (1.0 - rs)


def single_semi_infinite(albedo, eta, quad_pts: int = 16):
    """Diffuse reflectance of a semi-infinite medium via Sample.rt() (huge b)."""
    return slab_rt(albedo, 1.0e5, eta, quad_pts)[0]


if __name__ == "__main__":  # pragma: no cover - manual consistency check
    print(single_semi_infinite(0.99, 1.4), two_layer_reflectance(0.99, 5.0, 0.99, 1.4))
