"""Time, kernels, peak memory and accuracy of the biophysical stage (issue 10 and 20 benchmark).

One frame of a synthetic face's band-integrated subsurface albedo maps (synth's truth
model, thickness and oxygenation at the fit's values), 6 bands, fitted by :func:`polarbssrdf.inverse.biophysical.fit.fit_biophysical`
with the default :class:`BiophysicalConfig`, each case in its own child process
so that its peak resident memory (``getrusage``) and its Dr.Jit kernels are its
own:

* ``target``: the bench's face (the darker Table 2 row ``forehead, IV`` with
  ``biophysical_std`` C_m 0.012, beta_m 0.01, C_h_out 0.02, C_h_in 0.012),
  512 x 512 texels, 1% multiplicative noise on the albedo maps (target: under
  30 s on the 2-core machine);
* ``cheek``: a face the project is not tuned on, Table 2 row ``cheek, IV`` with
  synth's default spreads, 256 x 256 texels, 1% noise (issue 20: under 30 s);
* ``accuracy``: the bench's face at 256 x 256 texels, noise-free and with 1% noise.

Every case prints the MAE of each map as a percentage of its Table 2 range:
the fit, the per-texel inversion of eq. 47 alone (``invert_bands`` at every
texel) and the best constant map (the truth's mean). It also prints where the
fit's time goes (start, kernels, and per Gauss-Newton step the Jacobian, the
conjugate-gradient solve and its iterations, the loss with its forward blurs,
the gradient with its adjoint blurs) and, from Dr.Jit's kernel history, the
kernels launched and compiled with LLVM's compile time.

With ``--kernel-cache cold,warm`` each case runs first in a fresh ``HOME``
(``~/.drjit`` empty, as on a newcomer's machine) and then again in the same
``HOME``: the warm run must compile nothing.

    .venv/bin/python bench/bench_bio.py [--cases target,cheek,accuracy] [--kernel-cache cold,warm]
                                        [--config JSON] [--reference JSON] [--out figures.json]

``--reference '{"spectral": "effective"}'`` runs every case again with those config
fields right after and prints the time and MAE ratios, so that two settings are
compared on the same machine under the same load (this one: what the band-effective
model, one node per band, saves and costs against the band integral's 19 nodes).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH_STD = {"C_m": 0.012, "beta_m": 0.01, "C_h_out": 0.02, "C_h_in": 0.012}
CASES = {"target": [(512, 0.01, "forehead")], "cheek": [(256, 0.01, "cheek")],
         "accuracy": [(256, 0.0, "forehead"), (256, 0.01, "forehead")]}
PARAMETERS = ("C_m", "beta_m", "C_h_out", "C_h_in")
KNOWN_LAYERS = {"thickness_mm": (0.25, 0.0, 0.10, 0.40), "gamma": (0.75, 0.0, 0.50, 0.95)}


class Profile:
    """Seconds and calls of the fit's named steps (wrapped module functions)."""

    def __init__(self):
        self.seconds, self.calls = {}, {}

    def wrap(self, module, name, label=None, extra=None):
        original = getattr(module, name)
        label = label or name

        def timed(*args, **kwargs):
            if extra:
                extra(args, kwargs)
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                self.seconds[label] = self.seconds.get(label, 0.0) + time.perf_counter() - start
                self.calls[label] = self.calls.get(label, 0) + 1

        setattr(module, name, timed)

    def instrument(self):
        """Wrap the biophysical fit's steps and the blur (a missing name is skipped)."""
        import polarbssrdf.inverse.biophysical.fit as fit
        import polarbssrdf.inverse.biophysical.gauss_newton as gauss_newton
        import polarbssrdf.inverse.biophysical.problem as problem
        import polarbssrdf.render.texture_diffusion as diffusion

        for module, name, label in ((fit, "start_maps", "start (per-texel inversion)"),
                                    (fit, "block_face_means", "face means (block inversion)"),
                                    (fit, "fit_kernels", "SoG kernels"),
                                    (problem.DataTerm, "precision", "Jacobian (forward AD)"),
                                    (gauss_newton, "solve_step", "step solve (CG)"),
                                    (gauss_newton, "_evaluate", "loss (forward, blurs)"),
                                    (gauss_newton, "_gradient", "gradient (reverse, adjoint blurs)"),
                                    (fit, "gauss_newton", "Gauss-Newton total"),
                                    (fit, "posterior_blocks", "posterior (std, noise)"),
                                    (fit, "NuisanceSensitivity", "nuisance sensitivities")):
            if hasattr(module, name):
                self.wrap(module, name, label)
        if hasattr(gauss_newton, "cg"):
            def count_iterations(args, kwargs):
                user = kwargs.get("callback")

                def callback(x):
                    self.calls["CG iterations"] = self.calls.get("CG iterations", 0) + 1
                    if user:
                        user(x)
                kwargs["callback"] = callback
            self.wrap(gauss_newton, "cg", "CG (scipy)", count_iterations)
        self.wrap(diffusion, "_sum_of_gaussians", "blur forward")
        self.wrap(diffusion, "_sum_of_gaussians_adjoint", "blur adjoint")

    def report(self):
        return {label: {"seconds": round(self.seconds.get(label, 0.0), 3), "calls": self.calls.get(label, 0)}
                for label in sorted(set(self.seconds) | set(self.calls))}


