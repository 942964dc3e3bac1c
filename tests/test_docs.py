"""Docs that cannot go stale: every command and code block in README.md and docs/*.md is
checked against the current code, and marked outputs are regenerated and compared.

What is checked, for whatever the docs say today (other helpers keep editing them):
- `skyherd ...` commands (in code blocks, with or without a `$ ` prompt or `.venv/bin/`): the
  sub-command exists and the real parser accepts every argument (parse only: the flight or the
  training itself is not run here; its --help is).
- `python -m MODULE` / `python FILE`: the module or file exists; `pytest PATHS`: the paths or
  globs match test files; `make TARGET`: the target is in the Makefile.
- python blocks: compiled; a self-contained block (every name it uses is bound in it) is run;
  a fragment (it uses names from around it, e.g. `ap`, `phi`) has its imports run, so renamed
  modules and functions are caught.
- `<!-- output: CMD -->` on the line before a block: CMD is run (bash, from a temporary folder,
  `.venv/bin/` is this venv) and the block must have the structure of the real output: the
  same table headers and row labels, and every other line the same once numbers, paths and
  times are blanked.
- `<!-- doc-test: imports REASON -->` before a python block runs only its imports (a block
  that needs a live vehicle or a running simulator); `<!-- doc-test: skip REASON -->` skips a
  block.
"""

from __future__ import annotations

import ast
import builtins
import glob
import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


@dataclass(frozen=True)
class Block:
    file: str
    line: int  # first line of the block's text (1-based)
    lang: str
    text: str
    marker: str  # the HTML comment on the line before the fence, or ""

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}"


def blocks_of(path: Path) -> list[Block]:
    out, lines = [], path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^(\s*)```+\s*([\w+-]*)", lines[i])
        if not m:
            i += 1
            continue
        indent, lang = m.group(1), m.group(2).lower()
        j = i - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        marker = lines[j].strip() if j >= 0 and lines[j].strip().startswith("<!--") else ""
        k = i + 1
        while k < len(lines) and not lines[k].strip().startswith("```"):
            k += 1
        body = "\n".join(
            ln[len(indent) :] if ln.startswith(indent) else ln for ln in lines[i + 1 : k]
        )
        out.append(Block(str(path.relative_to(ROOT)), i + 2, lang, body, marker))
        i = k + 1
    return out


ALL = [b for p in DOCS for b in blocks_of(p)]


def _skip(b: Block) -> str | None:
    m = re.match(r"<!--\s*doc-test:\s*skip\s*(.*?)\s*-->", b.marker)
    return (m.group(1) or "no reason given") if m else None


# -- commands -----------------------------------------------------------------------------


def commands_of(b: Block) -> list[str]:
    """Command lines of a block: `$ ` prompt lines in any block; in shell-like blocks without
    prompts, lines that start with a known program. Comments and a trailing `&` dropped,
    `\\` continuations joined."""
    text = re.sub(r"\\\n\s*", " ", b.text)
    lines = text.splitlines()
    prompted = [ln[2:] for ln in lines if ln.startswith("$ ")]
    if prompted:
        cands = prompted
    elif b.lang in ("", "sh", "bash", "console", "shell"):
        cands = lines
    else:
        return []
    out = []
    for ln in cands:
        ln = ln.strip()
        if not ln or ln.startswith("#"):
            continue
        if not prompted and b.lang == "" and re.search(r"[─►⇄│→(]", ln.split("  #")[0]):
            continue  # a diagram or prose in a plain block, not a command line
        try:
            words = shlex.split(ln, comments=True)
        except ValueError:
            continue
        while words and words[-1] in ("&", "&&", ";"):
            words.pop()
        if any(w.endswith(":") for w in words[:2]):  # output such as "skyherd fly: run folder"
            continue
        if words and _program(words[0]) in ("skyherd", "python", "make"):
            out.append(shlex.join(words))
    return out


def _program(word: str) -> str:
    name = Path(word).name
    return "python" if re.fullmatch(r"python(3(\.\d+)?)?", name) else name


COMMANDS = [(b, c) for b in ALL if not _skip(b) for c in commands_of(b)]


