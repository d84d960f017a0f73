"""The biophysical stage: melanin and hemoglobin from subsurface albedo (supplement sec. 5.3).

* :mod:`.model`: four maps (``C_m``, ``beta_m``, ``C_h_out``, ``C_h_in``) ->
  lobe albedo per band through the two-layer skin model and the texture-space
  layered blur synth renders with (eq. 42, 46, 47), differentiable in Dr.Jit;
* :mod:`.fit`: the per-texel start and the Gauss-Newton fit (eq. 40-47);
* :mod:`.config`: its settings (a run config's ``bio`` object);
* :mod:`.stage`: per frame of a result, maps, previews and the region summary.

Data flow: ``rho_sss`` maps of the static and dynamic stages (read from the
result directory) -> start -> kernels -> fit -> ``bio/maps_f####.exr``.
"""
