"""Every Python code block of README.md and docs/*.md runs.

The ```python blocks of each file run in order, in one namespace (a later block uses the names
of an earlier one), in a fresh Python process with a clean environment: jax's default settings
(not this suite's strict ones from conftest.py), one CPU device, and a temporary working
directory holding a copy of ``scenes/`` (the docs run their examples from the repository root).
A failure names the file and line of the block, with the traceback pointing into the Markdown.

A block meant to be read only is fenced as ```python no-run, or preceded by the line
``<!-- no-run -->``. A block fenced as ```python slow (one that takes minutes, such as an edge
gradient of a deep scene) runs only when ``RAYTRAX_DOCS_SLOW=1``. Blocks in other languages
(bash, toml, text) are not run, but a block preceded by the line ``<!-- file: NAME -->`` is
written to the file NAME in the working directory first, so that the Python blocks can load it.

The files run two at a time (``RAYTRAX_DOCS_JOBS`` changes that): most of their time is XLA
compiling, which is mostly single-threaded. They share one jax persistent compilation cache (a
temporary folder), so a program that two pages compile is compiled once. Each block's wall and
CPU time is printed (``pytest -s``): keep them small (tiny images, few samples, few steps).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import site
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
NO_RUN_COMMENT = "<!-- no-run -->"
RUN_LANGUAGES = ("python", "py")
RUN_SLOW = os.environ.get("RAYTRAX_DOCS_SLOW", "") not in ("", "0")
TIMEOUT_S = 900

_FILE_COMMENT = re.compile(r"^<!-- file: (\S+) -->$")
_FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,}|~{3,})(?P<info>[^`]*)$")


@dataclasses.dataclass(frozen=True)
class Block:
    line: int  # 1-based line of the first line of code (the line after the opening fence)
    language: str
    info: tuple[str, ...]  # the info string's words after the language
    code: str
    no_run_comment: bool  # the last non-blank line before the fence is <!-- no-run -->
    file: str | None  # <!-- file: NAME --> before the fence: the file the block is written to

    def runs(self, slow: bool = False) -> bool:
        """Whether the block is run (``slow``: blocks marked ``slow`` too)."""
        if self.language not in RUN_LANGUAGES or "no-run" in self.info or self.no_run_comment:
            return False
        return slow or "slow" not in self.info


def code_blocks(text: str) -> list[Block]:
    """The fenced code blocks of a Markdown text, indented ones (in list items) included."""
    lines = text.splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        indent, fence, words = len(m["indent"]), m["fence"], m["info"].split()
        before = [ln.strip() for ln in lines[:i] if ln.strip()]
        close = re.compile(rf"^ *{re.escape(fence[0])}{{{len(fence)},}} *$")
        j = i + 1
        while j < len(lines) and not close.match(lines[j]):
            j += 1
        body = [ln[indent:] if ln[:indent].strip() == "" else ln.lstrip() for ln in lines[i + 1 : j]]
        language = words[0].lower() if words else ""
        file = _FILE_COMMENT.match(before[-1]) if before else None
        blocks.append(
            Block(
                line=i + 2,
                language=language,
                info=tuple(w.lower() for w in words[1:]),
                code="\n".join(body) + "\n",
                no_run_comment=bool(before) and before[-1] == NO_RUN_COMMENT,
                file=file[1] if file else None,
            )
        )
        i = j + 1
    return blocks


def runnable(path: Path) -> list[Block]:
    return [b for b in code_blocks(path.read_text(encoding="utf-8")) if b.runs(RUN_SLOW)]


def files(path: Path) -> dict[str, str]:
    """The blocks marked ``<!-- file: NAME -->``: ``{NAME: content}``."""
    return {b.file: b.code for b in code_blocks(path.read_text(encoding="utf-8")) if b.file}


# Runs in the child process: argv[1] is a JSON file {"path": ..., "blocks": [[line, code], ...]}.
# Each block is compiled with the Markdown file as its file name and its own line numbers, so a
# traceback shows the line of the document.
_DRIVER = """
import json, sys, time
spec = json.load(open(sys.argv[1], encoding="utf-8"))
ns = {"__name__": "__main__"}
for line, code in spec["blocks"]:
    print(f"--- {spec['name']}:{line}", file=sys.stderr, flush=True)
    t0, c0 = time.perf_counter(), time.process_time()
    exec(compile("\\n" * (line - 1) + code, spec["path"], "exec"), ns)
    t, c = time.perf_counter() - t0, time.process_time() - c0
    print(f"--- {spec['name']}:{line} ran in {t:.1f} s (cpu {c:.1f} s)", file=sys.stderr, flush=True)
