"""Fixtures shared by the command-line batteries."""

from __future__ import annotations

import pytest


@pytest.fixture()
def out_dir(tmp_path):
    """An existing output folder holding a file of the user's: a failed run must leave it exactly so."""
    d = tmp_path / "out"
    d.mkdir()
    (d / "keep.txt").write_text("the user's")
    return d


@pytest.fixture()
def cwd(tmp_path, monkeypatch):
    """An empty working folder: a refused run must leave it empty (no output, no temp file)."""
    d = tmp_path / "cwd"
    d.mkdir()
    monkeypatch.chdir(d)
    return d