def run_case(texture, noise, region="forehead", overrides=None):
    """In this (child) process: fit one frame (``BiophysicalConfig(**overrides)``) and return its figures."""
    import drjit as dr
    import numpy as np

    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig, fit_biophysical
    from polarbssrdf.inverse.biophysical.start import start_maps
    from polarbssrdf.render.subsurface import subsurface_exit_fraction
    from polarbssrdf.skin.parameters import table2_ranges
    from polarbssrdf.spectral import default_bands
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import TruthSettings, truth_maps

    atlas = texel_atlas(to_mitsuba(face_mesh(1)), texture)
    # thickness and oxygenation at the fit's values: this bench times the fit and scores the
    # chromophores' model (bench/bio_off_prior.py scores faces where they are not)
    settings = (TruthSettings(skin=("forehead", "IV"), biophysical_std=BENCH_STD, skin_layers=KNOWN_LAYERS)
                if region == "forehead" else TruthSettings(skin=(region, "IV"), skin_layers=KNOWN_LAYERS))
    maps = truth_maps(atlas, settings, np.random.default_rng(1))
    bands = default_bands()
    albedo = subsurface_albedo(maps, bands)
    if noise > 0:
        albedo = albedo * (1.0 + noise * np.random.default_rng(7).standard_normal(albedo.shape))
    inputs = {f"rho_sss.{b.name}": albedo[i] for i, b in enumerate(bands)}
    inputs["eta"] = maps["eta"]
    config = BiophysicalConfig(**(overrides or {}))
    profile = Profile()
    profile.instrument()
    history = []

    def drain_history(_message=None):
        # every entry carries its kernel's IR source: kept for a whole 512^2 fit they held
        # more memory than the fit itself (12 of the 14.1 GiB once reported for 256^2)
        history.extend({key: h[key] for key in ("hash", "cache_hit", "backend_time", "execution_time")}
                       for h in dr.kernel_history([dr.KernelType.JIT]))

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history_clear()
    start = time.perf_counter()
    result = fit_biophysical(inputs, bands, atlas, config, progress=drain_history)
    seconds = time.perf_counter() - start
    drain_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    compiled = [h for h in history if not h["cache_hit"]]
    kernels = {"launched": len(history), "distinct": len({h["hash"] for h in history}),
               "compiled": len(compiled), "llvm_seconds": round(sum(h["backend_time"] for h in compiled) / 1e3, 2),
               "execution_seconds": round(sum(h["execution_time"] for h in history) / 1e3, 2)}
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
    return {"texture": texture, "noise": noise, "skin": [region, "IV"], "texels": int(valid.sum()),
            "bands": len(bands), "seconds": round(seconds, 2),
            "texels_per_second": round(float(valid.sum()) / seconds),
            "kernels": kernels, "profile": profile.report(),
            "maps": {n: result.maps[n].tolist() for n in PARAMETERS} if MAPS_OUT else None,
            "rounds": [{k: v for k, v in h.items() if k != "losses"} | {"steps": len(h["losses"]) - 1}
                       for h in result.history],
            "config": overrides or {}, "correlation_length": result.noise.get("correlation_length"),
            "errors": errors}


