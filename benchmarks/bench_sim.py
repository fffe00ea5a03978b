"""Time and size of the NEO-Sim suite generation.

python benchmarks/bench_sim.py --profile standard --out outputs/neosim_standard
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import sys
import time
from pathlib import Path

from neoedit.cli.sim import SimBenchmarkCommand


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--profile", default="standard", choices=["small", "standard"])
    parser.add_argument("--out", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    t0 = time.perf_counter()
    SimBenchmarkCommand(out=args.out, profile=args.profile, seed=args.seed, overwrite=True).run()
    total_s = time.perf_counter() - t0
    suite = json.loads((args.out / "suite.json").read_text())
    n_images = 0
    for scene in suite["scenes"]:
        for scan in scene["scans"]:
            n_images += len(
                json.loads((args.out / scene["name"] / scan / "transforms.json").read_text())[
                    "frames"
                ]
            )
    size_mb = sum(f.stat().st_size for f in args.out.rglob("*") if f.is_file()) / 1e6
    print(f"\ncommand: python {shlex.join(sys.argv)}")
    print(f"machine: {platform.processor() or platform.machine()}, {platform.system()}")
    print(
        f"scenes: {len(suite['scenes'])}, scans: {sum(len(s['scans']) for s in suite['scenes'])}, "
        f"frames: {n_images}, total {total_s:.1f} s, {size_mb:.1f} MB"
    )


if __name__ == "__main__":
    main()
