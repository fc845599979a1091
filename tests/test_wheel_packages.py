"""The packages pyproject.toml lists are every package of the repository: a farm worker installs
the wheel (`pip install ".[farm]"`, docs/farm.md), which holds only the listed ones, so a new
sub-package left out would import in the checkout (and in the tests) and fail on a worker."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: folders with an __init__.py that are not shipped: the tests, benches and tools, the environments
NOT_SHIPPED = {"tests", "bench", "tools", "build", "dist", "out", "web", "wheels"}


def test_every_package_is_listed():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    found = {"hhd_lightmapper"}
    for init in ROOT.rglob("__init__.py"):
        parts = init.parent.relative_to(ROOT).parts
        if not parts or parts[0] in NOT_SHIPPED or parts[0].startswith("."):
            continue
        found.add(".".join(parts) if parts[0] == "scenekit" else ".".join(("hhd_lightmapper", *parts)))
    assert found == listed, (sorted(found - listed), sorted(listed - found))
