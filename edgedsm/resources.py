"""Files shipped inside the package (``edgedsm/data/``): example configs, scenes, the systemd unit.

``edgedsm/data/config`` and ``edgedsm/data/systemd`` are symbolic links to the repository's
``config/`` and ``systemd/``: the repository keeps the one copy users read and edit as examples,
and building a wheel copies the files the links point to (so an installed edgedsm carries them
and never reads the repository at run time). Load them through ``data_file``, which finds them
with ``importlib.resources`` wherever the package is installed.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from edgedsm.errors import EdgedsmError


def data_file(relative: str) -> Path:
    """The path of a packaged file, e.g. ``data_file("config/daemon/demo.toml")``.

    A path on the file system, because configs name other files relative to themselves (the
    demo config's scene). Existence is not checked here: reading a missing one fails there.
    """
    resource = resources.files("edgedsm").joinpath("data", *relative.split("/"))
    if not isinstance(resource, Path):  # e.g. imported from a zip file
        raise EdgedsmError(f"edgedsm's packaged file data/{relative} is not on a file system "
                           f"({resource!r}); install edgedsm as a regular (unzipped) package")
    return resource
