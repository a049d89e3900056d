"""Where the test suite's time goes: per test file and per test, wall and CPU seconds and JAX's compile share.

    python tests/ci_time.py                          # the whole suite as CI runs it (-n auto)
    python tests/ci_time.py tests/test_fit.py -n 0   # a subset: any pytest arguments
    python tests/ci_time.py --report times.json      # print a saved record again
    python tests/ci_time.py --long-tests tests/durations.json --slow   # and update the long tests' record

It runs ``python -m pytest`` with this file as a plugin (``-p ci_time``), which records for every
test (setup, call and teardown, where a module-scoped fixture's compilation lands in its first
test's setup):

* wall seconds, and CPU seconds of the process running it (every thread: XLA's compiler and its
  thread pool) and of the processes it started and waited for (CLI subprocesses, notebook kernels);
* JAX's own compile events (``jax.monitoring``): tracing to a jaxpr, lowering to MLIR, XLA's
  compilation (``backend_compile``), and the persistent compilation cache's hits and reads.

Collection (importing the test modules) is recorded per file and per worker. The report prints
the files by CPU seconds, the slowest tests, and the CPU-minutes of the whole run: on a quiet
machine with ``C`` cores and at least ``C`` workers the suite's wall time is about
``CPU seconds / C`` (compilation and the tests are CPU-bound), which is how a figure measured
under load becomes an estimate for a quiet machine. The load average at the start and the end
is printed beside every figure. The record is JSON (``--json``, default
``.pytest_cache/ci_time.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_JSON = ROOT / ".pytest_cache" / "ci_time.json"

# JAX's duration events (seconds) and counted events, by the short names the record uses.
DURATIONS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "xla",
    "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read",
}
COUNTS = {
    "/jax/core/compile/backend_compile_duration": "compiles",
    "/jax/compilation_cache/cache_hits": "cache_hits",
}
# JAX's backend_compile event spans a read from the persistent cache as well: a program read back
# is taken out of XLA's count and seconds (_xla) and counted apart.
FIELDS = ("wall", "cpu", "child_cpu", *DURATIONS.values(), *COUNTS.values())


# ---------------------------------------------------------------------------- the plugin (every process)
_totals: dict[str, float] = defaultdict(float)
_active = False
_record: dict = {"tests": {}, "workers": {}}
_collect: dict[str, dict] = {}
_start: dict[str, float] = {}
_PHASES = pytest.StashKey[dict]()


def _on_duration(event: str, duration: float, **kwargs) -> None:
    name = DURATIONS.get(event)
    if name is not None:
        _totals[name] += duration
    if event in COUNTS:
        _totals[COUNTS[event]] += 1


def _on_event(event: str, **kwargs) -> None:
    if event in COUNTS:
        _totals[COUNTS[event]] += 1


def _snapshot() -> dict[str, float]:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    now = {"wall": time.perf_counter(), "cpu": time.process_time(), "child_cpu": children.ru_utime + children.ru_stime}
    return {name: now.get(name, _totals[name]) for name in FIELDS}


def _since(start: dict[str, float]) -> dict[str, float]:
    end = _snapshot()
    return {name: round(end[name] - start[name], 4) for name in FIELDS}


def _worker(config) -> str:
    return getattr(config, "workerinput", {}).get("workerid", "main")


def pytest_addoption(parser):
    parser.addoption("--ci-time", metavar="PATH", help="record each test's wall, CPU and compile seconds as JSON")


def pytest_configure(config):
    global _active
    if not config.getoption("ci_time"):
        return
    from jax import monitoring

    monitoring.register_event_duration_secs_listener(_on_duration)
    monitoring.register_event_listener(_on_event)
    _active = True
    _start.update(_snapshot())
    _record["started"] = time.time()
    _record["load_start"] = os.getloadavg()


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector):
    if not (_active and isinstance(collector, pytest.Module)):
        return (yield)
    start = _snapshot()
    try:
        return (yield)
    finally:
        _collect[collector.nodeid] = _since(start)


def _timed_phase(item, when: str):
    if not _active:
        return (yield)
    start = _snapshot()
    try:
        return (yield)
    finally:
        item.stash.setdefault(_PHASES, {})[when] = _since(start)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item):
    return (yield from _timed_phase(item, "setup"))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    return (yield from _timed_phase(item, "call"))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item, nextitem):
    return (yield from _timed_phase(item, "teardown"))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    phase = item.stash.get(_PHASES, {}).get(call.when)
    if phase is not None:  # travels with the report from an xdist worker to the controller
        report.user_properties.append(("ci_time", {**phase, "worker": _worker(item.config)}))
    return report


def pytest_runtest_logreport(report):
    if not _active:
        return
    for key, value in report.user_properties:
        if key == "ci_time":
            test = _record["tests"].setdefault(report.nodeid, {"outcome": "passed"})
            test[report.when] = value
            if report.outcome != "passed" and not (report.when != "call" and report.outcome == "skipped"):
                test["outcome"] = report.outcome
            elif report.outcome == "skipped":
                test["outcome"] = "skipped"


def _process_summary() -> dict:
    return {"total": _since(_start), "collect": dict(_collect)}


def pytest_sessionfinish(session):
    if not _active:
        return
    config = session.config
    if hasattr(config, "workeroutput"):  # an xdist worker: the controller writes the record
        config.workeroutput["ci_time"] = json.dumps(_process_summary())
        return
    if not _record["workers"]:  # one process (-n 0): it ran the tests itself
        _record["workers"]["main"] = _process_summary()
    _record["wall"] = round(time.time() - _record["started"], 2)
    _record["load_end"] = os.getloadavg()
    _record["cpu_count"] = os.cpu_count()
    _record["exitstatus"] = int(session.exitstatus)
    path = Path(config.getoption("ci_time"))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_record, indent=1), encoding="utf-8")


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    if _active and "ci_time" in getattr(node, "workeroutput", {}):
        _record["workers"][node.gateway.id] = json.loads(node.workeroutput["ci_time"])


# ---------------------------------------------------------------------------- the report
def _sum(parts) -> dict[str, float]:
    out = dict.fromkeys(FIELDS, 0.0)
    for part in parts:
        for name in FIELDS:
            out[name] += part.get(name, 0.0)
    return out


def _xla(d: dict) -> tuple[float, float]:
    """(seconds, count) of XLA's own compilations, the programs read from the persistent cache left out."""
    return d["xla"] - d["cache_read"], d["compiles"] - d["cache_hits"]


