"""One progress protocol for every long call (issue 33, item 5): samii.progress.Progress (stage, advance, expect),
shown by the commands' one bar (samii.cli_progress.Bar)."""

from __future__ import annotations

import numpy as np
import pytest

from samii.progress import SILENT, part, said


def test_a_part_maps_a_nested_calls_total_onto_its_share(heard):
    parent = heard
    parent.expect(10)
    child = part(parent, 4, prefix="measuring: ")
    child.expect(200)  # the nested call's own units (physics steps, say): 200 of them are 4 of the parent's
    for _ in range(8):
        child.advance(25)
    child.stage("chunk")
    assert parent.done == pytest.approx(4.0) and parent.total == 10  # the nested expect stays with the nested call
    assert parent.stages == ["measuring: chunk"]
    quiet = part(parent, 0, prefix="second reading: ")  # counts nothing, says its stages
    quiet.expect(5)
    quiet.advance(5)
    quiet.stage("start notebook")
    assert parent.done == pytest.approx(4.0) and parent.stages[-1] == "second reading: start notebook"
    assert part(None, 3) is SILENT and said(None) is SILENT
    lines = []
    said(lines.append).stage("fitting")
    assert lines == ["fitting"]


def test_a_simulation_says_its_steps_and_advances_by_its_chunks(heard):
    from samii.sim.model import load_model
    from samii.sim.simulate import simulate

    simulate(load_model(), np.zeros(5000), chunk_steps=2000, progress=heard)
    assert heard.said == [("expect", 5000), ("advance", 2000), ("advance", 2000), ("advance", 1000)]


def test_a_fit_file_counts_one_unit_per_phase_weight(tmp_path, heard):
    """Each fit says its own stages' total; the file's progress maps each onto one unit of its phase weights."""
    from samii import notebook as nb
    from samii.formats import write_frf_csv
    from samii.identify import ModelStructure, SweptSineNoise, synthesize
    from samii.identify.fit_file import FitRequest, fit_frf_file

    st = ModelStructure.notebook_3mode()
    f = np.geomspace(0.1, 40.0, 200)
    data = synthesize(f, {c: st.response(nb.EQ9_4, f, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(1))
    path = tmp_path / "frf.csv"
    write_frf_csv(data, path)
    fit_frf_file(path, FitRequest(phase_weights=(0.1, 0.5), profiles="off"), progress=heard)
    assert [v for k, v in heard.said if k == "expect"] == [2]
    assert heard.done == pytest.approx(2.0) and heard.stages[0] == "reading"
    assert any(s.startswith("start ") for s in heard.stages)  # each fit's stages are said


def test_the_bar_shows_on_stderr_when_asked_and_never_with_no_progress(capsys):
    from samii.cli_progress import Bar

    with Bar("samii test", unit="step", disable=False) as bar:
        bar.expect(4)
        bar.stage("half")
        bar.advance(2)
    err = capsys.readouterr().err
    assert "samii test" in err and "half" in err
    with Bar("samii quiet", disable=True) as bar:  # --no-progress: every report, nothing shown
        bar.expect(4)
        bar.stage("quiet")
        bar.advance(4)
        bar.expect(5)
    assert capsys.readouterr().err == ""
    with Bar("samii never", disable=False) as bar:  # made at the first report only (shown on any stderr once made)
        pass
    assert capsys.readouterr().err == ""
