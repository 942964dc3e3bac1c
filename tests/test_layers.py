"""The layering, held against the imports. The rules are read from docs/architecture.md's table
(layer, package, allowed same-layer peers, "never" packages); every module under skyherd/ is
checked, with relative imports, importlib / __import__ calls with a literal name and module names
written as strings ("skyherd.flight.multirotor.autopilot", "skyherd.policy.groundair.env:X")."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "skyherd"
ARCHITECTURE = REPO / "docs" / "architecture.md"


@dataclass(frozen=True)
class Rule:
    layer: int
    same_layer: frozenset[str]
    never: frozenset[str]


def _names(cell: str) -> frozenset[str]:
    return frozenset(w.strip(" `") for w in cell.split(",") if w.strip(" `—-"))


def read_rules(path: Path = ARCHITECTURE) -> dict[str, Rule]:
    """package → Rule, from the markdown table after the `<!-- layers: -->` marker."""
    text = path.read_text(encoding="utf-8")
    table = text[text.index("<!-- layers:") :]
    rules = {}
    for line in table.splitlines()[1:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("|"):
            if rules:
                break
            continue
        if len(cells) < 4 or not cells[0].isdigit():
            continue
        rules[cells[1].strip("`")] = Rule(int(cells[0]), _names(cells[2]), _names(cells[3]))
    return rules


RULES = read_rules()

_MODULE_STRING = re.compile(
    r"^skyherd(\.[a-z_][a-z0-9_]*)+(:\w+)?$"
)  # not a schema name (skyherd.Phi)


def _package(module: str) -> str | None:
    """skyherd.safety.net → safety; anything outside skyherd → None."""
    parts = module.split(".")
    return parts[1] if parts[0] == "skyherd" and len(parts) > 1 else None


def imports_of(path: Path, root: Path) -> set[str]:
    """The skyherd packages a module imports, by any of the ways above."""
    rel = path.relative_to(root)
    here = ["skyherd", *rel.parts[:-1]]  # the module's package (an __init__'s own), dotted
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    modules: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's own package
                base = here[: len(here) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if module == "skyherd" or (node.level and not node.module):
                modules += [f"{module}.{a.name}" for a in node.names]
            else:
                modules.append(module)
        elif isinstance(node, ast.Call):
            f = node.func
            name = (
                f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            )
            if name in ("import_module", "__import__") and node.args:
                arg = node.args[0]
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    modules.append(arg.value)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            if _MODULE_STRING.match(node.value):
                modules.append(node.value.split(":")[0])
    return {p for p in map(_package, modules) if p}


def violations(package: str, root: Path = ROOT, rules: dict[str, Rule] = RULES) -> list[str]:
    mine, bad = rules[package], []
    for path in sorted((root / package).rglob("*.py")):
        for dep in sorted(imports_of(path, root) - {package}):
            theirs = rules.get(dep)
            why = (
                "is not a package of docs/architecture.md" if theirs is None
                else "is listed under never" if dep in mine.never
                else "is a higher layer" if theirs.layer > mine.layer
                else "is a same-layer peer not listed" if theirs.layer == mine.layer
                and dep not in mine.same_layer
                else ""
            )  # fmt: skip
            if why:
                bad.append(f"{path.relative_to(root)} imports {dep} ({why})")
    return bad


def test_the_table_names_every_package_and_only_those():
    on_disk = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()}
    assert set(RULES) == on_disk
    for pkg, rule in RULES.items():
        for peer in rule.same_layer:
            assert RULES[peer].layer == rule.layer, f"{pkg}: {peer} is not of layer {rule.layer}"


@pytest.mark.parametrize("package", sorted(RULES))
def test_imports_follow_the_architecture(package):
    assert violations(package) == []


def test_the_readme_layout_table_matches_the_architecture():
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| (\d) \| `skyherd/(\w+)/` \|", readme, re.M)
    assert {pkg: int(layer) for layer, pkg in rows} == {p: r.layer for p, r in RULES.items()}


PROBES = {
    "relative": ("safety/bad.py", "from ..mission import flight\n", "mission (is a higher layer)"),
    "importlib": (
        "safety/bad.py",
        "import importlib\nm = importlib.import_module('skyherd.scripts.cli')\n",
        "scripts (is a higher layer)",
    ),
    "string": ("safety/bad.py", "ENTRY = 'skyherd.world.sim:World'\n", "world (is a higher layer)"),
    "same_layer_never": (
        "world/bad.py",
        "from skyherd.mission.flight import FlightPlan\n",
        "mission (is listed under never)",
    ),
    "same_layer_unlisted": (
        "flight/bad.py",
        "from skyherd import perception\n",
        "perception (is a same-layer peer not listed)",
    ),
    "lower_never": ("world/bad.py", "import skyherd.policy.dqn as dqn\n", "policy (is listed under never)"),
}  # fmt: skip


@pytest.mark.parametrize("kind", sorted(PROBES))
def test_the_check_fails_on_a_probe_tree(tmp_path, kind):
    """The check itself can fail: each way of importing, planted in a copy of the package tree."""
    rel, code, why = PROBES[kind]
    for pkg in RULES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / rel).write_text(code)
    package = rel.split("/")[0]
    assert violations(package, tmp_path) == [f"{rel} imports {why}"]
    (tmp_path / rel).unlink()
    assert violations(package, tmp_path) == []


_PROGRAMS = {
    "sim": "import skyherd.scripts.sim, skyherd.world.sim, skyherd.world.follow, skyherd.world.bridged",
    "companion": (
        "import skyherd.scripts.companion, skyherd.mission.companion, skyherd.mission.runner, "
        "skyherd.mission.flight, "
        "skyherd.mission.pilots, skyherd.mission.perception, skyherd.mission.orbit, "
        "skyherd.mission.shepherd, skyherd.mission.search, skyherd.policy.models as kept; "
        "from skyherd import policy; policy.load_policy(kept.DEFAULT_POLICY)"
    ),
}  # fmt: skip


@pytest.mark.parametrize("program", sorted(_PROGRAMS))
def test_the_programs_import_no_learner_framework(program):
    """The world and the companion (flying the kept policy) load neither gymnasium nor torch."""
    code = (
        f"import sys; {_PROGRAMS[program]}; "
        "print(sorted(m for m in ('gymnasium', 'torch') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         timeout=300, check=True).stdout  # fmt: skip
    assert out.strip() == "[]", out
