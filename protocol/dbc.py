"""Where the machine-readable CAN description (``acb3.dbc``) lives.

The DBC ships inside the package so bus tools (cantools, SavvyCAN, vendor
analysers) and the bench read the same file; it describes the default BASE 0x100.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

DBC_PATH: Path = Path(str(files("protocol").joinpath("acb3.dbc")))
"""Filesystem path of ``protocol/acb3.dbc`` (e.g. for ``cantools.database.load_file``)."""
