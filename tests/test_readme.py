"""The README's examples run as written: its case loads, its Python example executes."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

import spotpde

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_readme_case_is_the_flagship_and_valid():
    (block,) = _blocks("toml")
    case = spotpde.load_case(tomllib.loads(block))
    flagship = spotpde.load_case(ROOT / "cases" / "quasi2d_layers.toml")
    assert case.data == flagship.data


def test_readme_python_example_runs(monkeypatch):
    block = _blocks("python")[0]
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    ds = namespace["ds"]
    assert {"rho_s", "u_z", "D_xx", "P", "P_height", "mass", "outflow"} <= set(ds.data_vars)
    assert namespace["k"].V2 / namespace["k"].V1 == pytest.approx(0.0024, rel=1e-12)


def test_readme_commands_are_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    commands = _blocks("bash")
    assert commands[0].strip() == "pip install . && spotpde run cases/quasi2d_layers.toml --plot"
    assert commands[1].strip() in ci


def test_readme_data_in_example_names_the_public_api():
    """The data-in example needs a user's tracks file: it must compile and call only
    public names that exist."""
    (block,) = [b for b in _blocks("python") if "spotpde.tracks.read" in b]
    compile(block, "README.md", "exec")
    for name in re.findall(r"spotpde\.([a-z_]+(?:\.[a-z_]+)?)\(", block):
        obj = spotpde
        for part in name.split("."):
            obj = getattr(obj, part)
        assert callable(obj), name
