"""stereojax.data.pairs: what ``stereojax predict`` takes as its inputs: Middlebury scenes named by their
folder, pair lists with quoted, spaced, tab-separated, non-ASCII and relative paths, malformed lines."""

import re
import shlex

import pytest

from stereojax.data import io
from stereojax.data.pairs import list_pairs
from stereojax.errors import StereoInputError

from ..helpers import shifted_pair
from ..robustness_helpers import _cli

FAST = ["--max-disp", "16", "--method", "census"]


def test_middlebury_scenes_are_named_by_their_folder(tmp_path, capsys):
    from stereojax.data.pairs import find_pairs

    for i, scene in enumerate(["Cones", "Teddy"]):
        left, right = shifted_pair(4, h=64, w=128, seed=i)
        io.write_png(tmp_path / "mb" / scene / "im0.png", left)
        io.write_png(tmp_path / "mb" / scene / "im1.png", right)
    pairs, batch = find_pairs([tmp_path / "mb"])
    assert batch and [p[0] for p in pairs] == ["Cones", "Teddy"]
    listing = tmp_path / "pairs.txt"
    listing.write_text("mb/Cones/im0.png mb/Cones/im1.png\nmb/Teddy/im0.png mb/Teddy/im1.png\n")
    pairs, _ = find_pairs([listing])
    assert [p[0] for p in pairs] == ["Cones", "Teddy"]


def test_pair_list_takes_quoted_spaced_tabbed_non_ascii_and_relative_paths(tmp_path, capsys):
    folder = tmp_path / "my pairs"
    (folder / "sub dir").mkdir(parents=True)
    names = ["left one.png", "right one.png", "gauche é.png", "droite é.png", "l3.png", "r3.png",
             "l 4.png", "r 4.png"]
    for i, n in enumerate(names):
        left, right = shifted_pair(3, h=48, w=80, seed=i // 2)
        io.write_png(folder / "sub dir" / n, left if i % 2 == 0 else right)
    absolute = folder / "sub dir" / "l3.png"
    lst = folder / "pairs.txt"
    lst.write_text("# left right\n\n"
                   '"sub dir/left one.png" \'sub dir/right one.png\'\n'
                   "sub dir/gauche é.png\tsub dir/droite é.png\n"
                   f"{shlex.quote(str(absolute))} 'sub dir/r3.png'   \n"
                   "sub\\ dir/l\\ 4.png sub\\ dir/r\\ 4.png\n", encoding="utf-8")
    pairs = list_pairs(lst)
    assert [(n, l.name, r.name) for n, l, r in pairs] == [
        ("left one", "left one.png", "right one.png"), ("gauche é", "gauche é.png", "droite é.png"),
        ("l3", "l3.png", "r3.png"), ("l 4", "l 4.png", "r 4.png")]
    assert all(l.is_file() and r.is_file() for _, l, r in pairs)
    out = tmp_path / "out"
    code, _, err = _cli(["predict", "--pairs", lst, "--out", out, *FAST], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["gauche é", "l 4", "l3", "left one"]


@pytest.mark.parametrize("line, what", [('"a.png b.png', "No closing quotation"),
                                         ("a.png b.png c.png", "got 3 field(s)"),
                                         ("a.png", "got 1 field(s)")])
def test_a_malformed_pair_list_line_is_refused_up_front_with_its_number(tmp_path, capsys, line, what):
    lst = tmp_path / "pairs.txt"
    lst.write_text(f"# header\nx.png y.png\n{line}\n")
    with pytest.raises(StereoInputError, match=rf"line 3: .*{re.escape(what)}"):
        list_pairs(lst)
    out = tmp_path / "out"
    code, _, err = _cli(["predict", "--pairs", lst, "--out", out, *FAST], capsys)
    assert code == 2 and "line 3" in err and not (out / "summary.json").exists()
