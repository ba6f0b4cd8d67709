#!/usr/bin/env python
"""Where the first run after an install spends its time: numba's compile time per kernel, stage by stage.

Each stage of :data:`pcdof.runtime.kernels.STAGES` runs its ``warmup()`` (as ``pcdof warmup`` does:
:func:`~pcdof.runtime.kernels.warm_stage`) in a fresh interpreter whose numba cache is an empty temporary
folder (``NUMBA_CACHE_DIR``), so every kernel compiles; numba's event API (``numba:compile`` per dispatcher
and signature, ``numba:run_pass`` per compiler pass) times each compile in the child's CPU time. A kernel's
*self* seconds leave out the kernels it calls that compile on their own (their own rows), so the column
sums to the stage's compile time; helpers declared ``inline="always"`` and numba's own overloads that are
not dispatchers count in their callers.

    python scripts/profile_compile.py                       # every stage, top 25 kernels
    python scripts/profile_compile.py --stages fill --signatures
    python scripts/profile_compile.py --passes 15           # and the costliest compiler passes
    python scripts/profile_compile.py --repeats 3 --json out/compile.json

Columns: ``kernel``, ``module``, ``sigs`` (signatures compiled), ``self s`` (CPU seconds, median over
*repeats*), ``incl s`` (with the kernels it called compiled on their own). Per stage: the warm-up's CPU
seconds in all (imports and running the tiny inputs included) and the part spent compiling. CPU time is
the work done, far less disturbed by other processes than wall time; still, repeat on a busy machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the program each child runs: one stage's warm-up with the listeners installed; prints one JSON object
CHILD = r'''
import json, sys, time
t_start = time.process_time()
from numba.core import event as ev

stage = sys.argv[1]
rows = {}        # (module, qualname) -> {"sigs": [...], "self": s, "incl": s}
passes = {}      # pass name -> self seconds
pass_kernels = {}  # (pass name, module, qualname) -> self seconds


class Nested(ev.Listener):
    """Times nested events: each one's CPU seconds in all and without the events nested in it."""

    def __init__(self):
        self.stack = []

    def on_start(self, event):
        self.stack.append([time.process_time(), 0.0])

    def on_end(self, event):
        t0, child = self.stack.pop()
        total = time.process_time() - t0
        if self.stack:
            self.stack[-1][1] += total
        self.record(event, total - child, total)


class Compiles(Nested):
    def record(self, event, own, total):
        fn = event.data["dispatcher"].py_func
        row = rows.setdefault((fn.__module__ or "?", fn.__qualname__), {"sigs": [], "self": 0.0, "incl": 0.0})
        row["sigs"].append(", ".join(str(a) for a in event.data["args"]))
        row["self"] += own
        row["incl"] += total


class Passes(Nested):
    def record(self, event, own, total):
        name = event.data["name"].split(" [", 1)[0]
        passes[name] = passes.get(name, 0.0) + own
        k = (name, event.data["module"] or "?", event.data["qualname"])
        pass_kernels[k] = pass_kernels.get(k, 0.0) + own


ev.register("numba:compile", Compiles())
ev.register("numba:run_pass", Passes())
from pcdof.runtime.kernels import warm_stage
t0 = time.process_time()
warm_stage(stage, whole_process=True)
t1 = time.process_time()
print(json.dumps({"stage": stage, "warmup_cpu": t1 - t0, "process_cpu": t1 - t_start,
                  "kernels": [[m, q, r["sigs"], r["self"], r["incl"]] for (m, q), r in rows.items()],
                  "passes": passes,
                  "pass_kernels": [[p, m, q, s] for (p, m, q), s in pass_kernels.items()]}))
