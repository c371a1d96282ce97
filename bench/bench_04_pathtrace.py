"""Chapter 4 (path tracing): ray throughput, and the efficiency of each estimator.

  1. rays per second (camera + bounce + shadow rays, from the stats counters)
     and samples (camera paths) per second on the Cornell box, 256x256, 2 threads;
  2. for each estimator, the relative MSE against a long MIS reference and the time
     it took, at increasing spp until relMSE <= 1e-3 (or a time cap); efficiency
     1 / (relMSE * time), which is constant for a Monte Carlo estimator (MSE ~ 1/N),
     and the time to reach relMSE 1e-3 = relMSE * time / 1e-3;
  3. the same on cornell-small-light.scene: how much faster MIS reaches the
     cosine estimator's error.

The reference's own error is subtracted: relMSE(test vs ref) ~ relMSE(test) +
relMSE(ref), with relMSE(ref) estimated as relMSE(mis at N spp) * N / N_ref.
Targets (not tests): >= 20 Mrays/s on 2 cores; MIS reaching the cosine error in
<= 1/5 of its time on the small-light scene.  Printed as measured, met or not.
"""
import os
import tempfile

from common import chapter_stats

CHAPTER = "04_pathtrace"
TARGET = 1e-3
TIME_CAP = 25.0  # seconds per estimator, so the bench stays within a few minutes


def rays_per_second():
    s = chapter_stats(CHAPTER, "scenes/cornell.scene", "--size", "256x256", "--spp", 16, "--threads", 2,
                      "--probe-samples", 32)
    c, t = s["counters"], s["render_s"]
    rays = c["camera_rays"] + c["bounce_rays"] + c["shadow_rays"]
    samples = s["width"] * s["height"] * s["spp"]
    print(f"cornell 256x256 16 spp mis, 2 threads: {rays / t * 1e-6:6.2f} Mrays/s "
          f"(camera {c['camera_rays'] / t * 1e-6:.2f}, bounce {c['bounce_rays'] / t * 1e-6:.2f}, "
          f"shadow {c['shadow_rays'] / t * 1e-6:.2f}), {samples / t * 1e-6:.3f} M samples/s, "
          f"{rays / samples:.2f} rays per sample   [target 20 Mrays/s: {'met' if rays / t >= 20e6 else 'NOT met'}]")


def efficiency(scene, size, reference_spp, estimators, tmp):
    reference = os.path.join(tmp, os.path.basename(scene) + ".ref.pfm")
    s = chapter_stats(CHAPTER, scene, "--size", size, "--spp", reference_spp, "--seed", 1000,
                      "--probe-samples", 32, "--out", reference)
    print(f"{scene} {size}: reference {reference_spp} spp mis in {s['render_s']:.1f} s")
    ref_relmse = None
    results = {}
    for estimator in estimators:
        spp, measured = 4, None
        while True:
            s = chapter_stats(CHAPTER, scene, "--size", size, "--spp", spp, "--estimator", estimator,
                              "--ref", reference, "--probe-samples", 32)
            relmse, t = s["metrics"]["relmse"], s["render_s"]
            if estimator == "mis" and ref_relmse is None:
                ref_relmse = relmse * spp / reference_spp  # the reference's own error
            corrected = max(relmse - (ref_relmse or 0.0), 1e-12)
            measured = (spp, t, relmse, corrected)
            if corrected <= TARGET or t * 4 > TIME_CAP:
                break
            spp *= 4
        spp, t, relmse, corrected = measured
        time_to_target = corrected * t / TARGET
        results[estimator] = time_to_target
        print(f"  {estimator:10s} {spp:5d} spp {t:7.2f} s  relMSE {relmse:.3g} (minus reference {corrected:.3g})"
              f"  efficiency 1/(relMSE t) {1.0 / (corrected * t):10.1f}  time to relMSE 1e-3: {time_to_target:8.2f} s")
    return results


if __name__ == "__main__":
    print("== chapter 4 (04_pathtrace) ==")
    rays_per_second()
    with tempfile.TemporaryDirectory() as tmp:
        efficiency("scenes/cornell.scene", "256x256", 256, ("mis", "light", "cosine", "hemisphere"), tmp)
        r = efficiency("scenes/cornell-small-light.scene", "128x128", 1024, ("mis", "cosine"), tmp)
        ratio = r["cosine"] / r["mis"]
        print(f"small light: MIS reaches relMSE 1e-3 {ratio:.1f}x faster than cosine "
              f"[target >= 5x: {'met' if ratio >= 5 else 'NOT met'}]")
