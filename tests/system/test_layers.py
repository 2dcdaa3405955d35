"""The package's layers: which sub-package may import which (docs/architecture.md, "Layers").

Imports are read from the source (top level and inside functions alike), so a lazy import
cannot hide a forbidden edge."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "stereojax"

#: each part of the package and the parts it may import (itself always allowed)
BASE = {"errors", "config", "volume", "devices", "progress", "interrupt", "metrics", "data", "kernels"}
STEPS = {"matching_cost", "aggregation", "optimization", "disparity", "validation", "refinement", "filters"}
ALLOWED = {
    **{b: BASE for b in BASE},
    **{s: BASE | STEPS | {"models"} for s in STEPS},
    "models": BASE | {"matching_cost"},
    "chain": BASE | STEPS | {"models"},
    "inference": BASE | STEPS | {"models", "chain"},
    "learning": BASE | STEPS | {"models", "chain"},
    "app": BASE | STEPS | {"models", "chain", "inference", "learning", "app"},
    "__init__": BASE | {"inference", "models"},
}


def part_of(module: str) -> str:
    """'stereojax.inference.predictor' -> 'inference'; 'stereojax.chain' -> 'chain'."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imported_parts(source: str, package: list[str]) -> dict[str, int]:
    """The parts of the package a module's source imports, with the first line of each;
    ``package``: the dotted parts of the package the module sits in (for relative imports)."""
    found = {}
    for node in ast.walk(ast.parse(source)):
        modules = []
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "stereojax":
                modules = [f"stereojax.{a.name}" for a in node.names]
            elif target.startswith("stereojax."):
                modules = [target]
        elif isinstance(node, ast.Import):
            modules = [a.name for a in node.names if a.name.startswith("stereojax.")]
        for m in modules:
            found.setdefault(part_of(m), node.lineno)
    return found


def _package_of(path: Path) -> list[str]:
    return list(path.relative_to(PACKAGE.parent).parts[:-1])


def violations(source: str, package: list[str], own: str, name: str = "") -> list[str]:
    allowed = ALLOWED[own] | {own}
    return [f"{name}:{line} ({own}) imports {part}"
            for part, line in imported_parts(source, package).items() if part not in allowed and part in ALLOWED]


def _own_part(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def test_every_module_belongs_to_a_known_part():
    unknown = sorted({_own_part(p) for p in PACKAGE.rglob("*.py")} - set(ALLOWED))
    assert unknown == [], f"parts without a layer rule in ALLOWED: {unknown}"


def test_no_module_imports_a_layer_above_its_own():
    found = [v for p in sorted(PACKAGE.rglob("*.py"))
             for v in violations(p.read_text(), _package_of(p), _own_part(p), str(p.relative_to(PACKAGE)))]
    assert found == [], "\n".join(found)


def test_learning_and_inference_never_import_each_other():
    for own, other in (("learning", "inference"), ("inference", "learning")):
        for path in sorted((PACKAGE / own).rglob("*.py")):
            assert other not in imported_parts(path.read_text(), _package_of(path)), \
                f"{path.name} ({own}) imports {other}"


@pytest.mark.parametrize("source, own, part", [
    ("from stereojax.inference.predictor import Predictor\n", "learning", "inference"),
    ("def f():\n    from stereojax.app import cli\n", "inference", "app"),
    ("from .. import chain\n", "matching_cost", "chain"),
])
def test_the_check_finds_a_forbidden_import(source, own, part):
    assert [v.rsplit(" ", 1)[-1] for v in violations(source, ["stereojax", own], own)] == [part]
    assert violations(source, ["stereojax", "app"], "app") == []
