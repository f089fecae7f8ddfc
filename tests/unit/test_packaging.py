"""The lab (edgedsm_lab: the benchmarks and the paper's reproduction) is a project of its own,
lab/pyproject.toml, beside the product's: it installs every package of edgedsm_lab, at edgedsm's
version, and asks only for what the test venv's lock holds (scripts/_env.sh installs it there with
--no-deps; the product's wheel leaves it out: tests/unit/test_house.py)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement

REPO = Path(__file__).resolve().parents[2]
PRODUCT = tomllib.loads((REPO / "pyproject.toml").read_text())
LAB = tomllib.loads((REPO / "lab" / "pyproject.toml").read_text())


def test_the_lab_installs_every_package_of_edgedsm_lab_and_nothing_else() -> None:
    setuptools = LAB["tool"]["setuptools"]
    packages = {".".join(path.parent.relative_to(REPO).parts) for path in (REPO / "edgedsm_lab").rglob("__init__.py")}
    assert set(setuptools["packages"]) == packages and len(packages) >= 3
    assert {(REPO / "lab" / where).resolve() for where in setuptools["package-dir"].values()} == {REPO / "edgedsm_lab"}


def test_the_lab_goes_with_its_own_edgedsm() -> None:
    assert LAB["project"]["version"] == PRODUCT["project"]["version"]
    requirements = {Requirement(text).name: Requirement(text) for text in LAB["project"]["dependencies"]}
    assert requirements["edgedsm"].specifier.contains(PRODUCT["project"]["version"])
    assert str(requirements["edgedsm"].specifier) == f"=={PRODUCT['project']['version']}"


def test_the_product_does_not_ask_for_the_lab() -> None:
    asked = PRODUCT["project"]["dependencies"] + [text for extra in PRODUCT["project"]["optional-dependencies"].values()
                                                  for text in extra]
    assert not any(Requirement(text).name.startswith("edgedsm") for text in asked)
    assert PRODUCT["tool"]["setuptools"]["packages"]["find"]["include"] == ["edgedsm", "edgedsm.*"]
