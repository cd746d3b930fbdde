"""Where the shipped schemas and missions are, installed or in a source checkout."""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent.parent


def _data_dir(name: str) -> Path:
    installed = _PACKAGE_DIR / "_data" / name  # wheel: force-included by pyproject.toml
    if installed.is_dir():
        return installed
    return _PACKAGE_DIR.parent / name  # source checkout / editable install


def schemas_dir() -> Path:
    """The directory holding ``aircraft.xsd``, ``mission.xsd``, ..."""
    return _data_dir("schemas")


def schema_path(kind: str) -> Path:
    """Path of the XSD for ``kind`` (``aircraft``, ``mission``, ``scenario``)."""
    return schemas_dir() / f"{kind}.xsd"


def missions_dir() -> Path:
    """The shipped mission library (``<type>/aircraft.xml``, ``<type>/<mission>.xml``)."""
    return _data_dir("missions")


def shipped_mission_files() -> list[Path]:
    """Every XML file of the shipped library, sorted."""
    return sorted(missions_dir().rglob("*.xml"))
