"""The layering, held against the imports (docs/architecture.md): a module may import only its
own layer or lower ones. runio is the lowest; scripts/ (the command line) the highest; the world
(`skyherd sim`) and the mission layer (`skyherd companion`) are separate programs and never
import each other."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "skyherd"

# package → layer; a module may import packages of its own layer or below (peers at one layer
# may import each other unless listed in SEPARATE).
LAYERS = {
    "runio": 0,
    "flight": 1, "groundsim": 1, "perception": 1, "policy": 1, "safety": 1,
    "hil": 2, "record": 2,
    "world": 3, "mission": 3,
    "scripts": 4,
}  # fmt: skip
SEPARATE = {("world", "mission"), ("mission", "world")}


def imports_of(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {_package(a.name) for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "skyherd":  # from skyherd import policy
                out |= {a.name for a in node.names}
            else:
                out.add(_package(node.module))
    return out


def _package(module: str) -> str:
    """skyherd.safety.net → safety (the layer's package)."""
    parts = module.split(".")
    return parts[1] if parts[0] == "skyherd" and len(parts) > 1 else parts[0]


def violations(package: str) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for dep in sorted(imports_of(path) & set(LAYERS)):
            if dep == package:
                continue
            if LAYERS[dep] > LAYERS[package] or (package, dep) in SEPARATE:
                bad.append(f"{path.relative_to(ROOT)} imports {dep}")
    return bad


@pytest.mark.parametrize("package", sorted(LAYERS))
def test_no_import_from_a_higher_layer(package):
    if not (ROOT / package).is_dir():
        pytest.skip(f"{package}/ does not exist in this checkout")
    assert violations(package) == []


def test_the_contract_catches_a_violation(tmp_path, monkeypatch):
    """The check itself can fail: a module of a low layer that imports the command line."""
    pkg = tmp_path / "runio"
    pkg.mkdir()
    (pkg / "bad.py").write_text(
        "from skyherd.scripts.cli import UsageError\nimport skyherd.mission.flight\n"
    )
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    assert violations("runio") == ["runio/bad.py imports mission", "runio/bad.py imports scripts"]
