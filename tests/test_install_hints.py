"""The install hint of a missing optional package fits how isoconvert was
installed: from a package index, its extra (``pip install "isoconvert[dicom]"``);
from a folder (a clone), where the index may not hold isoconvert and installing
the folder again rebuilds the kernels, the extra's own requirements as
pyproject.toml declares them."""

from __future__ import annotations

import importlib.metadata
import json
import tomllib
from pathlib import Path

import pytest

from isoconvert.errors import extra_hint, install_hint

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
EXTRAS = {
    name: needs
    for name, needs in tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))["project"][
        "optional-dependencies"
    ].items()
    if name != "test"
}


class _Installed:
    """A distribution's metadata as importlib.metadata gives it."""

    def __init__(self, url: str | None):
        self.url = url
        self.requires = [f'{need}; extra == "{name}"' for name, n in EXTRAS.items() for need in n]
        self.requires.insert(0, "numpy>=1.24")

    def read_text(self, name: str) -> str | None:
        if name == "direct_url.json" and self.url is not None:
            return json.dumps({"url": self.url, "dir_info": {}})
        return None


@pytest.fixture
def installed(monkeypatch):
    def install(url: str | None) -> None:
        extra_hint.cache_clear()
        monkeypatch.setattr(importlib.metadata, "distribution", lambda name: _Installed(url))

    yield install
    extra_hint.cache_clear()


@pytest.mark.parametrize("extra", sorted(EXTRAS))
def test_from_an_index_the_hint_is_the_extra(installed, extra):
    installed(None)
    assert extra_hint(extra) == f'pip install "isoconvert[{extra}]"'
    installed("https://files.example.org/isoconvert-1.0-cp311-linux_x86_64.whl")
    assert extra_hint(extra) == f'pip install "isoconvert[{extra}]"'


@pytest.mark.parametrize("extra", sorted(EXTRAS))
def test_from_a_folder_the_hint_is_the_extras_requirements(installed, extra):
    installed("file:///home/someone/isoconvert")
    assert extra_hint(extra) == "pip install " + " ".join(f'"{n}"' for n in EXTRAS[extra])


def test_the_packages_a_format_needs_name_their_extra(installed):
    installed(None)
    assert install_hint("h5py") == 'pip install "isoconvert[hdf5]"'
    assert install_hint("netCDF4") == 'pip install "isoconvert[netcdf]"'
    assert install_hint("lxml") == "pip install lxml"  # no extra of isoconvert's holds it


def test_this_installation_names_what_pyproject_declares():
    """The real metadata of the isoconvert installed here."""
    try:
        dist = importlib.metadata.distribution("isoconvert")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("isoconvert is not installed (pip install -e .)")
    origin = json.loads(dist.read_text("direct_url.json") or "{}")
    extra_hint.cache_clear()
    for extra, needs in EXTRAS.items():
        if str(origin.get("url", "")).startswith("file:"):
            assert extra_hint(extra) == "pip install " + " ".join(f'"{n}"' for n in needs)
        else:
            assert extra_hint(extra) == f'pip install "isoconvert[{extra}]"'