"""


def _clean_env(home: Path, jax_cache: Path) -> dict[str, str]:
    env = {k: os.environ[k] for k in ("PATH", "LANG", "LC_ALL", "TMPDIR", "SYSTEMROOT") if k in os.environ}
    env.update(
        HOME=str(home),  # what the docs write under ~ (the compilation cache) stays in the test's folder
        PYTHONUSERBASE=site.getuserbase(),  # packages installed with pip --user stay visible
        PYTHONPATH=str(ROOT),  # this checkout's raytrax, whatever else is installed
        JAX_PLATFORMS="cpu",
        # One persistent compilation cache for all the files of a run: a program that two pages
        # compile (README.md and docs/index.md show the same example) is compiled once.
        JAX_COMPILATION_CACHE_DIR=str(jax_cache),
        MPLBACKEND="Agg",
        PYTHONUNBUFFERED="1",
    )
    return env


def _run_file(path: Path, blocks: list[Block], work: Path, jax_cache: Path) -> subprocess.CompletedProcess:
    work.mkdir(parents=True)
    shutil.copytree(ROOT / "scenes", work / "scenes")
    (work / "home").mkdir()
    for name, content in files(path).items():
        target = work / name
        assert work.resolve() in target.resolve().parents, (
            f"{path.name}: file {name!r} is outside the working directory"
        )
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(content, encoding="utf-8")
    spec = work / "_blocks.json"
    name = str(path.relative_to(ROOT))
    spec.write_text(json.dumps({"path": str(path), "name": name, "blocks": [[b.line, b.code] for b in blocks]}))
    return subprocess.run(
        [sys.executable, "-c", _DRIVER, str(spec)],
        cwd=work,
        env=_clean_env(work / "home", jax_cache),
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )


FILES_WITH_CODE = [p for p in DOC_FILES if runnable(p)]


@pytest.fixture(scope="module")
def doc_runs(request, tmp_path_factory):
    """Start the runs of every selected file at once (longest first, ``RAYTRAX_DOCS_JOBS`` at a
    time); each test waits for its own."""
    jobs = int(os.environ.get("RAYTRAX_DOCS_JOBS", "2"))
    selected = {
        item.callspec.params["path"]
        for item in request.session.items
        if getattr(item, "originalname", None) == "test_code_blocks_run" and hasattr(item, "callspec")
    }
    order = sorted(selected, key=lambda p: -len(runnable(p)))
    pool = ThreadPoolExecutor(max_workers=max(1, jobs))
    base = tmp_path_factory.mktemp("docs")
    cache = base / "jax-cache"
    futures = {p: pool.submit(_run_file, p, runnable(p), base / f"{i}-{p.stem}", cache) for i, p in enumerate(order)}
    yield futures
    pool.shutdown(wait=False, cancel_futures=True)


@pytest.mark.parametrize("path", FILES_WITH_CODE, ids=lambda p: str(p.relative_to(ROOT)))
def test_code_blocks_run(path, doc_runs):
    proc = doc_runs[path].result()
    print("\n".join(ln for ln in proc.stderr.splitlines() if ln.startswith("---") and " ran in " in ln))
    if proc.returncode != 0:
        out = (proc.stdout[-3000:] + "\n" + proc.stderr[-12000:]).strip()
        pytest.fail(f"a Python block of {path.relative_to(ROOT)} failed (the last '---' line names it):\n{out}")


def test_the_docs_have_code_to_run():
    names = {str(p.relative_to(ROOT)) for p in FILES_WITH_CODE}
    assert {"README.md", "docs/gradients.md", "docs/scaling.md", "docs/scene-format.md"} <= names


def test_code_block_parser():
    text = "\n".join(
        [
            "```python",
            "a = 1",
            "```",
            "- item:",
            "",
            "  ```python",
            "  if a:",
            "      b = 2",
            "  ```",
            "```python no-run",
            "raise SystemExit",
            "```",
            "```python slow",
            "c = 3",
            "```",
            "<!-- no-run -->",
            "",
            "```python",
            "raise SystemExit",
            "```",
            "````bash",
            "```python",
            "````",
            "```",
            "plain",
            "```",
            "<!-- file: a.toml -->",
            "```toml",
            "x = 1",
            "```",
        ]
    )
    blocks = code_blocks(text)
    assert [(b.line, b.language, b.runs(), b.runs(slow=True)) for b in blocks] == [
        (2, "python", True, True),
        (7, "python", True, True),
        (11, "python", False, False),
        (14, "python", False, True),
        (19, "python", False, False),
        (22, "bash", False, False),
        (25, "", False, False),
        (29, "toml", False, False),
    ]
    assert blocks[-1].file == "a.toml" and blocks[-1].code == "x = 1\n"
    assert blocks[1].code == "if a:\n    b = 2\n"
    ns = {}
    for b in blocks:
        if b.runs():
            exec(b.code, ns)
    assert ns["b"] == 2 and "c" not in ns


def test_every_public_name_is_in_the_api_reference():
    import raytrax

    pages = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "docs" / "api").glob("*.md"))
    documented = set(re.findall(r"^::: raytrax\.(\w+)\s*$", pages, re.M))
    missing = sorted(n for n in raytrax.__all__ if not n.startswith("_") and n not in documented)
    assert not missing, f"public names missing from docs/api/*.md (add a '::: raytrax.NAME' line): {missing}"


def test_every_page_is_in_the_nav():
    yaml = pytest.importorskip("yaml")
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))

    def pages(entry):
        if isinstance(entry, str):
            yield entry
        elif isinstance(entry, dict):
            for v in entry.values():
                yield from pages(v)
        elif isinstance(entry, list):
            for v in entry:
                yield from pages(v)

    in_nav = set(pages(config["nav"]))
    on_disk = {str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md")}
    assert on_disk <= in_nav, f"pages missing from mkdocs.yml's nav: {sorted(on_disk - in_nav)}"