MAPS_OUT = False  # set in the child by --maps: the fitted maps go into the figures (to compare runs)


def child(texture, noise, region, home=None, maps=False, overrides=None):
    """Run :func:`run_case` in a fresh process (in ``home``, if given); its figures and peak RSS (MiB)."""
    code = (f"import json, resource, sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); "
            f"import bench_bio; bench_bio.MAPS_OUT = {bool(maps)}; "
            f"out = bench_bio.run_case({texture}, {noise}, {region!r}, json.loads({json.dumps(overrides or {})!r})); "
            "out['peak_rss_mib'] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024); "
            "print('RESULT ' + json.dumps(out))")
    env = dict(os.environ, HOME=str(home)) if home else None
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, env=env)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode or not lines:
        raise SystemExit(f"case {texture}^2, noise {noise} failed:\n{done.stderr[-2000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help=f"from {', '.join(CASES)}")
    parser.add_argument("--kernel-cache", default="", help="'cold,warm': run each case in a fresh HOME, "
                        "then again in it (default: this HOME, as it is)")
    parser.add_argument("--maps", action="store_true", help="keep the fitted maps in --out (to compare runs)")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures as JSON")
    parser.add_argument("--config", type=json.loads, default={}, help="BiophysicalConfig fields as JSON "
                        "(e.g. '{\"correlation_mm\": 5}'); default the defaults")
    parser.add_argument("--reference", type=json.loads, default=None, help="also run every case with these "
                        "BiophysicalConfig fields (JSON, '{}' for the defaults) right after, and print the ratios")
    args = parser.parse_args(argv)
    caches = [c for c in args.kernel_cache.split(",") if c] or ["as is"]
    figures = []
    for name in args.cases.split(","):
        for texture, noise, region in CASES[name]:
            home = tempfile.mkdtemp(prefix="bench-bio-home-") if caches != ["as is"] else None
            runs = [(cache, args.config) for cache in caches]
            if args.reference is not None:
                runs += [(cache, args.reference) for cache in caches]
            first = {}
            for cache, overrides in runs:
                print(f"{name}: {texture}^2, {region} IV, noise {noise:.0%}, kernel cache {cache}, "
                      f"config {json.dumps(overrides)} ...", flush=True)
                row = child(texture, noise, region, home, args.maps, overrides)
                row["case"], row["kernel_cache"] = name, cache
                figures.append(row)
                if cache in first:
                    print(f"  against config {json.dumps(first[cache]['config'])}: time "
                          f"{row['seconds'] / first[cache]['seconds']:.2f}x, MAE "
                          + ", ".join(f"{p} {row['errors'][p]['fit_pct'] / max(first[cache]['errors'][p]['fit_pct'], 1e-9):.2f}x"
                                      for p in PARAMETERS))
                first.setdefault(cache, row)
                if row.get("correlation_length"):
                    print(f"  correlation length {row['correlation_length']['correlation_mm']} mm "
                          f"({row['correlation_length']['from']})")
                k = row["kernels"]
                print(f"  {row['seconds']} s ({row['texels_per_second']:,} texels/s), peak RSS "
                      f"{row['peak_rss_mib']} MiB, rounds {[(r['steps'], round(r['seconds'], 1)) for r in row['rounds']]}")
                print(f"  kernels: {k['launched']:,} launched, {k['distinct']} distinct, {k['compiled']} compiled "
                      f"(LLVM {k['llvm_seconds']} s); kernel execution {k['execution_seconds']} s")
                steps = sum(r["steps"] for r in row["rounds"])
                for label, p in row["profile"].items():
                    per = (f", {p['seconds'] / steps:.2f} s per step"
                           if steps and not label.startswith(("start", "SoG", "Gauss")) else "")
                    print(f"  {label:36s} {p['seconds']:7.2f} s  {p['calls']:5d} calls{per}")
                for parameter, e in row["errors"].items():
                    print(f"  {parameter:8s} fit {e['fit_pct']:5.2f}%  per-texel {e['per_texel_pct']:6.2f}%  "
                          f"constant {e['constant_pct']:5.2f}%  (of the Table 2 range)")
    if args.out:
        args.out.write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
