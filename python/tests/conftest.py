"""Shared fixtures: the repository, its example configs, and the command-line binary whose JSON the
Python results must equal."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def cli() -> Path:
    """The release binary (built by the README's test command; built here if missing)."""
    exe = Path(os.environ.get("LIGHTPATH_BIN", REPO / "target" / "release" / "lightpath"))
    if not exe.is_file():
        subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=REPO, check=True)
    return exe


@pytest.fixture()
def run_cli(cli, tmp_path):
    """Run a command of the binary into a fresh folder and return that folder."""

    def run(*args: str, quiet: bool = True) -> Path:
        out = tmp_path / "cli"
        extra = ["--quiet"] if quiet else []
        subprocess.run([str(cli), *args, "--out", str(out), *extra], check=True)
        return out

    return run


def read_json(path: Path) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def read_toml(path: Path) -> dict:
    import sys

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # older interpreters: the tomli backport
        import tomli as tomllib
    with open(path, "rb") as f:
        return tomllib.load(f)