def _compile(d: dict) -> float:
    return d["trace"] + d["lower"] + d["xla"]


def _share(d: dict) -> str:
    return f"{100 * _compile(d) / d['wall']:.0f}%" if d["wall"] > 0 else "-"


def report(record: dict, top: int = 40) -> str:
    """The record as text: totals, workers, files by CPU seconds, the ``top`` slowest tests by wall seconds."""
    tests = {nodeid: _sum(t.get(w, {}) for w in ("setup", "call", "teardown")) for nodeid, t in record["tests"].items()}
    files: dict[str, list] = defaultdict(list)
    for nodeid, t in tests.items():
        files[nodeid.split("::")[0]].append(t)
    collect: dict[str, list] = defaultdict(list)
    for worker in record["workers"].values():
        for nodeid, c in worker["collect"].items():
            collect[nodeid].append(c)
    totals = _sum(w["total"] for w in record["workers"].values())
    cpu = totals["cpu"] + totals["child_cpu"]
    load = "load average {:.1f} at the start, {:.1f} at the end".format(record["load_start"][0], record["load_end"][0])
    outcomes = defaultdict(int)
    for t in record["tests"].values():
        outcomes[t["outcome"]] += 1
    lines = [
        f"{len(tests)} tests ({', '.join(f'{n} {o}' for o, n in sorted(outcomes.items()))}), "
        f"{len(record['workers'])} process(es), {record['cpu_count']} cores, {load}",
        f"wall {record['wall'] / 60:.1f} min; CPU {cpu / 60:.1f} min "
        f"(test processes {totals['cpu'] / 60:.1f}, processes they started {totals['child_cpu'] / 60:.1f}); "
        f"on a quiet machine with 2 cores and 2 workers about {cpu / 2 / 60:.1f} min",
        f"JAX in the test processes: tracing {totals['trace'] / 60:.1f} min, lowering {totals['lower'] / 60:.1f} min, "
        f"XLA {_xla(totals)[0] / 60:.1f} min in {_xla(totals)[1]:.0f} compilations, "
        f"{totals['cache_hits']:.0f} programs read from the persistent cache ({totals['cache_read']:.1f} s)",
        "",
        "| process | tests | wall s | CPU s | child CPU s | compile s | collection s |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, worker in sorted(record["workers"].items()):
        t = worker["total"]
        coll = sum(c["wall"] for c in worker["collect"].values())
        n = sum(1 for r in record["tests"].values() if r.get("call", r.get("setup", {})).get("worker") == name)
        lines.append(
            f"| {name} | {n} | {t['wall']:.0f} | {t['cpu']:.0f} | {t['child_cpu']:.0f} | {_compile(t):.0f} | {coll:.0f} |"
        )
    lines += [
        "",
        "Test files by CPU seconds (tests' setup, call and teardown; collection apart; compile = tracing, "
        "lowering and XLA, as a share of the wall time):",
        "",
        "| file | tests | wall s | CPU s | child CPU s | compile | XLA compilations | cache reads | collection s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    by_file = {name: _sum(parts) for name, parts in files.items()}
    for name, d in sorted(by_file.items(), key=lambda kv: -(kv[1]["cpu"] + kv[1]["child_cpu"])):
        coll = max((c["wall"] for c in collect.get(name, [])), default=0.0)
        lines.append(
            f"| {name} | {len(files[name])} | {d['wall']:.1f} | {d['cpu']:.1f} | {d['child_cpu']:.1f} | "
            f"{_share(d)} | {_xla(d)[1]:.0f} | {d['cache_hits']:.0f} | {coll:.1f} |"
        )
    lines += [
        "",
        f"The {top} slowest tests by wall seconds:",
        "",
        "| test | wall s | CPU s | child CPU s | compile | XLA compilations | cache reads |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for nodeid, d in sorted(tests.items(), key=lambda kv: -kv[1]["wall"])[:top]:
        lines.append(
            f"| {nodeid} | {d['wall']:.1f} | {d['cpu']:.1f} | {d['child_cpu']:.1f} | {_share(d)} | {_xla(d)[1]:.0f} | "
            f"{d['cache_hits']:.0f} |"
        )
    return "\n".join(lines)


def update_durations(record: dict, path: Path, least: float = 20.0) -> int:
    """Merge the wall seconds (setup, call, teardown) of the tests that took ``least`` or more into ``path``.

    ``tests/conftest.py`` runs the tests of that record first, longest first, under xdist; a test
    measured again replaces its entry, one now faster than ``least`` leaves it. Returns how many it holds.
    """
    seconds = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    for nodeid, test in record["tests"].items():
        wall = sum(test.get(when, {}).get("wall", 0.0) for when in ("setup", "call", "teardown"))
        if wall >= least:
            seconds[nodeid] = round(wall, 1)
        else:
            seconds.pop(nodeid, None)
    ordered = dict(sorted(seconds.items(), key=lambda kv: -kv[1]))
    path.write_text(json.dumps(ordered, indent=1) + "\n", encoding="utf-8")
    return len(ordered)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Run pytest and print where the time goes (other arguments go to pytest).",
        usage="python tests/ci_time.py [--json PATH] [--top N] [--report PATH] [--long-tests PATH] [PYTEST ARGS ...]",
    )
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, help=f"the record (default {DEFAULT_JSON})")
    parser.add_argument("--top", type=int, default=40, help="how many of the slowest tests to list (default 40)")
    parser.add_argument("--report", type=Path, metavar="PATH", help="print a saved record; run nothing")
    parser.add_argument(
        "--long-tests", type=Path, metavar="PATH",
        help="merge the tests of 20 s or more into this record of long tests (tests/durations.json)",
    )  # fmt: skip
    args, pytest_args = parser.parse_known_args(argv)
    if args.report is not None:
        print(report(json.loads(args.report.read_text(encoding="utf-8")), args.top))
        return 0
    here = str(Path(__file__).resolve().parent)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")])))
    command = [sys.executable, "-m", "pytest", "-p", "ci_time", f"--ci-time={args.json}", *pytest_args]
    print("$", " ".join(command), f"(load average {os.getloadavg()[0]:.1f})", flush=True)
    code = subprocess.call(command, cwd=ROOT, env=env)
    if args.json.is_file():
        record = json.loads(args.json.read_text(encoding="utf-8"))
        print(report(record, args.top))
        if args.long_tests is not None:
            print(f"{args.long_tests}: {update_durations(record, args.long_tests)} long tests")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
