"""constraints.txt pins every dependency to one version inside pyproject.toml's ranges."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


def _pins() -> dict[str, Version]:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, version = line.partition("==")
            pins[canonicalize_name(name)] = Version(version)
    return pins


def _requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return [Requirement(r) for r in project["dependencies"] + project["optional-dependencies"]["test"]]


def test_every_dependency_is_pinned_inside_its_range():
    pins = _pins()
    for req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} has no pin in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), (str(req), str(pins[name]))


def test_torch_pin_matches_cpu_and_cuda_builds():
    pin = _pins()["torch"]
    assert pin.local is None and pin == Version("2.13.0")
    for build in ("2.13.0+cpu", "2.13.0+cu128"):
        assert Requirement(f"torch=={pin}").specifier.contains(build)


def test_ci_installs_with_the_constraints():
    ci = (ROOT / ".ci" / "run").read_text()
    assert f"pip install -q torch=={_pins()['torch']} &&" in ci
    assert 'pip install -q -c constraints.txt -e ".[test]"' in ci
    assert ci.rstrip().endswith(".ci/newest")  # then the newest allowed versions
    assert "constraints" not in "".join(
        line for line in (ROOT / ".ci" / "newest").read_text().splitlines() if "pip install" in line
    )
