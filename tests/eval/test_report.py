"""The report folder: metrics.json (valid JSON, NaN as null), a Markdown table and PNG plots."""

import json

import numpy as np

from physdyn.eval.evaluate import compare
from physdyn.eval.report import write_report


def test_report_files_from_a_baseline_comparison(tiny_store, tmp_path):
    comparison = compare("stay_put", tiny_store, baselines=("coulomb_slide",))
    paths = write_report(comparison, tmp_path / "out")
    data = json.loads(paths["metrics"].read_text())  # strict JSON: the baselines' NaN axis error became null
    assert data["results"]["stay_put"]["headline"]["axis"] is None
    assert data["verdict"] == comparison["verdict"]
    table = [line for line in paths["report"].read_text().splitlines() if line.startswith("| ")]
    assert len(table) == 3 and all(line.count("|") == table[0].count("|") for line in table)
    assert "stay_put" in table[1] and "coulomb_slide" in table[2]
    for key in ("error_vs_time", "per_category"):
        assert paths[key].read_bytes()[:4] == b"\x89PNG" and paths[key].stat().st_size > 5000


def test_an_existing_report_is_kept_unless_overwrite(tiny_store, tmp_path):
    import pytest

    from physdyn.errors import PhysdynError

    comparison = compare("stay_put", tiny_store, baselines=("coulomb_slide",))
    paths = write_report(comparison, tmp_path / "out")
    paths["report"].write_text("my annotated report")
    with pytest.raises(PhysdynError, match="--overwrite"):
        write_report(comparison, tmp_path / "out")
    assert paths["report"].read_text() == "my annotated report"
    write_report(comparison, tmp_path / "out", overwrite=True)
    assert paths["report"].read_text() != "my annotated report"


def test_unknown_friction_skips_the_coulomb_baseline_and_says_why(tiny_store):
    import numpy as np

    from physdyn.data.store import load_store

    store = load_store(tiny_store)
    store.friction[:] = np.nan  # as an import of real trials without --friction
    comparison = compare("stay_put", store, baselines=("coulomb_slide", "cloud_sim"))
    assert "coulomb_slide" not in comparison["results"] and "cloud_sim" not in comparison["results"]
    assert "--friction" in comparison["verdict"] and "friction" in comparison["skipped_baselines"]["coulomb_slide"]
    assert "friction" in comparison["skipped_baselines"]["cloud_sim"]


def test_error_curves_stop_where_few_sequences_still_run(tiny_store):
    from physdyn.eval.report import curve_end

    count = [80, 80, 60, 40, 20, 10, 10]
    assert curve_end(count) == 5  # steps 0-4: 20 of 80 is the last count of at least a quarter
    assert curve_end(count, min_share=0.5) == 4 and curve_end(count, 0.1) == 7
    assert curve_end([8, 8, 6, 4, 2]) == 2  # fewer than 10 sequences: plotted while all of them run
    curves = compare("stay_put", tiny_store, baselines=())["results"]["stay_put"]["curves"]["non_toppling"]
    median, q25, q75 = (np.asarray(curves[f"position_m_{k}"], float) for k in ("median", "q25", "q75"))
    ok = np.isfinite(median)
    assert ok[:curve_end(curves["count"])].all()
    assert (q25[ok] <= median[ok] + 1e-12).all() and (median[ok] <= q75[ok] + 1e-12).all()
