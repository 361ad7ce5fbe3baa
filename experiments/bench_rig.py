"""Benchmark of the rig: `rig calibrate` on 4 sessions and an estimate through the rig, cold and warm.

The calibration sessions are the bundled Pezzi ones (0.9, 1.2, 1.5, 1.65 kPa) with a 0.3 mm/N linear
finger pad planted in their depths (so the selection has something to switch on); the estimate is
the held-out 1.1 kPa session, padded alike. "cold" is the first call in this process (compilation,
or the persistent cache's programs), "warm" the later ones.

Run:  python experiments/bench_rig.py --repeats 3 --out docs/bench/rig-cpu-2core.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import statistics
import time
import warnings
from pathlib import Path

PAD = 0.3e-3  # [m/N]
PRESSURES = (900, 1200, 1500, 1650)  # [Pa] of the bundled calibration sessions used


def padded(path):
    from shelljax.session import load_session

    session = load_session(path)
    return dataclasses.replace(session, depth=session.depth + PAD * session.force)


def timed(fn):
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "bench" / "rig-cpu-2core.json")
    )
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    from shelljax.config import bundled_data_dir
    from shelljax.rig import calibrate_rig, estimate_with_rig

    sessions = bundled_data_dir() / "sessions"
    calibration = [padded(sessions / f"calib_pezzi_{p:04d}Pa.toml") for p in PRESSURES]
    held_out = padded(sessions / "heldout_pezzi_1100Pa.toml")
    rows = {
        "calibrate (4 sessions, 7 candidate terms)": [],
        "estimate through the rig: fit": [],
        "estimate through the rig: bayes": [],
    }
    rig = None
    for _ in range(args.repeats + 1):
        seconds, rig = timed(lambda: calibrate_rig(calibration, progress=False))
        rows["calibrate (4 sessions, 7 candidate terms)"].append(seconds)
        rows["estimate through the rig: fit"].append(timed(lambda: estimate_with_rig(held_out, rig))[0])
        rows["estimate through the rig: bayes"].append(
            timed(lambda: estimate_with_rig(held_out, rig, method="bayes"))[0]
        )
    table = {
        name: {"cold_s": times[0], "warm_median_s": statistics.median(times[1:]), "warm_runs_s": times[1:]}
        for name, times in rows.items()
    }
    print(f"{'measure':>45s} {'cold [s]':>9s} {'warm median [s]':>16s}  warm runs [s]")
    for name, t in table.items():
        print(
            f"{name:>45s} {t['cold_s']:9.1f} {t['warm_median_s']:16.2f}  {', '.join(f'{v:.2f}' for v in t['warm_runs_s'])}"
        )
    print(f"rig models: {[('+'.join(m.terms) or 'ideal', round(m.weight, 2)) for m in rig.models]}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "machine": platform.platform(),
                "processor": platform.processor(),
                "repeats": args.repeats,
                "unit": "s",
                "results": table,
                "models": [{"terms": list(m.terms), "weight": m.weight} for m in rig.models],
            },
            indent=1,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
