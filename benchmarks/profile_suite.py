"""Where the test suite's time goes: jax tracing, lowering and XLA compiling, per test,
file and compiled program.

    python benchmarks/profile_suite.py                          # the whole suite, as the README runs it
    python benchmarks/profile_suite.py tests/test_edges.py -n 0 # one file, in this process
    python benchmarks/profile_suite.py --top 30 -- -k gradient  # pytest options after --

Runs the README's test command (``python -m pytest``, the options of ``pyproject.toml``;
arguments after the script's own are passed on) with this file loaded as a pytest plugin
in every worker. A ``jax.monitoring`` listener adds up, per test (setup, call and
teardown), the seconds jax spends tracing (``jaxpr_trace_duration``), lowering to
StableHLO (``jaxpr_to_mlir_module_duration``) and XLA spends compiling
(``backend_compile_duration``, also per compiled program's name); the rest of the
test's wall time is running compiled programs and plain Python. Tests that work in a
subprocess (the docs' code blocks, the CLI, notebooks) show as wall time only.

Prints the totals, then tables: per test file, per compiled program name (what the
suite compiles most), and the tests with the most compile time and with the most of
the rest. With ``-n 2`` (the default) the wall times are those of two workers sharing
the machine, so that a test's wall time is longer than it is alone; compare sums,
not single tests, between runs.
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import os
import subprocess
import sys
import tempfile
import time

OUT_ENV = "RAYTRAX_PROFILE_SUITE_DIR"
EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}

# ---------------------------------------------------------------------------
# The plugin (loaded by pytest with -p profile_suite in every worker)
# ---------------------------------------------------------------------------

_current: dict = {}


def _listener(event: str, duration_secs: float, **kwargs: str | int) -> None:
    kind = EVENTS.get(event)
    if kind is None or not _current:
        return
    _current[kind] += duration_secs
    if kind == "compile":
        _current["compiles"] += 1
        prog = _current["programs"].setdefault(str(kwargs.get("fun_name", "?")), [0.0, 0, 0.0])
        prog[0] += duration_secs
        prog[1] += 1
        prog[2] = max(prog[2], duration_secs)


def pytest_configure(config):
    if os.environ.get(OUT_ENV):
        import jax.monitoring

        jax.monitoring.register_event_duration_secs_listener(_listener)


def _hookwrapper(fn):
    import pytest

    return pytest.hookimpl(hookwrapper=True)(fn)


if os.environ.get(OUT_ENV):

    @_hookwrapper
    def pytest_runtest_protocol(item, nextitem):
        _current.clear()
        _current.update(trace=0.0, lower=0.0, compile=0.0, compiles=0, programs={})
        t0 = time.perf_counter()
        yield
        row = dict(_current, test=item.nodeid, file=item.nodeid.split("::")[0], wall=time.perf_counter() - t0)
        _current.clear()
        with open(os.path.join(os.environ[OUT_ENV], f"{os.getpid()}.jsonl"), "a") as f:
            f.write(json.dumps(row) + "\n")


# ---------------------------------------------------------------------------
# The driver
# ---------------------------------------------------------------------------


def _table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def report(rows, top: int) -> str:
    """The tables of the per-test ``rows`` the plugin wrote."""
    out = []
    tot = {k: sum(r[k] for r in rows) for k in ("wall", "trace", "lower", "compile", "compiles")}
    rest = tot["wall"] - tot["trace"] - tot["lower"] - tot["compile"]
    out.append(
        f"{len(rows)} tests, {tot['wall']:.0f} s of test time: XLA compiling {tot['compile']:.0f} s "
        f"({tot['compile'] / tot['wall']:.0%}, {tot['compiles']} programs), tracing {tot['trace']:.0f} s, "
        f"lowering {tot['lower']:.0f} s, the rest (running, Python, subprocesses) {rest:.0f} s"
    )

    files = collections.defaultdict(lambda: collections.Counter())
    for r in rows:
        f = files[r["file"]]
        for k in ("wall", "trace", "lower", "compile", "compiles"):
            f[k] += r[k]
        f["tests"] += 1
    fr = sorted(files.items(), key=lambda kv: -kv[1]["wall"])
    out.append("\nper file (seconds):\n")
    out.append(
        _table(
            ("file", "wall", "compile", "trace + lower", "programs compiled", "tests"),
            [
                (
                    n,
                    f"{f['wall']:.1f}",
                    f"{f['compile']:.1f}",
                    f"{f['trace'] + f['lower']:.1f}",
                    f["compiles"],
                    f["tests"],
                )
                for n, f in fr[:top]
            ],
        )
    )

    progs = collections.defaultdict(lambda: [0.0, 0, 0.0])
    for r in rows:
        for name, (s, c, longest) in r["programs"].items():
            p = progs[name]
            p[0] += s
            p[1] += c
            p[2] = max(p[2], longest)
    pr = sorted(progs.items(), key=lambda kv: -kv[1][0])
    out.append("\ncompiled programs by name (XLA compile seconds, summed over the suite):\n")
    out.append(
        _table(
            ("program", "seconds", "compiles", "longest one"),
            [(n, f"{s:.1f}", c, f"{m:.1f}") for n, (s, c, m) in pr[:top]],
        )
    )

    def tests_by(key, title):
        rs = sorted(rows, key=key, reverse=True)[:top]
        out.append(f"\n{title}:\n")
        out.append(
            _table(
                ("test", "wall", "compile", "trace + lower", "rest"),
                [
                    (
                        r["test"],
                        f"{r['wall']:.1f}",
                        f"{r['compile']:.1f}",
                        f"{r['trace'] + r['lower']:.1f}",
                        f"{r['wall'] - r['trace'] - r['lower'] - r['compile']:.1f}",
                    )
                    for r in rs
                ],
            )
        )

    tests_by(lambda r: r["compile"], "tests with the most compile time (seconds)")
    tests_by(lambda r: r["wall"] - r["trace"] - r["lower"] - r["compile"], "tests with the most other time (seconds)")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--top", type=int, default=20, help="rows per table")
    args, rest = ap.parse_known_args(argv)
    if rest[:1] == ["--"]:
        rest = rest[1:]
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with tempfile.TemporaryDirectory() as out:
        env = dict(os.environ, **{OUT_ENV: out})
        here = os.path.dirname(os.path.abspath(__file__))
        env["PYTHONPATH"] = os.pathsep.join([here] + [p for p in [os.environ.get("PYTHONPATH")] if p])
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "profile_suite", *rest], cwd=root, env=env)
        wall = time.perf_counter() - t0
        rows = [json.loads(line) for path in glob.glob(os.path.join(out, "*.jsonl")) for line in open(path)]
    if not rows:
        print("no test ran", file=sys.stderr)
        return proc.returncode or 1
    print(f"\npytest exit status {proc.returncode}, wall {wall:.0f} s\n")
    print(report(rows, args.top))
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
