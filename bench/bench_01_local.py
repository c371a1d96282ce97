"""Chapter 1 at 512x512: time and ray throughput for 1 and 2 threads."""
from common import best_of

print("== chapter 1 (01_local), 512x512, best of 3 ==")
for scene, extra in (("scenes/cornell-point.scene", []), ("scenes/cornell.scene", ["--light-samples", "16"])):
    for threads in (1, 2):
        s = best_of(3, "01_local", scene, "--size", "512x512", "--threads", threads, *extra)
        c, t = s["counters"], s["render_s"]
        print(f"{scene:28s} threads {threads}: render {t * 1000:7.1f} ms, "
              f"camera {c['camera_rays'] / t * 1e-6:6.2f} Mrays/s, shadow {c['shadow_rays'] / t * 1e-6:6.2f} Mrays/s "
              f"{' '.join(map(str, extra))}")
