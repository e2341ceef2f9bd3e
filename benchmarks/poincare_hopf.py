"""Poincaré–Hopf at the default sizes: does ``ufl-frames solve FILE`` (no size given)
find singularities whose indices add up to what the boundary's corners and the Euler
characteristic ask for, on every shape?

    python benchmarks/poincare_hopf.py [--files F ...] [--timeout 300] [--max-it 300]
                                       [--json FILE]

Files: every ``benchmarks/shapes/*.geo`` and ``meshes/gallery/*.geo`` (``--files`` picks
others). Each is solved in its own process group (killed after ``--timeout`` seconds)::

    python -m ufl_frames.app solve FILE --out TMP --force -q --max-it N

and a row printed from its ``summary.json``: triangles, the singularities' index sum,
the expected sum (corners rounded to quarter turns, at least one: a corner under 45° is a
squeezed quad corner; ``+k/4`` when k corners are within 2° of 135°, 225° or 315°, where
either rounding is right), whether they agree, the
index the interior curves' junctions force (``junction``: part of the sum), the loader's
note on the local feature size (``capped``: boundary points whose size it lowered) and
the whole run's wall and CPU seconds (CPU: the solve's process and what it waited
for). A failed run shows ``error``/``crash``/``timeout`` and its last line. The solves
use the ``ufl_frames`` the interpreter imports (``PYTHONPATH=OTHER/src`` measures
another checkout).
"""

import argparse
import json
import re
import resource
import sys
import tempfile
from pathlib import Path

from _common import ROOT
from _processes import last_line, run_in_group

DEFAULT_FILES = sorted((ROOT / "benchmarks" / "shapes").glob("*.geo")) + sorted(
    (ROOT / "meshes" / "gallery").glob("*.geo"))


def _row(path: Path, timeout: float, max_it: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        cmd = [sys.executable, "-m", "ufl_frames.app", "solve", str(path), "--out", str(out),
               "--force", "-q", "--max-it", str(max_it)]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        rc, _, err, seconds = run_in_group(cmd, timeout)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
        row = {"file": path.name, "seconds": seconds, "cpu_seconds": cpu}
        summary = out / "summary.json"
        if rc is None:
            return {**row, "status": "timeout"}
        if not summary.exists():
            status = "error" if "ufl-frames: error" in err else "crash"
            return {**row, "status": status, "last": last_line(err)[:100]}
        s = json.loads(summary.read_text())
        ph = s.get("poincare_hopf") or {}
        capped = next((int(m.group(1)) for note in s.get("loader_notes", [])
                       if (m := re.search(r"capped near (\d+) boundary", note))), 0)
        return {**row, "status": "ok", "triangles": s["num_cells"],
                "index_sum": ph.get("index_sum"), "expected": ph.get("expected"),
                "ambiguous": ph.get("ambiguous_corners", 0), "agrees": ph.get("agrees"),
                "junction": ph.get("junction_index", 0.0), "capped": capped,
                "singularities": len(s.get("singularities", []))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--files", nargs="+", type=Path, default=DEFAULT_FILES)
    parser.add_argument("--timeout", type=float, default=300.0)
    parser.add_argument("--max-it", type=int, default=300)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    header = (f"{'file':34s} {'triangles':>9s} {'capped':>6s} {'sum':>6s} {'expected':>10s} "
              f"{'junction':>8s} {'ok':>3s} {'s':>7s} {'cpu s':>7s}")
    print(header, flush=True)
    rows = []
    for path in args.files:
        row = _row(path, args.timeout, args.max_it)
        rows.append(row)
        if row["status"] != "ok":
            print(f"{row['file']:34s} {row['status']}: {row.get('last', '')} "
                  f"({row['seconds']:.0f} s, {row['cpu_seconds']:.0f} CPU s)", flush=True)
            continue
        expected = f"{row['expected']:g}" + (f"+{row['ambiguous']}/4" if row["ambiguous"] else "")
        print(f"{row['file']:34s} {row['triangles']:9d} {row['capped']:6d} "
              f"{row['index_sum']:6g} {expected:>10s} {row['junction']:8g} "
              f"{'yes' if row['agrees'] else 'NO':>3s} {row['seconds']:7.1f} "
              f"{row['cpu_seconds']:7.1f}", flush=True)
    solved = [r for r in rows if r["status"] == "ok"]
    agree = [r for r in solved if r["agrees"]]
    unsolved = ", ".join(f"{r['file']} ({r['status']})" for r in rows if r["status"] != "ok")
    disagree = ", ".join(r["file"] for r in solved if not r["agrees"])
    print(f"\n{len(rows)} files: {len(solved)} solved, {len(agree)} agree with Poincaré–Hopf; "
          f"not solved: {unsolved or 'none'}; disagree: {disagree or 'none'}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
