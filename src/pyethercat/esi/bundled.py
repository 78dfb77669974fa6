"""ESI files shipped with pyethercat (package data under ``pyethercat/data/esi``).

``seed002_drive.xml`` describes the Metronix EtherCAT servo drive (vendor 0xE4,
product 0x264860D2, revision 0x20000) as its CANopen-over-EtherCAT manual
describes it; the file's own comment says which chapters.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pyethercat.errors import EsiError

__all__ = ["SEED002_DRIVE", "bundled_esi", "bundled_esi_names"]

#: File name of the bundled Metronix servo drive ESI.
SEED002_DRIVE = "seed002_drive.xml"


def bundled_esi_names() -> list[str]:
    """Names of the ESI files shipped with the package."""
    root = resources.files("pyethercat") / "data" / "esi"
    return sorted(p.name for p in root.iterdir() if p.name.endswith(".xml"))


def bundled_esi(name: str = SEED002_DRIVE) -> Path:
    """Path of a shipped ESI file (``builtin:NAME`` in topology files and the CLI)."""
    path = Path(str(resources.files("pyethercat") / "data" / "esi" / name))
    if not path.is_file():
        raise EsiError(f"no bundled ESI named {name!r} (have: {', '.join(bundled_esi_names())})")
    return path
