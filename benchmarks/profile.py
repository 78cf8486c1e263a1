"""``catanc profile`` against the demo workers: each example spec run for 20 s, profiled, compared.

::

    flock /tmp/catanc-heavy.lock python -m benchmarks.profile [--duration 20] [--cores 2] [SPEC ...]

Per spec: ``catanc compile`` into a temporary folder, ``catanc run --demo`` for the duration
(root: SCHED_FIFO), ``catanc profile`` of its log.  Prints, per node, the spec's planning
figure, the proposed one and how far off (the workers burn exactly the spec's profile), then
whether ``--write`` followed by ``--check --tolerance 0`` round-trips, and the load average.
Beside the proposal, the p95 of the clients' own figures, and for heads what the kernel said of
every 8th run (``catanc.runtime.enforcer.runs``): by how much its count exceeded the client's figure (the
median: the client's own work around its callback) and on how many checked runs it stood in for
the client's figure (:func:`catanc.control.measure.reconcile`).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from catanc.control.measure import percentile
from catanc.model.load import load_spec
from catanc.runtime.logs.samples import MeasurementsError
from catanc.runtime.logs.writer import read_log
from catanc.runtime.profile.propose import profile_spec

ROOT = Path(__file__).parents[1]


def profile_one(spec_path: Path, duration_s: float, cores: int, folder: Path) -> list[str]:
    catanc = [sys.executable, "-m", "catanc"]
    subprocess.run([*catanc, "compile", str(spec_path), "-k", str(cores), "--out", str(folder / "out"), "--quiet"],
                   check=True, capture_output=True)  # fmt: skip
    table = next((folder / "out").rglob("runtime.json"))
    log = folder / "run.jsonl"
    subprocess.run([*catanc, "run", str(table), "--demo", "--quiet", "--duration", str(duration_s), "--log", str(log),
                    "--socket", str(folder / "catanc.sock")], check=True, capture_output=True)  # fmt: skip
    copy = folder / spec_path.name
    shutil.copy(spec_path, copy)
    lines = [f"{spec_path.name} ({cores} cores, {duration_s:g} s):"]
    try:
        result = profile_spec(copy.read_text(), str(copy), log.read_text(), str(log), tolerance=0.15)
    except MeasurementsError as exc:
        return [*lines, f"  {exc}"]
    spec = load_spec(spec_path)
    own = own_figures(log)
    for name, proposal in sorted(result.proposals.items()):
        planned = spec.nodes[name].mean_compute_ms
        off = (proposal.planning_ms - planned) / planned
        modes = ", ".join(f"{m.share:g} x {m.ms:g}" for m in proposal.modes)
        kernel = proposal.kernel
        checked = f"  kernel {kernel.extra_ms:+.3f} ms/run, {kernel.replaced}/{kernel.runs} replaced" if kernel else ""
        lines.append(
            f"  {name:8} {proposal.count:6d} samples  spec {planned:8.4g} ms  proposed {proposal.planning_ms:8.4g} ms"
            f"  {off:+6.1%}  (p95 of the clients' own figures {percentile(own[name], 95):.4g} ms){checked}"
            + (f"  modes {modes}" if modes else "")
        )
    copy.write_text(result.text)
    check = subprocess.run([*catanc, "profile", str(log), "--spec", str(copy), "--check", "--tolerance", "0"],
                           capture_output=True, check=False)  # fmt: skip
    lines.append(f"  --write then --check --tolerance 0: exit {check.returncode}")
    return lines


def own_figures(log: Path) -> dict[str, list[float]]:
    """Per node, the clients' own one-thread figures (the runtime replaces every 8th of a head's by the kernel's)."""
    found: dict[str, list[float]] = {}
    for event in read_log(log):
        if event.get("event") == "compute" and event.get("threads") == 1 and event.get("reported_ms") is not None:
            found.setdefault(event["node"], []).append(float(event["reported_ms"]))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("specs", nargs="*", type=Path)
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep each run's log in DIR (<spec>.jsonl)")
    args = parser.parse_args()
    specs = args.specs or sorted((ROOT / "specs").glob("*.yaml"))
    print(f"load average before: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    for spec in specs:
        with tempfile.TemporaryDirectory(prefix="catanc-profile-") as folder:
            print("\n".join(profile_one(spec, args.duration, args.cores, Path(folder))), flush=True)
            if args.keep is not None:
                args.keep.mkdir(parents=True, exist_ok=True)
                shutil.copy(Path(folder) / "run.jsonl", args.keep / f"{spec.stem}.jsonl")
    print(f"load average after: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")


if __name__ == "__main__":
    main()
