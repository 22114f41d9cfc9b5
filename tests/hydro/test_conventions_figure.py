"""The convention figures are drawn from the code by a reproducible script, and the committed PNGs exist."""

import importlib.util

import matplotlib.image as mpimg

from workbench.project import project_root

FIGURES = project_root() / "docs" / "figures"


def test_figure_script_is_reproducible(tmp_path):
    spec = importlib.util.spec_from_file_location("draw_conventions", FIGURES / "draw_conventions.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.main(["--out", str(tmp_path / "a")])
    mod.main(["--out", str(tmp_path / "b")])
    for name in ("leg_conventions.png", "robot_frames.png"):
        first, second = (tmp_path / d / name for d in ("a", "b"))
        assert first.read_bytes() == second.read_bytes()
        committed = FIGURES / name
        assert committed.is_file(), f"commit {committed} (run docs/figures/draw_conventions.py)"
        assert mpimg.imread(committed).shape == mpimg.imread(first).shape
