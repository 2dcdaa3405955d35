"""The project's own files: make evaluate never writes the project's results, and the licence files and
the weights' terms."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_make_evaluate_writes_outside_the_project_results():
    make = (ROOT / "Makefile").read_text()
    block = make[make.index("\nevaluate:"):make.index("\n# the project's own scored runs")]
    assert "--out $(OUT)/evaluate_" in block and "experiments/results" not in block
    report = (ROOT / "experiments" / "report.py").read_text()
    for name in ("evaluate_kitti2015_best", "evaluate_kitti2012_best", "evaluate_middlebury_best"):
        assert name in report and f"experiments/results/{name}" in make     # fed by its own target only


def test_licence_files_and_the_weights_terms():
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT" and "LICENSE" in project["license-files"]
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    terms = (ROOT / "stereojax" / "models" / "weights" / "LICENSE.md").read_text()
    assert "CC BY-NC-SA 3.0" in terms and "non-commercial" in terms.lower()
