"""Keep numba's disk cache of the joint filter honest across its source files.

Numba stamps a cached function with its own file only (mtime and size). The kernel's loop
calls compiled functions of other modules and freezes their constants (the state and
parameter slots) into its machine code, so a change there alone - an upgrade that touches
``joint_w.py`` or ``joint_layout.py`` but not ``joint_kernel.py`` - would leave the old code
running from ``__pycache__``. A digest of every source the kernel is built from is kept beside
the cache; when it differs, their cache entries are dropped and numba compiles afresh.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

STAMP_NAME = "joint-kernel.sources.sha256"


def sources_digest(modules: Sequence[ModuleType]) -> str:
    """sha256 over the modules' source files, in the order given."""
    digest = hashlib.sha256()
    for module in modules:
        digest.update(Path(str(module.__file__)).read_bytes())
    return digest.hexdigest()


def cache_folder(dispatcher: Any) -> Path | None:
    """Where numba keeps ``dispatcher``'s cache (None: not cached)."""
    path = getattr(getattr(dispatcher, "_cache", None), "_cache_path", None)
    return Path(path) if path else None


def drop_stale(dispatcher: Any, modules: Sequence[ModuleType]) -> bool:
    """Drop the cache entries of ``modules`` when their sources changed since the cache was
    written; True when it dropped them. Call before the first call of any of them."""
    folder = cache_folder(dispatcher)
    if folder is None:
        return False
    want = sources_digest(modules)
    stamp = folder / STAMP_NAME
    with contextlib.suppress(OSError):
        if stamp.read_text() == want:
            return False
    stems = {Path(str(m.__file__)).stem for m in modules}
    for entry in folder.glob("*.nb[ic]"):
        if entry.name.split(".", 1)[0] in stems:
            with contextlib.suppress(OSError):
                entry.unlink()
    with contextlib.suppress(OSError):  # a read-only install: numba caches elsewhere or not
        folder.mkdir(parents=True, exist_ok=True)
        stamp.write_text(want)
    return True
