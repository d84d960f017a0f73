"""Render time of the Python ``pbssrdf`` BSDF vs Mitsuba's C++ ``pplastic`` (issue 2).

Both BSDFs sit on the sphere of ``scenes/sphere.xml`` (radius 50 mm, camera
500 mm away, coaxial ``ppoint`` light polarized along image x) with the same
parameters: GGX, ``eta``, ``alpha`` and diffuse albedo; ``pbssrdf`` has
``rho_s = 1`` and ``rho_ss = 0`` so that it is the same model as
``pplastic`` (Baek 2018). Each configuration renders with ``stokes(direct)``
and ``stokes(path)`` at the same resolution and spp, in one process: one
warm-up render first (kernel tracing and compilation), then the timed
renders, alternating between the two BSDFs so that drift hits both alike.
A render is timed from the call to :func:`mitsuba.render` until
``dr.eval`` + ``dr.sync_thread`` return, so it includes Python tracing,
kernel-cache lookup and execution.

Run ``python bench/bench_render.py`` (``--help`` for options). Prints one row
per configuration with the median times and the ratio pbssrdf / pplastic
(target: <= 1.2).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import polarbssrdf  # noqa: F401  (configures libLLVM, registers the plugins)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402

from polarbssrdf.io import atomic_write_text  # noqa: E402

ETA, ALPHA, ALBEDO = 1.4, 0.35, 0.6
"""Shared material: relative index, GGX roughness, diffuse (subsurface) albedo."""

BSDFS = ("pbssrdf", "pplastic")


def bsdf_dict(name: str) -> dict:
    """The sphere's material as a Mitsuba dict: ``pbssrdf`` or the equivalent ``pplastic``."""
    if name == "pbssrdf":
        return {"type": "pbssrdf", "eta": ETA, "alpha_s": ALPHA, "rho_s": 1.0,
                "rho_ss": 0.0, "rho_sss": ALBEDO}
    if name == "pplastic":
        return {"type": "pplastic", "distribution": "ggx", "alpha": ALPHA, "int_ior": ETA,
                "ext_ior": 1.0, "diffuse_reflectance": {"type": "uniform", "value": ALBEDO}}
    raise ValueError(f"unknown BSDF '{name}' (expected one of {', '.join(BSDFS)})")


def integrator_dict(name: str, max_depth: int) -> dict:
    """``stokes`` around ``direct``, or around ``path`` with ``max_depth`` (vertices)."""
    if name == "direct":
        inner = {"type": "direct"}
    elif name == "path":
        inner = {"type": "path", "max_depth": max_depth}
    else:
        raise ValueError(f"unknown integrator '{name}' (expected direct or path)")
    return {"type": "stokes", "nested": inner}


def scene_dict(bsdf: str, integrator: str, resolution: int, spp: int, max_depth: int) -> dict:
    """The sphere scene of ``scenes/sphere.xml`` (mm) with the given BSDF and integrator."""
    return {
        "type": "scene",
        "integrator": integrator_dict(integrator, max_depth),
        "sensor": {
            "type": "perspective",
            "fov": 14.0,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 500], target=[0, 0, 0],
                                                       up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                     "rfilter": {"type": "box"}, "pixel_format": "luminance"},
        },
        "light": {"type": "ppoint", "position": [0.0, 0.0, 500.0], "intensity": 500000.0,
                  "polarization_axis": [1.0, 0.0, 0.0], "polarizer_normal": [0.0, 0.0, -1.0]},
        "sphere": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 50.0,
                   "bsdf": bsdf_dict(bsdf)},
    }


