"""Module boundaries: no module of the package reaches for another module's private names."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "stereojax"


def _private_uses(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    found, modules = [], set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("stereojax")):
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    found.append(f"{path.name}:{node.lineno} imports {node.module}.{alias.name}")
                else:
                    modules.add(alias.asname or alias.name)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("stereojax"):
                    modules.add((alias.asname or alias.name).split(".")[0])
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            found.append(f"{path.name}:{node.lineno} uses {node.value.id}.{node.attr}")
    return found


def test_no_module_uses_another_modules_private_names():
    found = [f for p in sorted(PACKAGE.rglob("*.py")) for f in _private_uses(p)]
    assert found == [], found


def test_the_check_finds_a_private_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from .pipeline import _as_grey\nfrom . import pipeline\nx = pipeline._COMPILED\n")
    assert len(_private_uses(bad)) == 2


#: the modules of training, and the inference modules they must not import
TRAINING = ("train.py", "sampling.py", "losses.py", "nets.py", "checkpoint.py")
INFERENCE = {"pipeline", "chain", "compile_cache", "tiling", "batch", "coarse"}


def _package_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                names.add(node.module.split(".")[0])
            else:
                names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("stereojax."):
            names.add(node.module.split(".")[1])
    return names


def test_training_never_imports_inference():
    found = {name: sorted(_package_imports(PACKAGE / name) & INFERENCE) for name in TRAINING}
    assert all(not v for v in found.values()), found


def test_the_import_check_finds_an_inference_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from .pipeline import as_grey\nfrom . import chain\n")
    assert _package_imports(bad) & INFERENCE == {"pipeline", "chain"}