'''


def run_stage(stage: str, src: Path) -> dict:
    """One stage's warm-up in a fresh interpreter with an empty numba cache; the child's report."""
    with tempfile.TemporaryDirectory(prefix="pcdof-numba-cache-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=os.pathsep.join(
            [str(src)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
        out = subprocess.run([sys.executable, "-c", CHILD, stage], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"stage {stage} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _median(values):
    return statistics.median(values) if values else 0.0


def main(argv=None) -> int:
    from pcdof.runtime.kernels import COMPILE_CPU_S, STAGES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--stages", default=",".join(STAGES), help="comma-separated stages (default: all)")
    ap.add_argument("--repeats", type=int, default=1, help="runs per stage; medians are reported (default 1)")
    ap.add_argument("--top", type=int, default=25, help="kernels listed per stage (default 25; 0: all)")
    ap.add_argument("--signatures", action="store_true", help="list each kernel's compiled signatures")
    ap.add_argument("--passes", type=int, default=0, metavar="N",
                    help="also list the N costliest compiler passes per stage, and their costliest kernels")
    ap.add_argument("--src", default=str(ROOT / "src"), help="the pcdof sources to profile (default: this tree's)")
    ap.add_argument("--json", metavar="PATH", help="write every run's raw report to PATH")
    args = ap.parse_args(argv)
    stages = [s.strip() for s in args.stages.split(",") if s.strip()]
    bad = [s for s in stages if s not in STAGES]
    if bad:
        ap.error(f"unknown stages {bad}; known: {list(STAGES)}")

    raw = {}
    for stage in stages:
        runs = [run_stage(stage, Path(args.src)) for _ in range(max(1, args.repeats))]
        raw[stage] = runs
        kernels: dict = {}
        for r in runs:
            for module, qualname, sigs, own, incl in r["kernels"]:
                k = kernels.setdefault((module, qualname), {"sigs": sigs, "self": [], "incl": []})
                k["self"].append(own)
                k["incl"].append(incl)
        table = sorted(((_median(v["self"]), _median(v["incl"]), m, q, v["sigs"]) for (m, q), v in kernels.items()),
                       reverse=True)
        warm = _median([r["warmup_cpu"] for r in runs])
        proc = _median([r["process_cpu"] for r in runs])
        compiling = _median([sum(k[3] for k in r["kernels"]) for r in runs])
        print(f"\n== {stage}: warm-up {warm:.1f} s CPU ({proc:.1f} s with the interpreter's start and imports), "
              f"{compiling:.1f} s of it compiling {len(table)} kernels, "
              f"{sum(len(t[4]) for t in table)} signatures (estimate in kernels.COMPILE_CPU_S: "
              f"{COMPILE_CPU_S.get(stage, float('nan')):.1f} s; {len(runs)} run(s))")
        print(f"{'kernel':<40} {'module':<36} {'sigs':>4} {'self s':>7} {'incl s':>7}")
        for own, incl, module, qualname, sigs in table[:args.top or None]:
            print(f"{qualname[:40]:<40} {module[:36]:<36} {len(sigs):>4} {own:>7.2f} {incl:>7.2f}")
            if args.signatures:
                for sig in sigs:
                    print(f"    ({sig})")
        rest = table[args.top:] if args.top else []
        if rest:
            print(f"{'(' + str(len(rest)) + ' more)':<40} {'':<36} {sum(len(t[4]) for t in rest):>4} "
                  f"{sum(t[0] for t in rest):>7.2f}")
        if args.passes:
            names = {p for r in runs for p in r["passes"]}
            ptable = sorted(((_median([r["passes"].get(p, 0.0) for r in runs]), p) for p in names), reverse=True)
            print(f"\n  {'compiler pass':<40} {'self s':>7}   costliest kernels in it")
            for secs, name in ptable[:args.passes]:
                per = {}
                for r in runs:
                    for p, m, q, s in r["pass_kernels"]:
                        if p == name:
                            per[q] = per.get(q, 0.0) + s / len(runs)
                top = sorted(per.items(), key=lambda kv: -kv[1])[:3]
                print(f"  {name:<40} {secs:>7.2f}   " + ", ".join(f"{q} {s:.2f}" for q, s in top))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(raw, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
