"""Chapter 2 (Whitted) on the Cornell spheres at 512x512: time and rays per
second for the full ray tree and with Hall & Greenberg pruning (--min-weight),
1 and 2 threads, best of 3."""
from common import best_of

RAY_KINDS = ("camera_rays", "shadow_rays", "reflected_rays", "refracted_rays")

print("== chapter 2 (02_whitted), scenes/cornell-spheres.scene, 512x512, --light-samples 4, best of 3 ==")
for label, extra in (("full tree", []), ("--min-weight 0.01", ["--min-weight", "0.01"]),
                     ("--min-weight 0.05", ["--min-weight", "0.05"])):
    for threads in (1, 2):
        s = best_of(3, "02_whitted", "scenes/cornell-spheres.scene", "--size", "512x512", "--light-samples", 4,
                    "--threads", threads, *extra)
        c, t = s["counters"], s["render_s"]
        rays = sum(c[k] for k in RAY_KINDS)
        print(f"{label:18s} threads {threads}: render {t * 1000:7.1f} ms, {rays / 1e6:6.2f} M rays "
              f"({rays / t * 1e-6:6.2f} Mrays/s; reflected {c['reflected_rays']}, refracted {c['refracted_rays']}, "
              f"shadow {c['shadow_rays']}), pruned {c['pruned_branches']}, cut at max depth {c['depth_limited_branches']}")
