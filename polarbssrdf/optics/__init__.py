"""Dr.Jit-generic polarization optics shared by the plugins and the inverse stages.

Modules: :mod:`.stokes` (Stokes vectors, analysers), :mod:`.mueller`
(Mueller matrices, frames; eq. 1, 4), :mod:`.fresnel` (eq. 2, T = 1 - R,
eq. 12), :mod:`.microfacet` (GGX, Smith), :mod:`.pbrdf` (the pBRDF lobes,
eq. 5, 6, 19), :mod:`.coaxial` (eq. 19-24) and :mod:`.dop` (Atkinson-Hancock).
"""

from polarbssrdf.optics.coaxial import (
    coaxial_fresnel_terms,
    coaxial_kappa,
    coaxial_stokes,
    separate_observations,
    specular_polarization_observation,
    subsurface_observation,
    subsurface_polarization_observation,
)
from polarbssrdf.optics.dop import diffuse_degree_of_polarization
from polarbssrdf.optics.fresnel import (
    average_diffuse_fresnel_reflectance,
    brewster_angle,
    fresnel_reflectance,
    fresnel_transmittance,
    plus_minus,
    reflection_phase_cosine,
    refracted_cosine,
)
from polarbssrdf.optics.microfacet import (
    ggx_distribution,
    microfacet_reflection_term,
    smith_g1_ggx,
    smith_masking_shadowing,
)
from polarbssrdf.optics.mueller import (
    coordinate_system,
    depolarizer,
    fresnel_mueller,
    linear_polarizer,
    rotate_mueller_basis,
    rotate_stokes_basis,
    rotator,
    stokes_basis,
)
from polarbssrdf.optics.pbrdf import (
    microfacet_lobe_mueller,
    pbrdf_intensity,
    pbrdf_mueller,
    subsurface_entry_stokes_row,
    subsurface_exit_stokes_column,
    subsurface_lobe_mueller,
)
from polarbssrdf.optics.stokes import (
    ANALYSER_ANGLES_DEG,
    analyser_intensity,
    angle_of_linear_polarization,
    degree_of_linear_polarization,
    degree_of_polarization,
    linear_analyser_row,
    polarization_images,
    stokes_from_polarization_images,
)