def check_command(cmd: str) -> None:
    words = shlex.split(cmd)
    prog = _program(words[0])
    if prog == "skyherd":
        from skyherd.scripts.cli import COMMANDS as SUB
        from skyherd.scripts.cli import build_parser

        args = words[1:]
        sub = next((a for a in args if not a.startswith("-")), None)
        assert sub in SUB or args == ["--version"], f"no sub-command {sub!r}"
        parser = build_parser(sub)
        try:
            ns, extra = parser.parse_known_args(args)
        except SystemExit as e:
            raise AssertionError(f"the parser refused `{cmd}`") from e
        assert not extra, f"unknown arguments {extra}"
    elif prog == "python":
        rest = words[1:]
        if rest[:2] == ["-m", "pytest"]:
            paths = [a.split("::")[0] for a in rest[2:] if not a.startswith("-") and "/" in a]
            for p in paths:
                assert glob.glob(str(ROOT / p)), f"pytest path {p} matches no file"
        elif rest[:1] == ["-m"]:
            assert importlib.util.find_spec(rest[1]) is not None, f"no module {rest[1]}"
        elif rest and not rest[0].startswith("-"):
            assert (ROOT / rest[0]).is_file(), f"no file {rest[0]}"
    elif prog == "make":
        targets = re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M)
        for t in (w for w in words[1:] if not w.startswith("-") and "=" not in w):
            assert t in targets, f"no make target {t}"


@pytest.mark.parametrize("block, cmd", COMMANDS, ids=[f"{b.where} {c[:50]}" for b, c in COMMANDS])
def test_documented_command_is_accepted(block, cmd):
    check_command(cmd)


def test_the_docs_have_commands_to_check():
    assert len(COMMANDS) >= 10  # the extraction itself works (a broken regex would find none)
    assert any("skyherd" in c for _, c in COMMANDS)


# -- python blocks ------------------------------------------------------------------------


def free_names(code: str) -> set[str]:
    """Names a block loads but never binds (nor imports) and that are not builtins."""
    tree = ast.parse(code)
    bound, loaded = set(dir(builtins)), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (loaded if isinstance(node.ctx, ast.Load) else bound).add(node.id)
        elif isinstance(node, ast.alias):
            bound.add((node.asname or node.name).split(".")[0])
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            bound.add(node.name)
        elif isinstance(node, ast.arg):
            bound.add(node.arg)
        elif isinstance(node, ast.ExceptHandler) and node.name:
            bound.add(node.name)
    return loaded - bound


PY = [b for b in ALL if b.lang in ("python", "py") and not _skip(b)]

DRIVER = textwrap.dedent(
    """
    import ast, json, signal, sys, time, traceback, io, contextlib
    jobs = json.load(sys.stdin)
    out = []
    def alarm(*_):
        raise TimeoutError("block ran longer than its budget")
    signal.signal(signal.SIGALRM, alarm)
    for job in jobs:
        t0 = time.process_time()
        res = {"where": job["where"], "ok": True, "error": ""}
        signal.alarm(job["timeout_s"])
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                exec(compile(job["code"], job["where"], "exec", flags=ast.PyCF_ALLOW_TOP_LEVEL_AWAIT), {"__name__": "__doc_block__"})
        except BaseException as e:
            res["ok"], res["error"] = False, "".join(traceback.format_exception_only(type(e), e)).strip()
        finally:
            signal.alarm(0)
        res["cpu_s"] = time.process_time() - t0
        out.append(res)
    print(json.dumps(out))
    """
)


def _imports_only(code: str) -> str:
    tree = ast.parse(code)
    keep = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
    return ast.unparse(ast.Module(body=keep, type_ignores=[]))


