"""Section 7 of `make bench`: what a field team waits for. The start-up of `replicate --help` (best of 5 fresh
processes), the per-step latency of `replicate act --stream --real` once it has started (a general policy exported
for 25 m buoys at 1 m/s, 9 buoys, 2,000 steps through a pipe, one step answered before the next is sent), the wall
time and peak memory of `replicate plan` on Lake Karaguz (9 buoys of 25 m at 1 m/s, the whole default mission),
and those of `replicate evaluate --policy` on each real lake of `data/lakes/` (100 episodes of the policy, naive
swarming and Lloyd, the best layout, and the episode written for a GIS) and on a generated 4,000-vertex lake with
arms and islands; each against its target in `params.yaml` `bench`."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from replicate.core.studies import BenchTargets

ROOT = Path(__file__).resolve().parents[1]
REPLICATE = [str(Path(sys.executable).parent / "replicate")]  # the installed command, as a user runs it


def help_startup(repeats: int = 5) -> float:
    """Seconds of the fastest of ``repeats`` fresh `replicate --help`."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run([*REPLICATE, "--help"], check=True, capture_output=True, cwd=ROOT)
        best = min(best, time.perf_counter() - start)
    return best


def stream_latency(policy: Path, steps: int = 2000, buoys: int = 9) -> tuple[float, float]:
    """(seconds to the first answer, seconds per step after it) of `act --stream --real` on ``policy``."""
    rng = np.random.default_rng(0)
    obs = rng.uniform(0, 50, size=(steps + 1, buoys, 22))
    obs[..., 10:14] = 1.0  # the heard-masks
    lines = [json.dumps(o.round(3).tolist()) + "\n" for o in obs]
    start = time.perf_counter()
    proc = subprocess.Popen([*REPLICATE, "act", "--policy", str(policy), "--stream", "--real"], cwd=ROOT, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    proc.stdin.write(lines[0])
    proc.stdin.flush()
    proc.stdout.readline()
    first = time.perf_counter() - start
    start = time.perf_counter()
    for line in lines[1:]:
        proc.stdin.write(line)
        proc.stdin.flush()
        reply = proc.stdout.readline()
    per_step = (time.perf_counter() - start) / steps
    proc.stdin.close()
    proc.wait()
    assert "error" not in reply, reply
    return first, per_step


LAKES = ("mae_kuang_reservoir", "lake_silach", "lake_karaguz")  # data/lakes/: 1,712, 1,236 and 467 vertices


# A small launcher reports its children's peak: a child forked straight from this process would start its count at
# this process's own resident size (Linux carries the high-water mark across fork and exec).
LAUNCHER = ("import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL); "
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")


def timed(argv: list[str]) -> tuple[float, float]:
    """(wall seconds, peak resident MB of its largest process) of one `replicate` command."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", LAUNCHER, *REPLICATE, *argv], cwd=ROOT, capture_output=True,
                          text=True)
    seconds = time.perf_counter() - start
    if done.returncode:
        raise RuntimeError(f"replicate {' '.join(argv)}: exit {done.returncode}: {done.stderr}")
    return seconds, int(done.stdout.split()[-1]) / 1024


def generated_lake(path: Path, vertices: int = 4_000) -> int:
    """A generated lake with three arms and two islands (``world.lakes``), 3 km across, its shores densified to
    about ``vertices`` points with a ripple of a tenth of their spacing, placed in UTM zone 32N and written to
    ``path`` as GeoJSON in lon/lat → its vertex count."""
    import geopandas as gpd
    import shapely
    from shapely import affinity

    from replicate.world.lakes import LakeSpec, generate

    lake = generate(LakeSpec(seed=4000, n_agents=9, ratio=0.8, arms=3, islands=2), 1.0)
    lake = affinity.scale(lake, 3000 / max(lake.bounds[2:]), 3000 / max(lake.bounds[2:]), origin=(0, 0))
    spacing = lake.boundary.length / vertices
    dense = shapely.segmentize(lake, spacing)
    def ripple(xy):  # a function of the position, so each ring's closing point moves with its first
        phase = xy @ np.array([[7.3, -5.1], [3.7, 6.9]]) / spacing
        return xy + 0.1 * spacing * np.sin(phase)

    rippled = shapely.transform(dense, ripple)
    placed = affinity.translate(shapely.make_valid(rippled), 500_000, 5_500_000)
    gpd.GeoDataFrame({"name": ["generated"]}, geometry=[placed], crs="EPSG:32632").to_crs("EPSG:4326").to_file(path)
    return int(shapely.get_num_coordinates(placed))


def plan_seconds(out: Path) -> tuple[float, float]:
    return timed(["plan", "--region", "data/lakes/lake_karaguz.geojson", "--buoys", "9", "--radius-m", "25",
                  "--speed-ms", "1.0", "--out", str(out)])


def evaluate_seconds(lake: str, out: Path) -> tuple[float, float]:
    return timed(["evaluate", "--policy", "src/replicate/defaults/general.pt", "--region", lake, "--out", str(out)])


def field_section(targets: BenchTargets) -> None:
    """Section 7, each figure against its target in ``targets`` (``params.bench``)."""
    print("== 7. what a field team waits for ==")
    print(f"`replicate --help` start-up: {help_startup():.2f} s (best of 5 fresh processes)")
    with tempfile.TemporaryDirectory() as tmp:
        policy = Path(tmp) / "buoy.pt"
        subprocess.run([*REPLICATE, "export", "--policy", "src/replicate/defaults/general.pt", "--radius-m", "25",
                        "--speed-ms", "1.0", "--out", str(policy)], check=True, capture_output=True, cwd=ROOT)
        first, per_step = stream_latency(policy)
        print(f"`replicate act --stream --real` (general policy, 9 buoys): first answer after {first:.2f} s, then "
              f"{per_step * 1e3:.3f} ms per step (target <= {targets.act_step_ms:g} ms: "
              f"{per_step * 1e3 / targets.act_step_ms:.2f}x of it)")
        _, fleet_step = stream_latency(policy, steps=500, buoys=targets.act_fleet)
        per_buoy = fleet_step * 1e3 / targets.act_fleet
        print(f"... {targets.act_fleet} buoys in one stream: {fleet_step * 1e3:.3f} ms per step, {per_buoy:.3f} ms per "
              f"buoy and step (target <= {targets.act_buoy_ms:g} ms: {per_buoy / targets.act_buoy_ms:.2f}x of it)")
        seconds, peak = plan_seconds(Path(tmp) / "plan")
        print(f"`replicate plan` on Lake Karaguz (9 buoys, 25 m, 1 m/s, the whole mission): {seconds:.1f} s, "
              f"peak {peak:.0f} MB (target <= {targets.peak_mb:.0f} MB)")
        for lake in LAKES:
            seconds, peak = evaluate_seconds(f"data/lakes/{lake}.geojson", Path(tmp) / f"{lake}.json")
            print(f"`replicate evaluate --policy` on {lake}: {seconds:.1f} s (target <= {targets.lake_evaluate_s:.0f} "
                  f"s: {seconds / targets.lake_evaluate_s:.2f}x of it), peak {peak:.0f} MB (target <= "
                  f"{targets.peak_mb:.0f} MB)")
        count = generated_lake(Path(tmp) / "generated.geojson")
        seconds, peak = evaluate_seconds(str(Path(tmp) / "generated.geojson"), Path(tmp) / "generated.json")
        print(f"`replicate evaluate --policy` on a generated lake of {count:,} vertices with 3 arms and 2 islands: "
              f"{seconds:.1f} s (target <= {targets.large_lake_evaluate_s:.0f} s: "
              f"{seconds / targets.large_lake_evaluate_s:.2f}x of it), peak {peak:.0f} MB (target <= "
              f"{targets.peak_mb:.0f} MB)")
