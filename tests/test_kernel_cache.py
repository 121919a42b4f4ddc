"""numba stamps a cached function with its own file only: the joint filter's loop, which
freezes other modules' code and constants into its machine code, must not run stale after
one of them changed (bench/fusion/kernel_cache.py)."""

from __future__ import annotations

import types
from pathlib import Path

from bench.fusion import (
    joint_drift,
    joint_kernel,
    joint_layout,
    joint_rewind,
    joint_updates,
    joint_w,
)
from bench.fusion.kernel_cache import STAMP_NAME, cache_folder, drop_stale, sources_digest


def _module(path: Path, text: str) -> types.ModuleType:
    path.write_text(text)
    module = types.ModuleType(path.stem)
    module.__file__ = str(path)
    return module


def _entries(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir() if p.suffix in (".nbi", ".nbc")}


def test_cache_entries_go_when_a_source_changes_and_stay_otherwise(tmp_path: Path) -> None:
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    kernel = _module(tmp_path / "kern.py", "def run(): ...\n")
    layout = _module(tmp_path / "slots.py", "A = 1\n")
    dispatcher = types.SimpleNamespace(_cache=types.SimpleNamespace(_cache_path=str(cache)))
    ours = {"kern.run-10.py311.nbi", "kern.run-10.py311.1.nbc", "slots.f-3.py311.nbi"}
    other = "elsewhere.g-7.py311.nbi"
    for name in (*ours, other):
        (cache / name).write_bytes(b"machine code")
    # no stamp yet (a cache from before the guard): dropped, the other module's kept
    assert drop_stale(dispatcher, (kernel, layout)) is True
    assert _entries(cache) == {other}
    assert (cache / STAMP_NAME).read_text() == sources_digest((kernel, layout))
    # numba writes them again; nothing changed: they stay
    for name in ours:
        (cache / name).write_bytes(b"machine code")
    assert drop_stale(dispatcher, (kernel, layout)) is False
    assert _entries(cache) == {*ours, other}
    # a constant changes in the layout module alone: the kernel's entries go too
    Path(str(layout.__file__)).write_text("A = 2\n")
    assert drop_stale(dispatcher, (kernel, layout)) is True
    assert _entries(cache) == {other}


def test_an_uncached_dispatcher_is_left_alone(tmp_path: Path) -> None:
    kernel = _module(tmp_path / "kern.py", "x = 1\n")
    assert drop_stale(types.SimpleNamespace(), (kernel,)) is False
    assert not list(tmp_path.glob("**/" + STAMP_NAME))


def test_the_real_kernel_is_guarded_over_all_its_sources() -> None:
    folder = cache_folder(joint_kernel.run)
    assert folder is not None  # numba still exposes where it caches: the guard is not inert
    modules = (joint_kernel, joint_w, joint_updates, joint_drift, joint_rewind, joint_layout)
    stamp = folder / STAMP_NAME
    if stamp.exists():  # written at import (absent only where the folder is read-only)
        assert stamp.read_text() == sources_digest(modules)