def timed_render(scene, spp: int, seed: int) -> tuple[float, float, np.ndarray]:
    """One render: wall-clock seconds, Dr.Jit's kernel execution seconds, the ``S0`` image.

    The wall time runs from the call to :func:`mitsuba.render` until the
    image is evaluated (``dr.eval`` + ``dr.sync_thread``). The kernel time
    sums ``execution_time`` of the render's JIT kernels in Dr.Jit's kernel
    history (as Dr.Jit reports it for the LLVM backend). The ``S0`` image
    (H x W NumPy array) is used to check that both BSDFs render the same
    picture.
    """
    dr.sync_thread()
    dr.kernel_history()  # clear
    start = time.perf_counter()
    image = mi.render(scene, seed=seed, spp=spp)
    dr.eval(image)
    dr.sync_thread()
    wall = time.perf_counter() - start
    kernels = sum(k.get("execution_time", 0.0) for k in dr.kernel_history()
                  if k.get("type") == dr.KernelType.JIT) * 1e-3
    names = [field.name for field in scene.sensors()[0].film().bitmap().struct_()]
    return wall, kernels, image.numpy()[:, :, names.index("S0.R")]


def compare_images(ours: np.ndarray, reference: np.ndarray) -> dict:
    """Same-picture check of two ``S0`` renders with the same seed.

    Returns
    -------
    dict
        ``nan_pixels`` of each image and ``mean_relative_difference`` of
        their means over the pixels finite in both.
    """
    finite = np.isfinite(ours) & np.isfinite(reference)
    mean_ours = float(ours[finite].mean(dtype=np.float64))
    mean_reference = float(reference[finite].mean(dtype=np.float64))
    return {"nan_pixels": {"pbssrdf": int(np.isnan(ours).sum()),
                           "pplastic": int(np.isnan(reference).sum())},
            "mean_relative_difference": mean_ours / mean_reference - 1.0}


def benchmark(variant: str, integrator: str, resolution: int, spp: int, runs: int,
              max_depth: int) -> dict:
    """Median render times of both BSDFs in one variant and integrator.

    Parameters
    ----------
    variant:
        A polarized LLVM Mitsuba variant.
    integrator:
        ``direct`` or ``path`` (inside ``stokes``).
    resolution:
        Image width and height in pixels.
    spp:
        Samples per pixel.
    runs:
        Timed renders per BSDF (after one warm-up render each).
    max_depth:
        ``path``'s maximum depth.

    Returns
    -------
    dict
        ``times`` (BSDF -> list of seconds), ``median`` (BSDF -> seconds),
        ``warmup`` (BSDF -> seconds of the first render), ``ratio`` (of the
        medians), ``min_ratio`` (of the fastest runs), ``paired_ratio``
        (median over runs of the ratio of the two back-to-back renders),
        ``kernel_ratio`` and the same-picture checks of the first timed
        renders (same seed): ``mean_S0_relative_difference``, ``nan_pixels``.
    """
    mi.set_variant(variant)
    polarbssrdf.register_plugins()
    scenes = {name: mi.load_dict(scene_dict(name, integrator, resolution, spp, max_depth))
              for name in BSDFS}
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    warmup = {name: timed_render(scenes[name], spp, seed=0)[0] for name in BSDFS}
    times = {name: [] for name in BSDFS}
    kernel_times = {name: [] for name in BSDFS}
    first_images = {}
    for run in range(runs):
        order = BSDFS if run % 2 == 0 else BSDFS[::-1]
        for name in order:
            wall, kernels, s0 = timed_render(scenes[name], spp, seed=run + 1)
            times[name].append(wall)
            kernel_times[name].append(kernels)
            first_images.setdefault(name, s0)
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    median = {name: statistics.median(values) for name, values in times.items()}
    minimum = {name: min(values) for name, values in times.items()}
    kernel_median = {name: statistics.median(v) for name, v in kernel_times.items()}
    check = compare_images(first_images["pbssrdf"], first_images["pplastic"])
    return {"variant": variant, "integrator": integrator, "resolution": resolution, "spp": spp,
            "max_depth": max_depth if integrator == "path" else None, "runs": runs,
            "times": times, "median": median, "min": minimum, "warmup": warmup,
            "kernel_times": kernel_times, "kernel_median": kernel_median,
            "ratio": median["pbssrdf"] / median["pplastic"],
            "min_ratio": minimum["pbssrdf"] / minimum["pplastic"],
            "paired_ratio": statistics.median(a / b for a, b in zip(times["pbssrdf"],
                                                                     times["pplastic"])),
            "nan_pixels": check["nan_pixels"],
            "kernel_ratio": kernel_median["pbssrdf"] / kernel_median["pplastic"],
            "mean_S0_relative_difference": check["mean_relative_difference"]}