def test_python_blocks_compile_and_run(tmp_path):
    """Self-contained blocks run whole; fragments run their imports (module docstring)."""
    jobs, kinds = [], {}
    for b in PY:
        try:
            compile(b.text, b.where, "exec", flags=ast.PyCF_ALLOW_TOP_LEVEL_AWAIT)
        except SyntaxError as e:
            raise AssertionError(f"{b.where}: python block does not compile: {e}") from e
        free = free_names(b.text)
        imports_only = re.match(r"<!--\s*doc-test:\s*imports", b.marker)
        whole = not free and "await" not in b.text and not imports_only
        why = "marked" if imports_only else f"uses {', '.join(sorted(free)) or 'await'}"
        kinds[b.where] = "run" if whole else f"imports only ({why})"
        jobs.append(
            {"where": b.where, "code": b.text if whole else _imports_only(b.text), "timeout_s": 120}
        )
    assert jobs, "no python block found"
    r = subprocess.run([sys.executable, "-c", DRIVER], input=json.dumps(jobs), capture_output=True,
                       text=True, cwd=tmp_path, timeout=900, env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    results = json.loads(r.stdout.strip().splitlines()[-1])
    bad = [f"{x['where']} ({kinds[x['where']]}): {x['error']}" for x in results if not x["ok"]]
    assert not bad, "\n".join(bad)
    assert any(k == "run" for k in kinds.values())  # at least one block is run whole
    for x in results:
        print(f"{x['where']}: {kinds[x['where']]}, {x['cpu_s']:.1f} s CPU")


# -- outputs ------------------------------------------------------------------------------

OUTPUTS = [b for b in ALL if re.match(r"<!--\s*output:", b.marker) and not _skip(b)]
_NUM = re.compile(r"[-+]?\d[\d,_]*(\.\d+)?([eE][-+]?\d+)?")


def shape(line: str) -> str:
    """A line with numbers, paths, times and padding blanked: what must not change."""
    s = re.sub(r"(/[\w.\-]+)+/?", "PATH", line)
    s = re.sub(r"\d{8}T\d{6}Z[-\w]*", "STAMP", s)
    s = _NUM.sub("N", s)
    s = re.sub(r"N( ?± ?N)?", "N", s)
    return re.sub(r"\s+", " ", s).strip()


def table_rows(text: str) -> list[list[str]]:
    rows = []
    for ln in text.splitlines():
        ln = ln.strip()
        if ln.startswith("|") and not re.fullmatch(r"\|[\s|:-]+\|", ln):
            rows.append([c.strip() for c in re.split(r"(?<!\\)\|", ln.strip("|"))])
    return rows


def compare_output(doc: str, actual: str) -> list[str]:
    """Differences in structure between a documented output and the real one."""
    problems = []
    d_rows, a_rows = table_rows(doc), table_rows(actual)
    d_labels = [shape(r[0]) for r in d_rows]
    a_labels = [shape(r[0]) for r in a_rows]
    if d_labels != a_labels[: len(d_labels)] and set(d_labels) - set(a_labels):
        problems.append(f"table rows differ: doc {d_labels} vs real {a_labels}")
    for r in d_rows:
        if len(r) != len(next((a for a in a_rows if shape(a[0]) == shape(r[0])), r)):
            problems.append(f"row {r[0]!r} has a different number of columns")
    real = {shape(ln) for ln in actual.splitlines()}
    for ln in doc.splitlines():
        if not ln.strip() or ln.strip().startswith("|") or ln.startswith("$ "):
            continue
        if shape(ln) not in real:
            problems.append(f"line not in the real output: {ln.strip()!r}")
    return problems


@pytest.mark.parametrize(
    "block",
    [pytest.param(b, marks=pytest.mark.slow) if " train " in b.marker else b for b in OUTPUTS],
    ids=[b.where for b in OUTPUTS],
)  # a learner run is slow (make test-fast leaves it out)
def test_documented_output_is_the_real_output(block, tmp_path):
    cmd = re.match(r"<!--\s*output:\s*(.*?)\s*-->", block.marker).group(1)
    cmd = cmd.replace(".venv/bin/", f"{VENV_BIN}/")
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ['PATH']}", "PYTHONPATH": str(ROOT)}
    r = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, cwd=tmp_path,
                       timeout=600, env=env)  # fmt: skip
    actual = r.stdout + r.stderr
    problems = compare_output(block.text, actual)
    assert not problems, (
        f"{block.where}: `{cmd}`\n"
        + "\n".join(problems)
        + f"\n--- real output ---\n{actual[-3000:]}"
    )


def test_output_comparison_sees_a_changed_table():
    """The comparison is not vacuous: a renamed row or a line the code no longer prints fails."""
    real = "| metric | value |\n|---|---|\n| decisions | 120 |\n| rejected | 3 |\nrun folder: /tmp/x/20261201T000000Z-fly\n"
    assert (
        compare_output("| metric | value |\n|--|--|\n| decisions | 80 |\nrun folder: /a/b\n", real)
        == []
    )
    assert compare_output("| metric | value |\n| decisions | 80 |\n| accepted | 1 |\n", real)
    assert compare_output("run directory: /a/b\n", real)


# -- the README's MAVSDK line -------------------------------------------------------------

MAVSDK_INSTANCES = range(80, 85)  # this area's vehicle instances (a parallel run may hold one)


