"""Time, peak memory and accuracy of the biophysical stage (issue 10 benchmark).

One frame of a synthetic face's subsurface albedo maps (synth's truth model:
the darker Table 2 row ``forehead, IV`` with real spatial variation,
``biophysical_std`` C_m 0.012, beta_m 0.01, C_h_out 0.02, C_h_in 0.012), 6
bands, fitted by :func:`polarbssrdf.inverse.biophysical.fit.fit_biophysical` with
the default :class:`BiophysicalConfig`, each case in its own child process so
that its peak resident memory (``getrusage``) is its own:

* ``target``: 512 x 512 texels, 1% multiplicative noise on the albedo maps
  (target: under 30 s on the 2-core machine);
* ``accuracy``: 256 x 256 texels, noise-free and with 1% noise.

Every case prints the MAE of each map as a percentage of its Table 2 range:
the fit, the per-texel inversion of eq. 47 alone (``invert_bands`` at every
texel) and the best constant map (the truth's mean).

    .venv/bin/python bench/bench_bio.py [--cases target,accuracy] [--out figures.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

CASES = {"target": [(512, 0.01)], "accuracy": [(256, 0.0), (256, 0.01)]}
PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")


def run_case(texture, noise):
    """In this (child) process: fit one frame and return its figures."""
    import numpy as np

    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig, fit_biophysical, start_maps
    from polarbssrdf.render.subsurface import subsurface_exit_fraction
    from polarbssrdf.skin.parameters import table2_ranges
    from polarbssrdf.spectral import default_bands
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import TruthSettings, truth_maps

    atlas = texel_atlas(to_mitsuba(face_mesh(1)), texture)
    settings = TruthSettings(skin=("forehead", "IV"),
                             biophysical_std={"C_m": 0.012, "beta_m": 0.01, "C_h_out": 0.02,
                                              "C_h_in": 0.012})
    maps = truth_maps(atlas, settings, np.random.default_rng(1))
    bands = default_bands()
    albedo = subsurface_albedo(maps, bands)
    if noise > 0:
        albedo = albedo * (1.0 + noise * np.random.default_rng(7).standard_normal(albedo.shape))
    inputs = {f"rho_sss.{b.name}": albedo[i] for i, b in enumerate(bands)}
    inputs["eta"] = maps["eta"]
    config = BiophysicalConfig()
    start = time.perf_counter()
    result = fit_biophysical(inputs, bands, atlas, config)
    seconds = time.perf_counter() - start
    valid = atlas.valid
    per_texel, _ = start_maps(albedo * subsurface_exit_fraction(maps["eta"])[None], valid, atlas,
                              bands, maps["eta"], BiophysicalConfig(start_texel_mm=0.0))
    ranges = table2_ranges()
    errors = {}
    for name in PARAMETERS:
        span = ranges[name][1] - ranges[name][0]
        truth = maps[name][valid]
        errors[name] = {
            "fit_pct": 100 * float(np.abs(result.maps[name][valid] - truth).mean() / span),
            "per_texel_pct": 100 * float(np.abs(per_texel[name][valid] - truth).mean() / span),
            "constant_pct": 100 * float(np.abs(truth - truth.mean()).mean() / span)}
    return {"texture": texture, "noise": noise, "texels": int(valid.sum()), "bands": len(bands),
            "seconds": round(seconds, 2), "texels_per_second": round(float(valid.sum()) / seconds),
            "rounds": [{k: v for k, v in h.items() if k != "losses"} | {"steps": len(h["losses"]) - 1}
                       for h in result.history],
            "errors": errors}


def child(texture, noise):
    """Run :func:`run_case` in a fresh process; its figures and peak RSS (MiB)."""
    code = (f"import json, resource, sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); "
            f"import bench_bio; out = bench_bio.run_case({texture}, {noise}); "
            "out['peak_rss_mib'] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024); "
            "print('RESULT ' + json.dumps(out))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode or not lines:
        raise SystemExit(f"case {texture}^2, noise {noise} failed:\n{done.stderr[-2000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help=f"from {', '.join(CASES)}")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures as JSON")
    args = parser.parse_args(argv)
    figures = []
    for name in args.cases.split(","):
        for texture, noise in CASES[name]:
            print(f"{name}: {texture}^2, noise {noise:.0%} ...", flush=True)
            row = child(texture, noise)
            row["case"] = name
            figures.append(row)
            print(f"  {row['seconds']} s ({row['texels_per_second']:,} texels/s), peak RSS "
                  f"{row['peak_rss_mib']} MiB, rounds {[(r['steps'], round(r['seconds'], 1)) for r in row['rounds']]}")
            for parameter, e in row["errors"].items():
                print(f"  {parameter:8s} fit {e['fit_pct']:5.2f}%  per-texel {e['per_texel_pct']:6.2f}%  "
                      f"constant {e['constant_pct']:5.2f}%  (of the Table 2 range)")
    if args.out:
        args.out.write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