def parse_args(argv=None) -> argparse.Namespace:
    """Command-line options of the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", default="llvm_ad_mono_polarized,llvm_ad_spectral_polarized",
                        help="comma-separated polarized variants")
    parser.add_argument("--integrators", default="direct,path",
                        help="comma-separated: direct, path")
    parser.add_argument("--resolution", type=int, default=256, help="pixels (square)")
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel")
    parser.add_argument("--runs", type=int, default=7, help="timed renders per BSDF (>= 5)")
    parser.add_argument("--max-depth", type=int, default=3, help="path's max_depth")
    parser.add_argument("--json", default=None, help="also write all timings to this file")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be >= 1")
    return args


def main(argv=None) -> int:
    """Run every configuration and print a table of medians and ratios."""
    args = parse_args(argv)
    load = os.getloadavg()
    print(f"load average at the start: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print(f"pbssrdf vs pplastic: {args.resolution}x{args.resolution}, {args.spp} spp, "
          f"median of {args.runs} runs after 1 warm-up, path max_depth={args.max_depth}; "
          f"eta={ETA}, alpha={ALPHA}, albedo={ALBEDO}, rho_ss=0")
    print(f"{'variant':<27} {'integrator':<15} {'pbssrdf[s]':>10} {'pplastic[s]':>11} "
          f"{'ratio':>5} {'paired':>6} {'min-ratio':>9} {'kernel-ratio':>12} {'warm-up[s]':>11} "
          f"{'S0-diff':>8} {'NaN px':>6}")
    results = []
    for variant in args.variants.split(","):
        for integrator in args.integrators.split(","):
            r = benchmark(variant.strip(), integrator.strip(), args.resolution, args.spp,
                          args.runs, args.max_depth)
            results.append(r)
            label = "stokes(direct)" if integrator == "direct" else \
                f"stokes(path,{args.max_depth})"
            nans = f"{r['nan_pixels']['pbssrdf']}/{r['nan_pixels']['pplastic']}"
            print(f"{r['variant']:<27} {label:<15} {r['median']['pbssrdf']:>10.3f} "
                  f"{r['median']['pplastic']:>11.3f} {r['ratio']:>5.2f} {r['paired_ratio']:>6.2f} "
                  f"{r['min_ratio']:>9.2f} "
                  f"{r['kernel_ratio']:>12.2f} "
                  f"{r['warmup']['pbssrdf']:>5.2f}/{r['warmup']['pplastic']:<5.2f} "
                  f"{r['mean_S0_relative_difference']:>+8.1e} {nans:>6}", flush=True)
    load = os.getloadavg()
    print(f"load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} "
          f"on {os.cpu_count()} CPUs (other processes inflate and scatter the timings)")
    worst = max(r["ratio"] for r in results)
    print(f"worst ratio {worst:.2f} (target <= 1.2): {'OK' if worst <= 1.2 else 'ABOVE TARGET'}")
    print("columns: pbssrdf[s], pplastic[s] = median wall-clock render times; ratio = "
          "their quotient (the target); paired = median of the per-run quotients of back-to-back "
          "renders (robust to load from other processes); "
          "min-ratio = quotient of the fastest runs; "
          "kernel-ratio = quotient of the medians of Dr.Jit's reported kernel execution "
          "times; warm-up = first render pbssrdf/pplastic (tracing + compilation or "
          "kernel-cache load); S0-diff = relative difference of the mean S0 of the first "
          "timed renders (same seed) over pixels finite in both; NaN px = NaN pixels in "
          "those S0 images (pbssrdf/pplastic)")
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n", overwrite=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
