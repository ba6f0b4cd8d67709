"""What each class of depth error costs the render (pcdof.bench.depth_errors): the classes on known maps, the
counterfactual rows on a tiny wide case, and the bench part."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcdof.bench import depth_errors
from pcdof.errors import InputError


def test_classes_of_known_errors():
    exact = np.array([[1.0, 1.0, 3.0, 3.0],
                      [1.0, 1.0, 3.0, 0.0]])
    filled = np.array([[1.0, 3.0, 1.0, 3.05],
                       [1.1, 1.0, 3.0, 2.0]])  # right, foreground given the wall, wall given the foreground, noise;
    # 10 % off (small at 15 %), right, right, nothing seen there
    got = depth_errors.error_classes(filled, exact)
    nearer, farther, small = (got[name] for name in depth_errors.VARIANTS[1:4])
    np.testing.assert_array_equal(nearer, [[0, 1, 0, 0], [0, 0, 0, 0]])
    np.testing.assert_array_equal(farther, [[0, 0, 1, 0], [0, 0, 0, 0]])
    np.testing.assert_array_equal(small, [[0, 0, 0, 1], [1, 0, 0, 0]])
    assert depth_errors.error_classes(filled, exact, ratio=0.05)[depth_errors.VARIANTS[1]][1, 0]


def test_classes_put_right_give_the_exact_depth():
    rng = np.random.default_rng(3)
    exact = rng.uniform(0.5, 4.0, (40, 50))
    exact[rng.random(exact.shape) < 0.05] = 0.0
    filled = np.where(rng.random(exact.shape) < 0.5, exact, rng.uniform(0.5, 4.0, exact.shape))
    classes = depth_errors.error_classes(filled, exact)
    masks = np.stack(list(classes.values()))
    assert masks.sum(axis=0).max() <= 1  # disjoint
    union = masks.any(axis=0)
    seen = exact > 0
    np.testing.assert_array_equal(np.where(union, exact, filled)[seen], exact[seen])
    assert not union[~seen].any()


@pytest.mark.parametrize("args, name", [((np.ones((3, 4)), np.ones((4, 3))), "filled_m and exact_m"),
                                        ((np.ones(5), np.ones(5)), "filled_m and exact_m"),
                                        ((np.ones((2, 2)), np.ones((2, 2)), 0.0), "ratio"),
                                        ((np.ones((2, 2)), np.ones((2, 2)), float("nan")), "ratio"),
                                        ((np.ones((2, 2)), np.ones((2, 2)), True), "ratio")])
def test_bad_input_is_refused_naming_it(args, name):
    filled, exact, *ratio = args
    with pytest.raises(InputError, match=name):
        depth_errors.error_classes(filled, exact, **({"ratio": ratio[0]} if ratio else {}))


@pytest.fixture(scope="module")
def tiny_rows(tmp_path_factory):
    cache = tmp_path_factory.mktemp("gt")
    return depth_errors.run_depth_errors(kinds=["fence"], seeds=[0], blurs=(120.0,), size=(64, 48),
                                         depth_size=(64, 53), cache_dir=str(cache), progress=False)


def test_rows_of_a_tiny_case(tiny_rows):
    rows = tiny_rows
    assert [r["variant"] for r in rows] == list(depth_errors.VARIANTS) * 3
    assert [r["focus"] for r in rows[::len(depth_errors.VARIANTS)]] == ["near", "mid", "far"]
    for case in zip(*[iter(rows)] * len(depth_errors.VARIANTS)):
        filled, *classes, exact = case
        assert all(10 < r["psnr"] < 80 and 5 < r["psnr_edge"] < 80 for r in case)
        assert filled["pixels"] == sum(r["pixels"] for r in classes) > 0 and exact["pixels"] == 0
        assert all(0 <= r["holes"] <= r["pixels"] for r in case)
        for r in classes:  # a class with no pixel renders the filled depth itself
            if r["pixels"] == 0:
                assert r["psnr"] == filled["psnr"]
    table = depth_errors.cost_table(rows)
    assert "| fence | near | 1 |" in table and "| all | all | 3 |" in table
    assert depth_errors.VARIANTS[1] in table.splitlines()[0]


def test_bench_part(tmp_path):
    from click.testing import CliRunner

    from pcdof.cli import main

    out = tmp_path / "bench"
    result = CliRunner().invoke(main, ["bench", "--quick", "--only", "depth-errors", "-o", str(out)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    assert [r["variant"] for r in report["depth_errors"]] == list(depth_errors.VARIANTS) * 3
    csv_head = (out / "depth_errors.csv").read_text().splitlines()[0]
    assert csv_head.split(",")[:5] == ["scene", "seed", "focus", "blur_px", "variant"]
    assert "## What each class of depth error costs the render" in (out / "report.md").read_text()
