"""Pictures for the README and the model card, written to ``assets/``.

* ``assets/samii_model.png``: the embedded model at its ``home`` keyframe (static
  equilibrium, nominal pose), rendered offscreen by MuJoCo from two cameras;
* ``assets/samii_measure_bode.png``: ``samii measure``'s default swept-sine Bode
  plot (the same as ``samii measure --out DIR`` writes as ``bode.png``).

Offscreen rendering needs an OpenGL back end without a screen: run
``MUJOCO_GL=egl python experiments/render_model/run.py`` (``osmesa`` also works
where installed).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"


def render_model(path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    from samii.sim.model import default_model_path
    from samii.sim.plugin import load_plugin

    load_plugin()
    model = mujoco.MjModel.from_xml_path(str(default_model_path().parent / "scene.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    renderer = mujoco.Renderer(model, 480, 640)  # the scene's default offscreen buffer is 640 wide
    renderer.update_scene(data, camera="side")
    side = renderer.render()
    cam = mujoco.MjvCamera()
    tip = data.site("base_accel").xpos
    cam.lookat[:] = (tip[0] + 0.1, tip[1], tip[2] + 0.2)  # the arm, on the beam's top
    cam.distance, cam.azimuth, cam.elevation = 2.2, -125.0, -10.0
    renderer.update_scene(data, camera=cam)
    close = renderer.render()
    fig, axes = plt.subplots(1, 2, figsize=(12.8, 4.8))
    for ax, img, title in zip(
        axes,
        (side, close),
        (
            "side camera: foot clamp, the vertical beam (4.29 m free), arm on its top",
            "the arm at the nominal pose (-90, 90, 90, 0, 0, 0) deg; link 3 points north",
        ),
    ):
        ax.imshow(img)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.suptitle("samii: SAMII on its flexible cantilevered beam (MuJoCo, home keyframe at static equilibrium)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    if not os.environ.get("MUJOCO_GL"):
        print("set MUJOCO_GL=egl (or osmesa) for offscreen rendering", file=sys.stderr)
        return 2
    ASSETS.mkdir(exist_ok=True)
    render_model(ASSETS / "samii_model.png")
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["samii", "measure", "--out", tmp, "--no-progress"], check=True)
        shutil.copy(Path(tmp) / "bode.png", ASSETS / "samii_measure_bode.png")
    print(f"wrote {ASSETS / 'samii_model.png'} and {ASSETS / 'samii_measure_bode.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