def readme_mavsdk_snippet() -> str:
    """The README's `# MAVSDK-Python ...:` comment line and its `#   ` continuation lines, as
    the Python code they show."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    start = next(i for i, ln in enumerate(lines) if re.match(r"#\s*MAVSDK-Python", ln.strip()))
    code = [lines[start].split(":", 1)[1].strip()]
    for ln in lines[start + 1 :]:
        if not re.match(r"#\s{2,}\S", ln.strip()):
            break
        code.append(ln.strip()[1:])
    return textwrap.dedent(code[0] + "\n" + textwrap.dedent("\n".join(code[1:])))


def test_readme_mavsdk_line_works_with_mavsdk_4():
    """Run the README's MAVSDK line as written (port moved to instance 80..84) against a real SITL
    (flight.sitl.Sitl); MAVSDK-Python 4.1 must find the autopilot."""
    import asyncio

    from skyherd.flight.airframes_registry import make_autopilot
    from skyherd.flight.clock import SimClock
    from skyherd.flight.mavlink import EndpointConfig
    from skyherd.flight.sitl import Sitl

    code = readme_mavsdk_snippet()
    assert "udpin://127.0.0.1:14540" in code
    for instance in MAVSDK_INSTANCES:
        ap = make_autopilot("quadrotor", clock=SimClock(), instance=instance)
        try:
            sitl = Sitl(ap, EndpointConfig(instance=instance), speedup=4.0)
        except OSError:  # its ports are taken (another run of this suite): the next instance
            continue
        break
    else:
        pytest.fail(f"every vehicle instance in {MAVSDK_INSTANCES} is in use")
    last = code.rstrip().splitlines()[-1]
    inner = last[: len(last) - len(last.lstrip())]  # inside the snippet's `async with`
    code = code.replace("14540", str(14540 + instance))
    code += f"\n{inner}return drone, await drone.get_system_id()\n"
    src = "async def _readme():\n" + textwrap.indent(code, "    ")
    ns: dict = {}
    exec(compile(src, "README.md (MAVSDK line)", "exec"), ns)
    with sitl:
        sitl.start()
        drone, sysid = asyncio.run(asyncio.wait_for(ns["_readme"](), timeout=120))
    assert drone is not None and sysid == 1 + instance


# -- the README's figures: the output of a script, each with its command -------------------

FIGURE = re.compile(r"!\[[^\]]*\]\((docs/figures/[^)\s]+)\)")
FIGURES_INSTANCE = 37  # this area's vehicle instance


def _figures_manifest() -> dict:
    from skyherd.report.figures import MANIFEST, OUT

    return json.loads((OUT / MANIFEST).read_text(encoding="utf-8"))


def test_readme_figures_exist_with_their_command_and_hash():
    """Every figure the README shows is in docs/figures/figures.json (written by
    `python -m skyherd.scripts.figures`) with the command on the line above it and the file's
    SHA-256; the README's figures block is the one the script writes from that file."""
    import hashlib

    from skyherd.report.figures import readme_block

    manifest = _figures_manifest()
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    shown = [(i, m.group(1)) for i, ln in enumerate(lines) if (m := FIGURE.search(ln))]
    assert {Path(p).name for _, p in shown} == set(manifest["figures"]) and shown
    for i, rel in shown:
        entry = manifest["figures"][Path(rel).name]
        assert lines[i - 1].strip() == f"<!-- figure: {entry['command']} -->", rel
        data = (ROOT / rel).read_bytes()
        assert (
            data.startswith(b"\x89PNG") and hashlib.sha256(data).hexdigest() == entry["sha256"]
        ), f"{rel} is not the file figures.json lists: run `make figures`"
    assert readme_block(manifest) in "\n".join(lines)


@pytest.mark.slow
def test_readme_figures_are_what_their_command_draws_today(tmp_path):
    """Fly each drawn figure's command (the flight is the same on any machine at any load:
    lockstep) and compare the figure it draws, byte for byte, with the README's."""
    from skyherd.report.figures import DRAWN, command_text, sha256
    from skyherd.scripts.figures import fly

    manifest = _figures_manifest()
    runs: dict[tuple, Path] = {}
    for name, (argv, src, _) in DRAWN.items():
        assert manifest["figures"][name]["command"] == command_text(argv)
        if argv not in runs:
            runs[argv] = fly(argv, tmp_path / "runs", FIGURES_INSTANCE)
        assert sha256(runs[argv] / src) == manifest["figures"][name]["sha256"], (
            f"docs/figures/{name} is not what `{command_text(argv)}` draws today: run "
            "`make figures` (python -m skyherd.scripts.figures) and commit its output"
        )
