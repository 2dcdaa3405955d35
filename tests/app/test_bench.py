"""stereojax.app.bench, the measurements of `make bench`: the machine's description, and the demo
timing runs what `make demo` runs."""

from stereojax.app import bench


def test_cpu_description_names_the_model_and_vector_units():
    text = bench.cpu_description()
    assert text and "(" in text and text.endswith(")")


def test_demo_child_times_what_make_demo_runs(monkeypatch):
    """The demo timing is of `--method best` on the built-in pair, with the confidence map, as
    `make demo` runs it (the chain itself is replaced: make demo's own test runs it)."""
    from stereojax.models import registry as models

    seen = {}

    def fake_warm_chain(left, right, cfg, model=None, repeats=3, confidence=False):
        seen.update(shape=left.shape[:2], cfg=cfg, model=model, confidence=confidence)
        return {"warm_s": 1.5, "compile_s": 2.0}

    monkeypatch.setattr(bench, "warm_chain", fake_warm_chain)
    out = bench.demo_child(repeats=1)
    want = models.resolve("best", width=741, height=500, dataset="middlebury", max_disp=64)
    assert seen["shape"] == (500, 741) and seen["confidence"] is True
    assert seen["cfg"] == want.config and seen["model"].net == want.model().net
    assert out["model"] == want.description and "middlebury" in out["model"]
    assert out["warm_s"] == 1.5 and out["shape"] == [500, 741] and out["max_disp"] == 64
