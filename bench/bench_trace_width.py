"""Single rays or packets inside the compiled bounce loop (renderer/integrators/_trace_kernel.py).

    .venv/bin/python bench/bench_trace_width.py [STAGES ...] [--res 128 128] [--spp 16] [--repeats 5]
        [--widths 1,4,8,16] [--threads 1]

For each fast-path stage: render() with FastPath.TRACE_WIDTH set to each width in turn (1:
rtcIntersect1 / rtcOccluded1 per ray; 4, 8, 16: rtcIntersect<W> / rtcOccluded<W> packets of the
live rays in their order), the widths alternated run by run; prints per width the median CPU
seconds of the whole render() call (this process's, load and build included: on a shared machine
CPU time is steadier than wall time) and the median render seconds (wall, load and build
excluded), and each width's speed relative to single rays by CPU time. The images are the
same for every width (Embree answers each ray alike), so only the time differs.
"""
from __future__ import annotations

import argparse
import statistics
import time

from renderer.integrators import fast_path as fp
from renderer.render import RenderOptions, render

DEFAULT_STAGES = ["stages/cornell_box.usda", "stages/talk/sphere_occluder.usda", "stages/instanced.usda",
                  "stages/dof.usda"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stages", nargs="*")
    ap.add_argument("--res", type=int, nargs=2, default=(128, 128))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--widths", default="1,4,8,16")
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    widths = [int(w) for w in a.widths.split(",")]
    print("| stage | " + " | ".join(f"W={w} CPU s (wall s)" for w in widths) + " | "
          + " | ".join(f"W={w} / W={widths[0]}" for w in widths[1:]) + " |")
    print("|---" * (1 + 2 * len(widths) - 1) + "|")
    for st in a.stages or DEFAULT_STAGES:
        secs = {w: [] for w in widths}
        cpu = {w: [] for w in widths}
        for w in widths:  # warm: compile and load, one tiny render per width
            fp.TRACE_WIDTH = w
            render(st, RenderOptions(spp=1, resolution=(16, 16), threads=a.threads))
        for rep in range(a.repeats):
            for w in (widths if rep % 2 == 0 else widths[::-1]):
                fp.TRACE_WIDTH = w
                c0 = time.process_time()
                r = render(st, RenderOptions(spp=a.spp, resolution=tuple(a.res), threads=a.threads, seed=rep))
                cpu[w].append(time.process_time() - c0)
                assert r.stats["fast_path"] == "on", r.stats["fast_path"]
                secs[w].append(r.stats["seconds"]["render"])
        med = {w: statistics.median(secs[w]) for w in widths}
        mc = {w: statistics.median(cpu[w]) for w in widths}
        print(f"| {st} | " + " | ".join(f"{mc[w]:.3f} ({med[w]:.3f})" for w in widths) + " | "
              + " | ".join(f"{mc[widths[0]] / mc[w]:.2f}x" for w in widths[1:]) + " |", flush=True)


if __name__ == "__main__":
    main()
