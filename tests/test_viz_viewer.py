"""A recording in the real Rerun viewer (headless): the stored layout loads as built, every view
shows without a problem, and the deformed 3D view shows the beam move where the true-scale one
barely does. Skipped where no Vulkan driver is installed (the viewer needs one even without a
window; Debian's ``mesa-vulkan-drivers`` gives a software one)."""

from __future__ import annotations

import numpy as np
import pytest

from samii.cli import main
from samii.viz.viewer import HeadlessViewer, graphics_available

pytestmark = pytest.mark.skipif(not graphics_available(), reason="no Vulkan driver for the Rerun viewer (apt-get install mesa-vulkan-drivers)")


def _tip(path, run):
    """(t [s], tip displacement [mm]) of ``run`` as logged."""
    from samii.viz.recording import read_scalars

    return read_scalars(path, f"/{run}/displacement_mm/tip")[f"/{run}/displacement_mm/tip"]


def _changed(a, b) -> float:
    """Fraction of pixels that differ visibly between two screenshots of one view."""
    import matplotlib.image as mpimg

    x, y = mpimg.imread(a)[..., :3], mpimg.imread(b)[..., :3]
    assert x.shape == y.shape and x.shape[0] > 100 and x.shape[1] > 100
    return float(np.mean(np.max(np.abs(x - y), axis=-1) > 0.1))


@pytest.mark.slow
def test_the_viewer_shows_the_layout_and_the_beam_moving(tmp_path):
    rrd = tmp_path / "release.rrd"
    assert main(["closedloop", "--controller", "unity", "--scenario", "release", "--duration-s", "3", "--out", str(tmp_path / "out"),
                 "--rerun", str(rrd), "--rerun-fps", "50"]) == 0  # fmt: skip
    t, tip = _tip(rrd, "closedloop")
    t_peak = float(t[np.argmax(np.abs(tip))])
    assert 0.05 < t_peak < 0.4  # a quarter period of mode 1 (1.73 Hz) after the impulse, give or take the others
    with HeadlessViewer(rrd) as v:
        views = v.views()
        kinds = sorted(x.kind for x in views)
        assert kinds.count("3D") == 2 and kinds.count("TimeSeries") == 5 and "TextDocument" in kinds, kinds
        assert not [x for x in views if x.problems], [x for x in views if x.problems]
        deformed = next(x.name for x in views if x.kind == "3D" and "beam ×" in x.name)
        true = next(x.name for x in views if x.kind == "3D" and "true scale" in x.name)
        assert next(x for x in views if x.name == deformed).origin == "/closedloop/deformed"
        v.show(0.0)
        at_rest = {name: v.screenshot(tmp_path / f"{i}_rest.png", view=name) for i, name in enumerate((deformed, true))}
        whole = v.screenshot(tmp_path / "window.png")
        v.show(t_peak)
        at_peak = {name: v.screenshot(tmp_path / f"{i}_peak.png", view=name) for i, name in enumerate((deformed, true))}
        assert not v.errors()
    import matplotlib.image as mpimg

    img = mpimg.imread(whole)
    assert img.shape[:2] == (1080, 1920) and float(np.std(img[..., :3])) > 0.05  # painted, not blank
    moved = _changed(at_rest[deformed], at_peak[deformed])
    still = _changed(at_rest[true], at_peak[true])
    # the beam at ×(5 % of its length / largest deflection) bends visibly; at true scale it moves ~1 mm
    assert moved > 0.002, (moved, still)
    assert still < 0.5 * moved, (moved, still)
